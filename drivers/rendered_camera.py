"""Simulated twin of a PTZ camera: renders the frame a head at (pan, tilt, zoom) would see.

The truth source for tests and ``fgloc survey --simulate``. Model:

* The camera base sits at ``pose`` (:class:`fgloc.core.model.CameraPose`, base -> world).
  The optical centre lies on the pan and tilt axes; the head rotation and the
  optical frame are those of :mod:`fgloc.camera.pixel_angles`.
* Pinhole + OpenCV distortion from :class:`fgloc.camera.intrinsics.CameraIntrinsics`
  (``intrinsics.at_zoom`` for other zooms: focal length x1 ... x10).
* Background: smooth random texture fixed to directions in the base frame (it
  moves across the image when the head turns), plus static bright lights
  (``LedScene.distractors``, always on, may saturate).
* Lit LEDs: an integrated (pixel-area) Gaussian spot of ``led_flux`` DN in
  total and ``led_sigma_px`` width, centred exactly at the LED's distorted
  projection, so the centroid truth is exact.
* Sensor noise: Gaussian, variance ``read_noise^2 + shot_gain * signal`` (DN),
  seeded; then rounding and clipping to uint8.
* Head errors (optional, :mod:`fgloc.core.head_model`): an imperfect head at encoder
  readings (pan, tilt) looks where :mod:`fgloc.drivers.imperfect_head` says; frames show
  LEDs, background and static lights through the real camera frame and optical centre, so
  the encoders read the imperfect head's angles when an LED is centred.

Grayscale uint8 frames. Everything is numpy; the background of a view is
cached, and each frame only renders small patches around spots.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import base_to_pixel, in_image, optical_to_base, pixel_to_ray
from fgloc.core.geometry import FloatArray, pan_tilt_bearing, world_to_base
from fgloc.core.model import CameraPose
from fgloc.drivers.imperfect_head import head_view, ideal_equivalent_directions

_erf = np.frompyfunc(math.erf, 1, 1)


@dataclass
class LedScene:
    """World points: node LEDs (``positions``, id -> (3,)), which are lit (``lit``, mutable),
    and static bright lights that are always on (``distractors``, (K, 3) world points)."""

    positions: dict[str, np.ndarray]
    lit: set[str] = field(default_factory=set)
    distractors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


class SimulatedLedController:
    """:class:`fgloc.core.hardware.LedController` twin: switches LEDs in a :class:`LedScene`."""

    def __init__(self, scene: LedScene) -> None:
        self.scene = scene

    def set_led(self, node_id: str, on: bool) -> bool:
        """Switch ``node_id``'s LED; False (no acknowledgement) for an unknown node."""
        if node_id not in self.scene.positions:
            return False
        (self.scene.lit.add if on else self.scene.lit.discard)(node_id)
        return True


@dataclass(frozen=True)
class RenderSettings:
    """Photometry of the rendered frames (DN = uint8 grey levels, sizes in pixels)."""

    led_flux: float = 1500.0  #: total LED spot signal (DN summed over pixels)
    led_sigma_px: float = 1.2  #: LED spot (PSF) standard deviation
    background_mean: float = 50.0  #: mean background level
    black_level: float = 12.0  #: darkest background level (sensor black offset)
    background_contrast: float = 20.0  #: texture amplitude (std-ish)
    texture_seed: int = 7  #: seed of the background texture (fixed to the world)
    distractor_flux: float = 20000.0  #: total signal of a static bright light (saturates its core)
    distractor_sigma_px: float = 2.5  #: size of a static bright light
    read_noise: float = 1.5  #: read noise sigma (DN)
    shot_gain: float = 0.05  #: shot noise variance per DN of signal


def _integrated_gaussian_1d(centre: float, sigma: float, lo: int, hi: int) -> np.ndarray:
    """Fraction of a unit 1-D Gaussian falling in each pixel lo..hi-1 (pixel k spans k +- 0.5)."""
    edges = (np.arange(lo, hi + 1, dtype=float) - 0.5 - centre) / (sigma * math.sqrt(2.0))
    cdf = 0.5 * (1.0 + np.asarray(_erf(edges), dtype=float))
    return np.diff(cdf)


def add_spot(image: np.ndarray, u: float, v: float, flux: float, sigma: float) -> None:
    """Add an integrated Gaussian spot (total ``flux`` DN) centred at pixel (u, v), in place."""
    h, w = image.shape
    half = int(math.ceil(5.0 * sigma)) + 1
    c0, c1 = max(int(math.floor(u)) - half, 0), min(int(math.floor(u)) + half + 2, w)
    r0, r1 = max(int(math.floor(v)) - half, 0), min(int(math.floor(v)) + half + 2, h)
    if c0 >= c1 or r0 >= r1:
        return
    gx = _integrated_gaussian_1d(u, sigma, c0, c1)
    gy = _integrated_gaussian_1d(v, sigma, r0, r1)
    image[r0:r1, c0:c1] += flux * np.outer(gy, gx)


_RAY_CACHE: OrderedDict[CameraIntrinsics, np.ndarray] = OrderedDict()


_RAY_LOCK = threading.Lock()


def _pixel_rays(intr: CameraIntrinsics) -> np.ndarray:
    """Unit optical rays (H, W, 3) float32 of every pixel; cached for the last few models.
    Thread-safe (survey code runs one thread per camera)."""
    with _RAY_LOCK:
        rays = _RAY_CACHE.get(intr)
        if rays is not None:
            _RAY_CACHE.move_to_end(intr)
            return rays
    jj, ii = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    rays = pixel_to_ray(intr, np.stack([jj, ii], axis=-1)).astype(np.float32)
    with _RAY_LOCK:
        _RAY_CACHE[intr] = rays
        while len(_RAY_CACHE) > 4:
            _RAY_CACHE.popitem(last=False)
    return rays


class RenderedCamera:
    """Renders frames of one camera base looking at an :class:`LedScene`."""

    def __init__(self, pose: CameraPose, scene: LedScene, settings: RenderSettings | None = None) -> None:
        self.pose = pose
        self.scene = scene
        self.settings = settings or RenderSettings()
        rng = np.random.default_rng(self.settings.texture_seed)
        # Random plane waves on the direction sphere: periods of ~1 to ~6 degrees.
        freqs = rng.uniform(10.0, 60.0, size=8)
        dirs = rng.normal(size=(8, 3))
        self._waves = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * freqs[:, None]
        self._phases = rng.uniform(0.0, 2.0 * np.pi, size=8)
        self._backgrounds: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    # ----- truth -------------------------------------------------------------------------
    def base_directions(self, points: np.ndarray, pan: float = 0.0, tilt: float = 0.0, pupil_shift: float = 0.0) -> np.ndarray:
        """World point(s) (..., 3) as base-frame vectors from the optical centre.

        The optical centre is the base position moved ``pupil_shift`` (survey units) forward
        along the optical axis of the head at (pan, tilt); 0 means on the rotation axes."""
        q = world_to_base(self.pose.rotation, self.pose.position, points)
        if pupil_shift:
            q = q - pupil_shift * pan_tilt_bearing(pan, tilt)
        return q

    def led_pixels(
        self, intrinsics: CameraIntrinsics, pan: float, tilt: float, margin: float = 0.0, pupil_shift: float = 0.0
    ) -> dict[str, tuple[float, float]]:
        """True pixel (u, v) of every node LED (lit or not) in the image at least ``margin`` px inside."""
        if not self.scene.positions:
            return {}
        ids = list(self.scene.positions)
        pts = np.array([self.scene.positions[i] for i in ids], dtype=float)
        uv, front = base_to_pixel(intrinsics, self.base_directions(pts, pan, tilt, pupil_shift), pan, tilt)
        ok = front & in_image(intrinsics, uv, margin)
        return {i: (float(uv[k, 0]), float(uv[k, 1])) for k, i in enumerate(ids) if ok[k]}

    # ----- rendering ---------------------------------------------------------------------
    def _pixel_rays(self, intr: CameraIntrinsics) -> np.ndarray:
        return _pixel_rays(intr)

    def background(self, intr: CameraIntrinsics, pan: float, tilt: float,
                   correction: FloatArray | None = None) -> np.ndarray:
        """Noise-free background (float32 DN, distractors included) for a view; cached.

        ``correction`` (3x3): the real camera frame is ``correction @ optical_to_base(pan, tilt)``
        (a head with errors, :func:`fgloc.drivers.imperfect_head.head_view`); None: the ideal head."""
        key = (intr, round(pan, 12), round(tilt, 12), None if correction is None else np.round(correction, 15).tobytes())
        with self._lock:
            bg = self._backgrounds.get(key)
            if bg is not None:
                self._backgrounds.move_to_end(key)
                return bg
        s = self.settings
        view = optical_to_base(pan, tilt) if correction is None else correction @ optical_to_base(pan, tilt)
        d = self._pixel_rays(intr) @ view.T.astype(np.float32)
        phase = d @ self._waves.T.astype(np.float32) + self._phases.astype(np.float32)
        tex = np.sin(phase).sum(axis=-1) * (s.background_contrast / 2.0)
        bg = (s.background_mean + tex).astype(np.float32)
        np.maximum(bg, s.black_level, out=bg)
        if len(self.scene.distractors):
            lights = self.base_directions(self.scene.distractors)
            if correction is not None:
                lights = lights @ correction
            uv, front = base_to_pixel(intr, lights, pan, tilt)
            for k in np.flatnonzero(front & in_image(intr, uv, -10.0)):
                add_spot(bg, float(uv[k, 0]), float(uv[k, 1]), s.distractor_flux, s.distractor_sigma_px)
        with self._lock:
            self._backgrounds[key] = bg
            while len(self._backgrounds) > 4:
                self._backgrounds.popitem(last=False)
        return bg

    def render(
        self, intr: CameraIntrinsics, pan: float, tilt: float, rng: np.random.Generator, pupil_shift: float = 0.0
    ) -> np.ndarray:
        """A noisy uint8 (H, W) frame with the head at (pan, tilt) radians through ``intr``
        (optical centre ``pupil_shift`` forward of the rotation axes, see ``base_directions``)."""
        lit = [i for i in sorted(set(self.scene.lit)) if i in self.scene.positions]
        directions = np.zeros((0, 3))
        if lit:
            pts = np.array([self.scene.positions[i] for i in lit], dtype=float)
            directions = self.base_directions(pts, pan, tilt, pupil_shift)
        return self.render_directions(intr, pan, tilt, rng, directions)

    def render_directions(
        self, intr: CameraIntrinsics, pan: float, tilt: float, rng: np.random.Generator, directions: np.ndarray,
        correction: FloatArray | None = None,
    ) -> np.ndarray:
        """A noisy uint8 (H, W) frame with the head at (pan, tilt) radians through ``intr``, with a
        lit LED spot along each base-frame direction of ``directions`` (K, 3) (any length), on
        this camera's background and static lights (``scene.distractors``). With a head's
        ``correction`` (see :meth:`background`) ``directions`` are already those the ideal head
        would show (:func:`fgloc.drivers.imperfect_head.ideal_equivalent_directions`)."""
        s = self.settings
        img = self.background(intr, pan, tilt, correction).copy()
        if len(directions):
            uv, front = base_to_pixel(intr, np.asarray(directions, dtype=float), pan, tilt)
            for k in np.flatnonzero(front & in_image(intr, uv, -10.0)):
                add_spot(img, float(uv[k, 0]), float(uv[k, 1]), s.led_flux, s.led_sigma_px)
        noise_sd = np.sqrt(s.read_noise**2 + s.shot_gain * img)
        img += noise_sd * rng.standard_normal(img.shape, dtype=np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


class SimulatedHead:
    """:class:`fgloc.core.hardware.PanTiltHead` twin, in process: angles are stored, ``grab_frame`` renders.

    ``angle_step`` (radians, e.g. ``math.radians(1 / 14.4)`` for the EVI-D100) quantises
    where the head actually goes; ``position()`` reads back the quantised angles exactly.
    The frame is rendered through ``intrinsics.at_zoom(zoom())``. ``pupil_shift_at_tele``
    (survey units) moves the optical centre forward along the optical axis in proportion to
    zoom, 0 at the widest zoom: the effect that makes only the widest zoom trustworthy.
    ``head_errors`` (7,) makes it an imperfect head (:mod:`fgloc.core.head_model` order and
    units): ``position()`` then reads the encoders of a head that looks where
    :mod:`fgloc.drivers.imperfect_head` says.
    """

    def __init__(
        self,
        pose: CameraPose,
        scene: LedScene,
        intrinsics: CameraIntrinsics,
        seed: int = 0,
        angle_step: float | None = None,
        settings: RenderSettings | None = None,
        pupil_shift_at_tele: float = 0.0,
        head_errors: FloatArray | None = None,
    ) -> None:
        self.camera = RenderedCamera(pose, scene, settings)
        self.head_errors = None if head_errors is None or not np.any(head_errors) else np.asarray(head_errors, float)
        self.pupil_shift_at_tele = pupil_shift_at_tele
        self.intrinsics = intrinsics
        self.angle_step = angle_step
        self.rng = np.random.default_rng(seed)
        self._pan = 0.0
        self._tilt = 0.0
        self._zoom = intrinsics.zoom
        self.moves = 0

    @property
    def scene(self) -> LedScene:
        return self.camera.scene

    def _quantise(self, angle: float) -> float:
        if not self.angle_step:
            return float(angle)
        return float(round(angle / self.angle_step) * self.angle_step)

    def move_to(self, pan: float, tilt: float) -> None:
        self._pan, self._tilt = self._quantise(pan), self._quantise(tilt)
        self.moves += 1

    def position(self) -> tuple[float, float]:
        return (self._pan, self._tilt)

    def set_zoom(self, zoom: float) -> None:
        self._zoom = float(min(max(zoom, 0.0), 1.0))

    def zoom(self) -> float:
        return self._zoom

    def stop(self) -> None:
        pass

    def home(self) -> None:
        self.move_to(0.0, 0.0)

    def current_intrinsics(self) -> CameraIntrinsics:
        """True intrinsics at the current zoom."""
        if self._zoom == self.intrinsics.zoom:
            return self.intrinsics
        return self.intrinsics.at_zoom(self._zoom)

    def _imperfect_directions(self, ids: list[str]) -> np.ndarray:
        """What the ideal head shows where this imperfect head sees the LEDs ``ids``."""
        assert self.head_errors is not None
        if not ids:
            return np.zeros((0, 3))
        pts = np.array([self.scene.positions[i] for i in ids], dtype=float)
        q = world_to_base(self.camera.pose.rotation, self.camera.pose.position, pts)
        return ideal_equivalent_directions(self.head_errors, self._pan, self._tilt, q, self.pupil_shift())

    def grab_frame(self) -> np.ndarray:
        if self.head_errors is None:
            return self.camera.render(self.current_intrinsics(), self._pan, self._tilt, self.rng, self.pupil_shift())
        lit = [i for i in sorted(set(self.scene.lit)) if i in self.scene.positions]
        return self.camera.render_directions(self.current_intrinsics(), self._pan, self._tilt, self.rng,
                                             self._imperfect_directions(lit),
                                             correction=head_view(self.head_errors, self._pan, self._tilt)[0])

    def visible_leds(self, margin: float = 0.0) -> dict[str, tuple[float, float]]:
        """Truth: pixel of every node LED in the current view (lit or not)."""
        intr = self.current_intrinsics()
        if self.head_errors is None:
            return self.camera.led_pixels(intr, self._pan, self._tilt, margin, self.pupil_shift())
        ids = list(self.scene.positions)
        uv, front = base_to_pixel(intr, self._imperfect_directions(ids), self._pan, self._tilt)
        ok = front & in_image(intr, uv, margin)
        return {i: (float(uv[k, 0]), float(uv[k, 1])) for k, i in enumerate(ids) if ok[k]}

    def pupil_shift(self) -> float:
        """Current optical-centre offset along the optical axis (survey units), 0 at the widest zoom."""
        return self.pupil_shift_at_tele * self._zoom


def simulated_rig(
    cameras: dict[str, CameraPose],
    nodes: dict[str, np.ndarray],
    intrinsics: CameraIntrinsics,
    seed: int = 0,
    angle_step: float | None = None,
    settings: RenderSettings | None = None,
    distractors: np.ndarray | None = None,
    head_errors: dict[str, FloatArray] | None = None,
) -> tuple[dict[str, SimulatedHead], SimulatedLedController]:
    """Heads for every camera pose (camera i seeded ``seed + i``) looking at one shared
    :class:`LedScene` of ``nodes``, and the LED controller that switches them;
    ``head_errors`` (camera id -> (7,), :mod:`fgloc.core.head_model`) makes heads imperfect.

    E.g. ``simulated_rig(survey.truth.cameras, survey.truth.nodes, intrinsics)``.
    """
    scene = LedScene(
        positions={k: np.asarray(v, dtype=float) for k, v in nodes.items()},
        distractors=np.zeros((0, 3)) if distractors is None else np.asarray(distractors, dtype=float),
    )
    heads = {
        cam_id: SimulatedHead(pose, scene, intrinsics, seed=seed + i, angle_step=angle_step, settings=settings,
                              head_errors=(head_errors or {}).get(cam_id))
        for i, (cam_id, pose) in enumerate(cameras.items())
    }
    return heads, SimulatedLedController(scene)
