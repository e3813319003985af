"""Find a lit LED with a pan-tilt head and measure its (pan, tilt): search, centre, read.

Angles are radians in the spec's convention (pan counter-clockwise from above
about the base z axis, tilt = elevation). Image pixels: x right, y down; the
optical axis is the head's pointing direction at (pan, tilt) and the image's
x axis points to decreasing pan (right, seen from behind the camera).

This module holds a small built-in spot detector and the exact pixel -> pan/tilt
conversion (no lens distortion); :class:`SpotFinder` and :class:`PixelModel`
are the seams where the camera-pipeline code (``fgloc.camera.led_detection``,
``fgloc.camera.pixel_angles``) plugs in with undistortion and a better detector.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.geometry import FloatArray, angle_between
from fgloc.core.hardware import PanTiltHead


@dataclass(frozen=True)
class SearchConfig:
    """Where and how cameras look for a lit LED. Angles in radians, times in seconds.

    The pattern is a grid over [pan_min, pan_max] x [tilt_min, tilt_max] with
    cells ``overlap`` times the field of view apart, visited nearest-first from
    where the camera last saw a node. Centring stops when the LED is within
    ``centre_tolerance_px`` of the principal point or after ``max_centre_steps``.
    ``detection`` is ``single`` (brightest spot of one frame above ``threshold``: dark
    scenes) or ``on-off`` (an LED-off and an LED-on frame per look, differenced by
    :func:`fgloc.camera.led_detection.detect_led`: robust to background and static lights).
    """

    pan_min: float = -math.pi
    pan_max: float = math.pi
    tilt_min: float = math.radians(-85.0)
    tilt_max: float = math.radians(20.0)
    overlap: float = 0.8
    centre_tolerance_px: float = 2.0
    max_centre_steps: int = 6
    settle_s: float = 0.0
    led_wait_s: float = 0.0
    method: str = "pixel-offset"
    threshold: int = 64
    detection: str = "single"



IGNORE_RADIUS_PX = 12.0  #: :attr:`LedLocator.ignore`: a masked LED's disk (its blob and the centroid window's reach)


@dataclass(frozen=True)
class Spot:
    """An LED image: sub-pixel centroid (x right, y down) and peak brightness (0..255)."""

    x: float
    y: float
    peak: float


class SpotFinder(Protocol):
    def __call__(self, frame: np.ndarray) -> Spot | None:
        """The lit LED in ``frame``, or None when there is none."""


class PixelModel(Protocol):
    def pixel_to_pan_tilt(self, pan: float, tilt: float, x: float, y: float) -> tuple[float, float]:
        """Bearing (pan, tilt) of pixel (x, y) when the head reads (pan, tilt)."""


SPOT_RADIUS_PX = 10  #: :func:`brightest_spot`'s centroid window reaches this far from the brightest pixel


def brightest_spot(threshold: int = 64, radius: int = SPOT_RADIUS_PX) -> Callable[[np.ndarray], Spot | None]:
    """A detector: the brightest pixel (>= ``threshold``), refined by an intensity centroid.

    The centroid runs over a (2 radius + 1)^2 window with the window's minimum
    subtracted; for a blob of a few pixels' width this is sub-pixel accurate.
    """

    def find(frame: np.ndarray) -> Spot | None:
        img = frame.max(axis=2) if frame.ndim == 3 else frame
        flat = int(np.argmax(img))
        py, px = divmod(flat, img.shape[1])
        peak = float(img[py, px])
        if peak < threshold:
            return None
        y0, y1 = max(py - radius, 0), min(py + radius + 1, img.shape[0])
        x0, x1 = max(px - radius, 0), min(px + radius + 1, img.shape[1])
        win = img[y0:y1, x0:x1].astype(float)
        w = win - win.min()
        total = w.sum()
        if total <= 0:
            return Spot(float(px), float(py), peak)
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return Spot(float((w * xs).sum() / total), float((w * ys).sum() / total), peak)

    return find


def _elevation_matrix(tilt: float) -> FloatArray:
    c, s = math.cos(tilt), math.sin(tilt)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _pan_matrix(pan: float) -> FloatArray:
    c, s = math.cos(pan), math.sin(pan)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class PinholePixelModel:
    """Exact conversion between pixels and base-frame bearings for a head at (pan, tilt).

    Pinhole in closed form; with distortion coefficients, pixels are undistorted by
    :func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt` (same frames). ``bearing_to_pixel``
    (used by the simulated rig) is pinhole only.
    """

    intrinsics: CameraIntrinsics

    def pixel_to_pan_tilt(self, pan: float, tilt: float, x: float, y: float) -> tuple[float, float]:
        k = self.intrinsics
        if any((k.k1, k.k2, k.p1, k.p2, k.k3)):  # undistort: the camera pipeline's exact conversion
            from fgloc.camera.pixel_angles import pixel_to_pan_tilt

            p, t = pixel_to_pan_tilt(k, np.array([x, y]), pan, tilt)
            return float(p), float(t)
        ray = np.array([1.0, -(x - k.cx) / k.fx, -(y - k.cy) / k.fy])
        d = _pan_matrix(pan) @ _elevation_matrix(tilt) @ ray
        return math.atan2(d[1], d[0]), math.atan2(d[2], math.hypot(d[0], d[1]))

    def bearing_to_pixel(self, pan: float, tilt: float, bearing: FloatArray) -> tuple[float, float] | None:
        """Pixel of a base-frame bearing when the head reads (pan, tilt); None if behind."""
        k = self.intrinsics
        r = _elevation_matrix(tilt).T @ _pan_matrix(pan).T @ np.asarray(bearing, float)
        if r[0] <= 1e-9:
            return None
        return k.cx - k.fx * r[1] / r[0], k.cy - k.fy * r[2] / r[0]

    def field_of_view(self) -> tuple[float, float]:
        """(horizontal, vertical) field of view in radians."""
        k = self.intrinsics
        return 2 * math.atan(k.width / (2 * k.fx)), 2 * math.atan(k.height / (2 * k.fy))


def _direction(pan: float, tilt: float) -> FloatArray:
    return np.array([math.cos(tilt) * math.cos(pan), math.cos(tilt) * math.sin(pan), math.sin(tilt)])


def search_cells(search: SearchConfig, fov: tuple[float, float]) -> list[tuple[float, float]]:
    """Grid of (pan, tilt) head positions covering the search range, cells ``overlap`` x FOV apart."""
    step_pan, step_tilt = search.overlap * fov[0], search.overlap * fov[1]
    span = search.pan_max - search.pan_min
    full_circle = span >= 2 * math.pi - 1e-9
    n_pan = max(1, math.ceil(span / step_pan)) + (0 if full_circle else 1)
    pans = search.pan_min + np.arange(n_pan) * (span / (n_pan if full_circle else max(n_pan - 1, 1)))
    n_tilt = max(1, math.ceil((search.tilt_max - search.tilt_min) / step_tilt)) + 1
    tilts = np.linspace(search.tilt_min, search.tilt_max, n_tilt)
    return [(float(p), float(t)) for t in tilts for p in pans]


def nearest_first(cells: list[tuple[float, float]], start: tuple[float, float]) -> list[tuple[float, float]]:
    """Cells sorted by great-circle distance from ``start`` (ties: grid order), deterministic."""
    s = _direction(*start)
    dist = [math.acos(max(-1.0, min(1.0, float(_direction(*c) @ s)))) for c in cells]
    order = sorted(range(len(cells)), key=lambda i: (round(dist[i], 12), i))
    return [cells[i] for i in order]


@dataclass
class MeasureStats:
    """What one measurement cost: head moves and frames grabbed."""

    moves: int = 0
    frames: int = 0


class LedLocator:
    """Search for the lit LED, centre it, and return its (pan, tilt) bearing.

    ``call(op)`` runs one head operation (the runner wraps it with retries and
    reconnects); the locator itself never touches the head directly.
    """

    def __init__(
        self,
        search: SearchConfig,
        pixel_model: PinholePixelModel,
        spot_finder: Callable[[np.ndarray], Spot | None] | None = None,
    ) -> None:
        self.search = search
        self.pixels = pixel_model
        self.find_spot = spot_finder or brightest_spot(search.threshold)
        self.cells = search_cells(search, pixel_model.field_of_view())
        self.stats = MeasureStats()
        self.last_look: tuple[float, float] | None = None  #: (pan, tilt) radians of the last look, None before
        #: (pan, tilt) radians where the head rests after this locator's last operation, None when
        #: unknown. A look within ``centre_tolerance_px`` of it grabs at once, with no move and no
        #: settle. Whoever else drives the head, or may have moved it (another operation, a failure,
        #: a reconnect), sets it to None first (:meth:`fgloc.survey.runner.CameraWorker.call`).
        self.resting_at: tuple[float, float] | None = None
        #: base-frame unit bearings of other lit LEDs whose light is not the one sought (another
        #: camera's node lit at the same time, read by this camera there): with ``single`` detection
        #: each frame is dark within :data:`IGNORE_RADIUS_PX` of them (on-off frames blink only the
        #: sought LED, so the others cancel). The caller keeps the sought LED well away from them.
        self.ignore: list[FloatArray] = []
        # For on-off detection: blink(grab) -> (LED-on frame, LED-off frame); set per node by the runner.
        self.blink: Callable[[Callable[[], np.ndarray]], tuple[np.ndarray, np.ndarray]] | None = None

    def detect(self, call: Callable[[Callable[[PanTiltHead], object]], object],
               at: tuple[float, float] | None = None) -> Spot | None:
        """The lit LED in the current view (one frame, or an on/off pair), or None. ``at``: the
        head's (pan, tilt), radians, where :attr:`ignore` is masked (single detection)."""
        grab = lambda: call(lambda h: h.grab_frame())  # noqa: E731
        if self.search.detection == "on-off":
            from fgloc.camera.led_detection import detect_led

            if self.blink is None:
                raise ValueError("on-off detection needs a blink function")
            on, off = self.blink(grab)  # type: ignore[arg-type]
            result = detect_led(on, off)
            if not result.found or result.detection is None:
                return None
            d = result.detection
            return Spot(d.u, d.v, d.peak)
        frame = grab()
        if self.ignore and at is not None:
            frame = self._masked(np.asarray(frame), at)
        return self.find_spot(frame)  # type: ignore[arg-type]

    def _masked(self, frame: np.ndarray, at: tuple[float, float]) -> np.ndarray:
        """``frame`` (head at ``at``) dark within :data:`IGNORE_RADIUS_PX` of each :attr:`ignore` bearing."""
        out = frame.copy()
        ys, xs = np.ogrid[:frame.shape[0], :frame.shape[1]]
        for bearing in self.ignore:
            px = self.pixels.bearing_to_pixel(at[0], at[1], bearing)
            if px is not None:
                out[(xs - px[0]) ** 2 + (ys - px[1]) ** 2 <= IGNORE_RADIUS_PX ** 2] = 0
        return out

    def clamp(self, pan: float, tilt: float) -> tuple[float, float]:
        """The nearest head position inside the search range (pan wrapped first)."""
        s = self.search
        if s.pan_max - s.pan_min < 2 * math.pi - 1e-9:
            pan = s.pan_min + (pan - s.pan_min) % (2 * math.pi)
            if pan > s.pan_max:  # in the gap: go to the nearer limit
                over = pan - s.pan_max
                under = s.pan_min + 2 * math.pi - pan
                pan = s.pan_max if over <= under else s.pan_min
        return pan, min(max(tilt, s.tilt_min), s.tilt_max)

    def rests_at(self, pan: float, tilt: float) -> bool:
        """Whether the head rests within ``centre_tolerance_px`` of (pan, tilt) radians (:attr:`resting_at`)."""
        if self.resting_at is None:
            return False
        k = self.pixels.intrinsics
        angle = float(angle_between(_direction(*self.resting_at), _direction(pan, tilt)))
        return angle * max(k.fx, k.fy) <= self.search.centre_tolerance_px

    def _look(self, call: Callable[[Callable[[PanTiltHead], object]], object], pan: float, tilt: float) -> Spot | None:
        pan, tilt = self.clamp(pan, tilt)
        here = self.resting_at
        if here is None or not self.rests_at(pan, tilt):  # a head already there only grabs
            call(lambda h: h.move_to(pan, tilt))
            here = (pan, tilt)
            self.stats.moves += 1
            if self.search.settle_s > 0:
                time.sleep(self.search.settle_s)
        self.last_look = (pan, tilt)
        self.stats.frames += 1
        spot = self.detect(call, here)
        self.resting_at = here
        return spot

    def locate(
        self, call: Callable[[Callable[[PanTiltHead], object]], object], start: tuple[float, float]
    ) -> tuple[float, float] | None:
        """(pan, tilt) of the lit LED, or None when the whole pattern shows none.

        Moves never leave the search range: an LED beyond it is measured from the
        frame at the range's edge (pixel-offset method).
        """
        start = self.clamp(*start)
        spot = self._look(call, *start)
        if spot is None:
            for cell in nearest_first(self.cells, start):
                if self.clamp(*cell) == start:
                    continue  # looked at already
                spot = self._look(call, *cell)
                if spot is not None:
                    break
            else:
                return None
        return self._centre_and_read(call, spot)

    def _centre_and_read(self, call: Callable, spot: Spot) -> tuple[float, float] | None:
        k = self.pixels.intrinsics
        for _ in range(self.search.max_centre_steps):
            pan, tilt = call(lambda h: h.position())
            if math.hypot(spot.x - k.cx, spot.y - k.cy) <= self.search.centre_tolerance_px:
                break
            target = self.pixels.pixel_to_pan_tilt(pan, tilt, spot.x, spot.y)
            edge = self.clamp(*target)
            at_edge = abs(math.remainder(edge[0] - target[0], 2 * math.pi)) > 1e-9 or abs(edge[1] - target[1]) > 1e-9
            found = self._look(call, *target)
            if found is None:
                return None
            spot = found
            if at_edge:  # the LED lies beyond the range: measure it off-centre from the edge
                break
        pan, tilt = call(lambda h: h.position())
        self.resting_at = (float(pan), float(tilt))
        if self.search.method == "centre":
            return float(pan), float(tilt)
        return self.pixels.pixel_to_pan_tilt(pan, tilt, spot.x, spot.y)
