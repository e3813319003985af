"""One pan-tilt head adapter for every PTZ driver: spec radians in, device counts to the driver.

A driver subclasses :class:`HeadAdapter` and implements the counts level only
(:meth:`~HeadAdapter.read_counts_once`, :meth:`~HeadAdapter.move_to_counts`,
:meth:`~HeadAdapter.set_zoom_counts`, :meth:`~HeadAdapter.zoom_counts`, ``stop``,
``home``). This base gives it ``fgloc.core.hardware.PanTiltHead``:

* angles: spec (pan, tilt) radians <-> signed device counts through
  :class:`fgloc.drivers.ptz_units.PanTiltUnits`, which holds the model's counts per
  degree and the mounting (desk, or ceiling: pan and tilt signs flipped);
* limits: :meth:`~HeadAdapter.check_counts` rejects counts outside the model's
  mechanical range before anything is sent;
* read-back: :meth:`~HeadAdapter.position_counts` reads until two successive reads
  agree, which rejects a head still settling and a reply corrupted in transit;
* zoom as a fraction of the optical range (0 wide ... 1 optical tele);
* frames from a frame source (an object with ``read()`` or a zero-argument callable).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import ClassVar, Protocol, Self

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.drivers.ptz_units import CameraModel, PanTiltUnits, PositionOutOfRangeError


class FrameSourceLike(Protocol):
    def read(self) -> np.ndarray: ...


FrameSourceArg = FrameSourceLike | Callable[[], np.ndarray] | None


class HeadAdapter:
    """Base of the PTZ heads: the spec-radian ``PanTiltHead`` on top of a driver's counts level.

    Subclasses set :attr:`unsteady_error` (raised when reads never agree) and may
    override :meth:`_frame_without_source` (called when no frame source was given).
    ``_last_counts`` is the last position the driver knows the head to be at, in
    counts (None when unknown); drivers use it to size move timeouts.
    """

    unsteady_error: ClassVar[type[FglocError]] = FglocError

    def __init__(self, units: PanTiltUnits, frames: FrameSourceArg = None, confirm_reads: bool = True,
                 max_reads: int = 5, read_gap_s: float = 0.0) -> None:
        self.units = units
        self.frames = frames
        self.confirm_reads = confirm_reads
        self.max_reads = max_reads
        self.read_gap_s = read_gap_s  # seconds between two reads that disagreed
        self._last_counts: tuple[int, int] | None = None

    @property
    def model(self) -> CameraModel:
        return self.units.model

    @property
    def where(self) -> str:
        """Where the head is (for error messages): a port, a URL."""
        return self.model.name

    # -- the counts level, per driver
    def read_counts_once(self) -> tuple[int, int]:
        """One position inquiry: (pan, tilt) in signed device counts."""
        raise NotImplementedError

    def move_to_counts(self, pan: int, tilt: int) -> None:
        """Absolute move in device counts; returns when the head is there."""
        raise NotImplementedError

    def set_zoom_counts(self, counts: int) -> None:
        """Absolute zoom in (unsigned) zoom counts; returns when the lens is there."""
        raise NotImplementedError

    def zoom_counts(self) -> int:
        """Read-back zoom in zoom counts."""
        raise NotImplementedError

    # -- shared
    def check_counts(self, pan: int, tilt: int) -> None:
        """Raise PositionOutOfRangeError unless (pan, tilt) counts lie in the model's mechanical range."""
        m = self.model
        if not (m.pan_min <= pan <= m.pan_max and m.tilt_min <= tilt <= m.tilt_max):
            raise PositionOutOfRangeError(
                f"({pan}, {tilt}) counts outside {m.name} range pan {m.pan_min}..{m.pan_max}, "
                f"tilt {m.tilt_min}..{m.tilt_max}")

    def position_counts(self) -> tuple[int, int]:
        """Read-back (pan, tilt) in device counts, confirmed by two equal successive reads when enabled."""
        prev = self.read_counts_once()
        if not self.confirm_reads:
            self._last_counts = prev
            return prev
        for _ in range(self.max_reads - 1):
            cur = self.read_counts_once()
            if cur == prev:
                self._last_counts = cur
                return cur
            prev = cur
            if self.read_gap_s > 0:
                time.sleep(self.read_gap_s)
        raise self.unsteady_error(f"{self.where}: pan-tilt position did not read the same twice in "
                                  f"{self.max_reads} reads (head still moving or line noise)")

    # -- PanTiltHead
    def move_to(self, pan: float, tilt: float) -> None:
        """Move to spec (pan, tilt) radians; blocks until the head is there."""
        self.move_to_counts(*self.units.to_counts(pan, tilt))

    def position(self) -> tuple[float, float]:
        """Read-back spec (pan, tilt) radians (pan in (-pi, pi])."""
        return self.units.to_spec(*self.position_counts())

    def set_zoom(self, zoom: float) -> None:
        """Zoom to a fraction of the optical range (0 wide ... 1 optical tele)."""
        self.set_zoom_counts(self.units.zoom_to_counts(zoom))

    def zoom(self) -> float:
        """Read-back zoom as a fraction of the optical range (above 1 in the digital range)."""
        return self.units.zoom_from_counts(self.zoom_counts())

    def grab_frame(self) -> np.ndarray:
        """One frame from the frame source, else from the driver (:meth:`_frame_without_source`)."""
        frames = self.frames
        if frames is None:
            return self._frame_without_source()
        read = getattr(frames, "read", None)
        if callable(read):
            return read()
        assert callable(frames)
        return frames()

    def _frame_without_source(self) -> np.ndarray:
        raise FglocError(f"{self.where}: this head has no frame source (give --video or a FrameSource)")

    def close(self) -> None:
        """Release the connection (nothing to release by default)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
