"""Interfaces of survey hardware, as structural protocols (no I/O here).

Drivers in ``drivers/`` (real hardware and their simulated twins) implement
these; measurement and survey code in ``fgloc`` depends only on them, so core
code never imports a driver.

Angles are radians in the spec's convention (``docs/file-format.md``):
pan counter-clockwise seen from above about the base z axis, zero along base x;
tilt is elevation above the base x-y plane, positive up. Conversion from device
counts, signs and mounting (a ceiling mount flips) happens inside the driver.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class PanTiltHead(Protocol):
    """A pan-tilt-zoom camera head."""

    def move_to(self, pan: float, tilt: float) -> None:
        """Move to absolute (pan, tilt) in radians and block until the move completes."""

    def position(self) -> tuple[float, float]:
        """Read back the head's current (pan, tilt) in radians."""

    def set_zoom(self, zoom: float) -> None:
        """Set zoom as a fraction of the optical range: 0.0 is widest, 1.0 full optical tele."""

    def zoom(self) -> float:
        """Read back the zoom fraction (0.0 widest ... 1.0 full optical tele)."""

    def stop(self) -> None:
        """Stop any motion."""

    def home(self) -> None:
        """Return to the home position (pan = tilt = 0 in the device's own frame)."""

    def grab_frame(self) -> np.ndarray:
        """The current image as a uint8 array (H, W) grayscale or (H, W, 3) BGR."""


@runtime_checkable
class LedController(Protocol):
    """The mote network's base station: lights a node's LED on request."""

    def set_led(self, node_id: str, on: bool) -> bool:
        """Switch node ``node_id``'s LED; True when the node acknowledged."""
