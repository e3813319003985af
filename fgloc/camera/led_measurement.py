"""Measure a node's (pan, tilt) with a pan-tilt head: pixel-offset mode and centring mode.

Depends only on the :mod:`fgloc.core.hardware` protocols (a real driver or its simulated
twin), :mod:`fgloc.camera.led_detection` and :mod:`fgloc.camera.pixel_angles`.

* **Pixel-offset mode** (:func:`measure_led`): read the head, find the LED in
  an on/off frame pair, convert its centroid exactly into the node's (pan,
  tilt). One frame pair per node; accuracy set by the intrinsics.
* **Centring mode** (:func:`centre_on_led`): move the head until the LED is
  within ``tolerance_px`` of the principal point, then report the read-back
  head angles. Insensitive to intrinsics errors, limited by the head's step.

Angles in radians, spec convention (``docs/file-format.md``). Both
modes assume the optical centre is on the rotation axes, which holds only at
the widest zoom: :func:`check_zoom` warns (:class:`ZoomWarning`) otherwise.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_detection import DetectionResult, DetectorConfig, detect_led
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.errors import FglocError
from fgloc.core.hardware import LedController, PanTiltHead

#: Zoom fractions closer than this count as the same setting.
ZOOM_TOLERANCE = 0.01


class ZoomWarning(UserWarning):
    """Measuring at a zoom where the angle model is not trustworthy."""


class LedControlError(FglocError):
    """The base station did not acknowledge an LED command."""


class FrameSizeError(FglocError):
    """Frames whose size differs from the image size the intrinsics were calibrated at."""


def check_frame_size(frame: np.ndarray, intrinsics: CameraIntrinsics) -> None:
    """Raise FrameSizeError unless ``frame`` is intrinsics.width x intrinsics.height."""
    h, w = np.asarray(frame).shape[:2]
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise FrameSizeError(
            f"frame: size {w}x{h} differs from the calibrated image size {intrinsics.width}x{intrinsics.height}; "
            "calibrate at the frame grabber's resolution"
        )


def check_zoom(head_zoom: float, intrinsics: CameraIntrinsics) -> list[str]:
    """Warn (ZoomWarning) and return the problems when measuring at ``head_zoom`` with ``intrinsics``.

    Two separate problems: intrinsics calibrated at another zoom (pixel angles will be
    wrong), and any zoom other than the widest (the paper found only the widest zoom keeps
    the optical centre on the rotation axes, so bearings gain a parallax error).
    """
    problems = []
    if abs(head_zoom - intrinsics.zoom) > ZOOM_TOLERANCE:
        problems.append(
            f"head zoom {head_zoom:.3f} differs from the calibrated zoom {intrinsics.zoom:.3f}: "
            "pixel-to-angle conversion uses the wrong intrinsics"
        )
    if head_zoom > ZOOM_TOLERANCE:
        problems.append(
            f"measuring at zoom {head_zoom:.3f}: only the widest zoom (0) keeps the optical centre "
            "on the pan/tilt axes; bearings will carry a parallax error"
        )
    for p in problems:
        warnings.warn(p, ZoomWarning, stacklevel=3)
    return problems


@dataclass(frozen=True)
class LedMeasurement:
    """One look at an LED: the detection, the read-back head angles, and when found the
    node's ``pan, tilt`` (radians) and its 1-sigma angular precision ``sigma`` (radians,
    centroid noise only, no intrinsics or head errors)."""

    detection: DetectionResult
    head_pan: float
    head_tilt: float
    pan: float | None = None
    tilt: float | None = None
    sigma: float | None = None

    @property
    def found(self) -> bool:
        return self.detection.found


def measurement_from_detection(
    detection: DetectionResult, head_pan: float, head_tilt: float, intrinsics: CameraIntrinsics
) -> LedMeasurement:
    """Combine a detection with the head angles it was taken at (pixel-offset mode)."""
    if not detection.found:
        return LedMeasurement(detection, head_pan, head_tilt)
    d = detection.detection
    assert d is not None  # found
    pan, tilt = pixel_to_pan_tilt(intrinsics, [d.u, d.v], head_pan, head_tilt)
    sigma = d.sigma_px / math.sqrt(intrinsics.fx * intrinsics.fy)
    return LedMeasurement(detection, head_pan, head_tilt, float(pan), float(tilt), sigma)


def measure_led(
    head: PanTiltHead,
    led_on_frame: np.ndarray,
    led_off_frame: np.ndarray,
    intrinsics: CameraIntrinsics,
    config: DetectorConfig | None = None,
) -> LedMeasurement:
    """Pixel-offset mode: node (pan, tilt) from a frame pair grabbed at the head's current pose."""
    check_zoom(head.zoom(), intrinsics)
    check_frame_size(led_on_frame, intrinsics)
    head_pan, head_tilt = head.position()
    return measurement_from_detection(detect_led(led_on_frame, led_off_frame, config), head_pan, head_tilt, intrinsics)


def grab_led_pair(head: PanTiltHead, leds: LedController, node_id: str) -> tuple[np.ndarray, np.ndarray]:
    """(LED-on frame, LED-off frame) of ``node_id``; the LED is left off. Raises LedControlError."""
    if not leds.set_led(node_id, True):
        raise LedControlError(f"node {node_id}: LED on command not acknowledged")
    try:
        on = head.grab_frame()
    finally:
        if not leds.set_led(node_id, False):
            raise LedControlError(f"node {node_id}: LED off command not acknowledged")
    return on, head.grab_frame()


def led_detector(
    head: PanTiltHead, leds: LedController, node_id: str, config: DetectorConfig | None = None
) -> Callable[[], DetectionResult]:
    """A ``detect()`` callable for :func:`centre_on_led`: blink ``node_id`` and detect it."""
    return lambda: detect_led(*grab_led_pair(head, leds, node_id), config)


@dataclass(frozen=True)
class CentringResult:
    """Outcome of :func:`centre_on_led`.

    ``pan, tilt``: head read-back when centred (radians; the centring-mode measurement,
    None when the LED was lost). ``residual_px``: LED distance from the principal point at
    the end. ``final``: the pixel-offset measurement from the last frame pair (usually more
    precise than the head's quantised angles). ``moves``: head moves made.
    """

    converged: bool
    pan: float | None
    tilt: float | None
    residual_px: float
    moves: int
    final: LedMeasurement | None
    reason: str


def centre_on_led(
    head: PanTiltHead,
    detect: Callable[[], DetectionResult],
    intrinsics: CameraIntrinsics,
    tolerance_px: float = 1.0,
    max_moves: int = 8,
) -> CentringResult:
    """Move the head until the LED is within ``tolerance_px`` of the principal point.

    Each step detects the LED, computes its exact (pan, tilt) from the read-back head
    angles and points the head there. Stops unconverged when the LED is lost or
    ambiguous, after ``max_moves`` moves, or when a move leaves the head where it was
    (its angle step is coarser than the tolerance). Raises FrameSizeError when the head's
    frames do not match the intrinsics' image size.
    """
    check_zoom(head.zoom(), intrinsics)
    check_frame_size(head.grab_frame(), intrinsics)
    cx, cy = intrinsics.principal_point
    moves = 0
    last: LedMeasurement | None = None
    residual = math.inf
    while True:
        head_pan, head_tilt = head.position()
        result = detect()
        last = measurement_from_detection(result, head_pan, head_tilt, intrinsics)
        if not result.found:
            return CentringResult(False, None, None, residual, moves, last, f"LED {result.status.value}")
        d = result.detection
        assert d is not None and last.pan is not None and last.tilt is not None  # found
        residual = math.hypot(d.u - cx, d.v - cy)
        if residual <= tolerance_px:
            return CentringResult(True, head_pan, head_tilt, residual, moves, last, "centred")
        if moves >= max_moves:
            return CentringResult(False, head_pan, head_tilt, residual, moves, last, f"not centred after {moves} moves")
        head.move_to(last.pan, last.tilt)
        moves += 1
        if head.position() == (head_pan, head_tilt):
            return CentringResult(False, head_pan, head_tilt, residual, moves, last,
                                  "head cannot move closer (angle step coarser than the tolerance)")
