"""Preflight: refuse a survey that cannot work before anything moves (docs/survey.md, "Preflight").

Two stages, each refusing with one line ``RIG: FIELD: camera ID: problem`` (an
:class:`PreflightError`, exit status 2; URL user info redacted):

* :func:`check_rig` (rig.json alone, before any device is opened): every camera's
  intrinsics are plausible (frame at most :data:`MAX_SIDE_PX` a side and
  :data:`MAX_PIXELS`, principal point inside the frame, fields of view between
  :data:`MIN_FOV_DEG` and :data:`MAX_FOV_DEG`, pixel aspect within 1:5), so no absurd
  frame is ever allocated; and for every head that enforces its mechanical range
  (real drivers, and the VISCA twins under ``--simulate``) the model is known to
  ``fgloc.drivers.ptz_units`` and the search range lies inside the head's pan and tilt range
  for its mounting.
* :func:`check_devices` (rig opened, nothing moved): the base station opened (see
  ``session.open_hardware``); every camera opens (reachable, authenticated, its video
  source opens), answers a position inquiry and delivers a frame of the size its
  intrinsics were calibrated at. Transient failures are retried like head commands
  (``retry.head_attempts`` with the rig's back-off); a refused login or a video source
  that does not open is not.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.errors import FglocError
from fgloc.core.hardware import PanTiltHead
from fgloc.core.redact import redact_urls
from fgloc.core.retry import RetryPolicy, linear
from fgloc.files.rig_config import CameraConfig, RigConfig

logger = logging.getLogger(__name__)

MAX_SIDE_PX = 16384  # larger than any video camera's frame (8K UHD is 7680 x 4320)
MAX_PIXELS = 1 << 26  # 67 Mpx; 100000 x 100000 would be a 9.3 GiB frame
MIN_FOV_DEG = 0.01
MAX_FOV_DEG = 175.0


class PreflightError(FglocError):
    """The rig cannot survey: a camera or the base station fails a check. One line, URLs redacted."""

    def __init__(self, message: str) -> None:
        super().__init__(redact_urls(" ".join(message.split())))


def _fail(rig: RigConfig, index: int, field: str, problem: str) -> PreflightError:
    cam = rig.cameras[index]
    return PreflightError(f"{rig.path}: cameras[{index}].{field}: camera {cam.id}: {problem}")


def intrinsics_problem(k: CameraIntrinsics) -> str | None:
    """Why intrinsics cannot describe a real camera's frames, or None when they can."""
    if not (0 < k.width <= MAX_SIDE_PX and 0 < k.height <= MAX_SIDE_PX and k.width * k.height <= MAX_PIXELS):
        return (f"a {k.width}x{k.height} px frame is not plausible (at most {MAX_SIDE_PX} px a side "
                f"and {MAX_PIXELS / 1e6:.0f} Mpx)")
    if not (0.0 <= k.cx <= k.width and 0.0 <= k.cy <= k.height):
        return f"principal point ({k.cx:g}, {k.cy:g}) px lies outside the {k.width}x{k.height} px frame"
    for axis, size, f in (("horizontal", k.width, k.fx), ("vertical", k.height, k.fy)):
        fov = math.degrees(2 * math.atan(size / (2 * f)))
        if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
            return (f"focal length {f:g} px gives a {axis} field of view of {fov:.3g} deg "
                    f"(plausible: {MIN_FOV_DEG:g} to {MAX_FOV_DEG:g} deg)")
    if not 0.2 <= k.fx / k.fy <= 5.0:
        return f"fx / fy = {k.fx / k.fy:.3g} is not a plausible pixel aspect (0.2 to 5)"
    return None


def enforces_limits(cam: CameraConfig, rig: RigConfig, simulate: bool) -> bool:
    """True when the camera's head refuses moves outside its model's range (not the in-process twin)."""
    return cam.driver != "simulated" or (simulate and rig.simulation.twin == "visca")


def _range_problem(rig: RigConfig, index: int) -> PreflightError | None:
    from fgloc.drivers.ptz_units import CAMERA_MODELS, PanTiltUnits, camera_model, mounting

    cam = rig.cameras[index]
    try:
        model = camera_model(cam.model)
    except FglocError:
        return _fail(rig, index, "model", f"unknown model {cam.model!r} (known: {', '.join(sorted(CAMERA_MODELS))})")
    units = PanTiltUnits(model, mounting(cam.mounting))
    pans = sorted(math.degrees(units.to_spec(c, 0)[0]) for c in (model.pan_min, model.pan_max))
    tilts = sorted(math.degrees(units.to_spec(0, c)[1]) for c in (model.tilt_min, model.tilt_max))
    s, eps = rig.search_for(cam.id), 1e-6
    where = "search" if cam.search is None else f"cameras[{index}].search"
    limits = (("pan_min_deg", s.pan_min, pans[0] - eps <= math.degrees(s.pan_min), pans),
              ("pan_max_deg", s.pan_max, math.degrees(s.pan_max) <= pans[1] + eps, pans),
              ("tilt_min_deg", s.tilt_min, tilts[0] - eps <= math.degrees(s.tilt_min), tilts),
              ("tilt_max_deg", s.tilt_max, math.degrees(s.tilt_max) <= tilts[1] + eps, tilts))
    for name, value, inside, (lo, hi) in limits:
        if not inside:
            axis = name.split("_")[0]
            return PreflightError(
                f"{rig.path}: {where}.{name}: camera {cam.id} ({model.name}, {cam.mounting}) can {axis} only "
                f"{lo:.1f}..{hi:.1f} deg, the search goes to {math.degrees(value):g} deg")
    return None


def check_rig(rig: RigConfig, simulate: bool = False) -> None:
    """Refuse implausible intrinsics, unknown models and search ranges outside a head's range;
    when simulating, the single-frame detector on rendered frames (it reads their textured
    background and static lights as LEDs: every reading wrong, docs/survey.md)."""
    if simulate and rig.simulation.frames == "rendered" and rig.search.detection == "single":
        raise PreflightError(f"{rig.path}: search.detection: 'single' with simulation.frames 'rendered' reads the "
                             "rendered background and static lights as LEDs (every reading wrong); use 'on-off'")
    for i, cam in enumerate(rig.cameras):
        problem = intrinsics_problem(cam.intrinsics)
        if problem is not None:
            raise _fail(rig, i, "intrinsics", problem)
        if enforces_limits(cam, rig, simulate):
            error = _range_problem(rig, i)
            if error is not None:
                raise error


def _describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _permanent(exc: BaseException) -> bool:
    """Errors that a retry cannot fix: a refused login, a video source that does not open."""
    from fgloc.drivers.frames import FrameError
    from fgloc.drivers.sony_cgi import SonyCgiError, SonyCgiServerError

    return isinstance(exc, FrameError) or (isinstance(exc, SonyCgiError) and not isinstance(exc, SonyCgiServerError))


def check_camera(rig: RigConfig, index: int, open_head: Callable[[str], PanTiltHead]) -> None:
    """Open camera ``index``, read its position and grab one frame; nothing moves. Closes the head."""
    from fgloc.drivers.frames import FrameError

    cam = rig.cameras[index]
    stage = {"now": "open"}

    def attempt(_n: int) -> None:
        stage["now"] = "open"
        head = open_head(cam.id)
        try:
            stage["now"] = "position"
            head.position()
            stage["now"] = "frame"
            frame = np.asarray(head.grab_frame())
        finally:
            close = getattr(head, "close", None)
            if callable(close):
                try:
                    close()
                except Exception:  # noqa: BLE001 - a head that failed may fail to close
                    pass
        k = cam.intrinsics
        if frame.ndim not in (2, 3) or frame.shape[:2] != (k.height, k.width):
            stage["now"] = "size"
            raise _fail(rig, index, "intrinsics", f"frames are {'x'.join(map(str, frame.shape[1::-1]))} px "
                        f"(width x height), the intrinsics are for {k.width}x{k.height} px")

    def before_retry(_failures: int, exc: BaseException) -> None:
        logger.info(redact_urls(f"preflight: {cam.id}: retrying after: {_describe(exc)}"))

    policy = RetryPolicy(rig.retry.head_attempts, lambda e: not (_permanent(e) or isinstance(e, PreflightError)),
                         linear(rig.retry.backoff_s))
    try:
        policy.call(attempt, before_retry)
    except PreflightError:
        raise
    except Exception as exc:  # noqa: BLE001 - every driver error becomes one line naming the camera
        if isinstance(exc, FrameError) and stage["now"] == "open":
            raise _fail(rig, index, "video", f"video source does not open: {_describe(exc)}") from None
        if stage["now"] == "frame":
            raise _fail(rig, index, "video", f"no frame from the camera: {_describe(exc)}") from None
        what = "does not answer a position inquiry" if stage["now"] == "position" else "cannot be opened"
        raise _fail(rig, index, "port", f"{what}: {_describe(exc)}") from None


def check_devices(rig: RigConfig, open_head: Callable[[str], PanTiltHead]) -> None:
    """:func:`check_camera` for every camera, in rig order (the first problem is refused)."""
    for i in range(len(rig.cameras)):
        check_camera(rig, i, open_head)
