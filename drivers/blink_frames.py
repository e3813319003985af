"""Rendered video of a view full of blinking motes: codes, flicker, glints, drops, clock drift.

Extends :mod:`fgloc.drivers.rendered_camera` (its background texture, spot model and
noise) with time. Seeded: the same ``rng`` state gives the same frames.

* **Motes** (:class:`BlinkingMote`): each repeats its code word (bit L-1 first, LED on
  for a 1 bit) from its own start time ``t0`` with its own bit period (the commanded
  period times ``1 + ppm 1e-6``: crystal error, so motes drift against the camera).
* **Exposure**: a frame starting at ``t`` integrates ``[t, t + exposure_s]``; an LED
  contributes ``led_flux`` times the exact fraction of that window it was on (a bit
  edge inside the exposure gives an intermediate level).
* **Static lights** (``statics``, world points): always on, ``static_flux`` mean,
  modulated by mains flicker ``1 + depth cos(2 pi 2 f_mains t + phase)`` (lamps flicker
  at twice the mains frequency), integrated over the exposure.
* **Daylight glints** (``glints`` per view): false blobs at random pixels that switch on
  and off at random (a two-state Markov chain per frame, ``glint_on`` / ``glint_stay``),
  each with its own brightness that also varies frame to frame.
* **Video**: frames at ``frame_rate_hz`` from ``t_start``; a frame is lost with
  probability ``drop_rate`` (not delivered), or replaced by a copy of the previous
  delivered image with ``duplicate_rate`` (a grabber re-delivering a stale buffer,
  stamped with the new time); timestamps carry ``timestamp_jitter_s`` Gaussian
  jitter; the head vibrates by ``jitter_px`` (Gaussian, per frame, all spots); the
  global brightness varies by ``ambient_sd`` (fraction, per frame).
* **Rolling shutter** (``readout_s``, default 0: a CCD such as the EVI-D100's exposes every
  row at once): row ``v`` starts its exposure ``v / height x readout_s`` after row 0, so
  an LED (or lamp) is sampled at its centre row's time. The few rows of one spot differ
  by ``rows / height x readout_s`` (0.35 ms for 5 of 480 rows at a 33 ms readout, against
  a 2 ms exposure): that spread within a spot is left out.
* **Rate fall** (``rate_fall_s``, default None): from ``t_start + rate_fall_s`` on the
  camera delivers only every second frame, as a camera falling from 60 to 30 Hz (or a
  grabber that cannot keep up) does.

Frames are grayscale uint8 (H, W); timestamps are seconds on the camera host's clock.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import base_to_pixel, in_image, pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.drivers.rendered_camera import RenderedCamera, add_spot


@dataclass(frozen=True)
class BlinkRenderConfig:
    """Video and disturbance parameters (seconds, pixels, DN; rates are probabilities)."""

    frame_rate_hz: float = 30000.0 / 1001.0
    exposure_s: float = 0.002
    led_flux: float = 1500.0
    led_sigma_px: float = 1.2
    drop_rate: float = 0.05
    duplicate_rate: float = 0.0
    timestamp_jitter_s: float = 0.001
    jitter_px: float = 0.05
    ambient_sd: float = 0.02
    mains_hz: float = 50.0
    flicker_depth: float = 0.5
    static_flux: float = 20000.0
    static_sigma_px: float = 2.5
    glints: int = 0
    glint_flux: tuple[float, float] = (500.0, 3000.0)
    glint_on: float = 0.3
    glint_stay: float = 0.6
    glint_sigma_px: float = 1.5
    readout_s: float = 0.0  #: rolling shutter: delay of the last row's exposure after the first's
    rate_fall_s: float | None = None  #: from this long after the start on, every second frame is lost


@dataclass(frozen=True)
class BlinkingMote:
    """A mote repeating ``bits`` (0/1, transmission order) every ``bit_period_s`` from ``t0`` (s)."""

    node: str
    position: np.ndarray
    bits: np.ndarray
    bit_period_s: float
    t0: float

    def on_fraction(self, t: np.ndarray, exposure: float) -> np.ndarray:
        """Fraction of each exposure window ``[t, t + exposure]`` the LED was on (exact)."""
        return (self._cumulative_on(t + exposure) - self._cumulative_on(t)) / exposure

    def _cumulative_on(self, t: np.ndarray) -> np.ndarray:
        b = np.asarray(self.bits, dtype=float)
        length = b.size
        prefix = np.concatenate([[0.0], np.cumsum(b)])
        s = np.maximum(np.asarray(t, dtype=float) - self.t0, 0.0) / self.bit_period_s
        n = np.floor(s).astype(np.int64)
        frac = s - n
        cycles, r = np.divmod(n, length)
        return (cycles * prefix[length] + prefix[r] + frac * b[r]) * self.bit_period_s


def motes_with_codes(
    positions: dict[str, np.ndarray], codes: dict[str, np.ndarray], bit_period_s: float,
    rng: np.random.Generator, ppm_sd: float = 50.0, start_spread_s: float = 10.0,
) -> list[BlinkingMote]:
    """Motes started at random times within ``start_spread_s`` before 0 with crystal errors of
    ``ppm_sd`` parts per million (Gaussian): what unsynchronised unicast start commands give."""
    out = []
    for node in positions:
        ppm = rng.normal(0.0, ppm_sd)
        out.append(BlinkingMote(node, np.asarray(positions[node], float), np.asarray(codes[node], np.uint8),
                                bit_period_s * (1.0 + 1e-6 * ppm), -rng.uniform(0.0, start_spread_s)))
    return out


def motes_lit(
    lit: Mapping[int, tuple[int, int]], positions: Mapping[int, np.ndarray], bit_period_s: float,
    rng: np.random.Generator, ppm_sd: float = 50.0, start_spread_s: float = 10.0,
) -> list[BlinkingMote]:
    """The motes a blink field shows: ``lit[address] = (length, code)`` (e.g.
    ``BlinkField.lit()``: running and not paused; a paused mote is dark, so it is not
    rendered), each at ``positions[address]``, started as in :func:`motes_with_codes`."""
    nodes = [a for a in sorted(lit) if a in positions]
    codes = {f"{a}": np.array([(lit[a][1] >> (lit[a][0] - 1 - i)) & 1 for i in range(lit[a][0])], np.uint8)
             for a in nodes}
    return motes_with_codes({f"{a}": np.asarray(positions[a], float) for a in nodes}, codes, bit_period_s, rng,
                            ppm_sd, start_spread_s)


def motes_synchronized(
    positions: dict[str, np.ndarray], codes: dict[str, np.ndarray], bit_period_s: float,
    rng: np.random.Generator, epoch_s: float = 0.0, offset_s: float = 0.002, ppm_sd: float = 50.0,
) -> list[BlinkingMote]:
    """Motes that started bit 0 of their word at a broadcast ``epoch_s`` (camera host clock),
    each off by a uniform ``+-offset_s`` (radio and serial latency the host does not
    know) and drifting by a Gaussian crystal error of ``ppm_sd`` parts per million from
    then on: what a synchronized (re)start gives. Records long after the epoch see the
    drift accumulate (``t_start`` of :func:`render_view`)."""
    out = []
    for node in positions:
        ppm = rng.normal(0.0, ppm_sd)
        out.append(BlinkingMote(node, np.asarray(positions[node], float), np.asarray(codes[node], np.uint8),
                                bit_period_s * (1.0 + 1e-6 * ppm), epoch_s + rng.uniform(-offset_s, offset_s)))
    return out


def _flicker_mean(t: np.ndarray, exposure: float, freq: float, depth: float, phase: float) -> np.ndarray:
    """Mean of ``1 + depth cos(w t' + phase)`` over ``[t, t + exposure]``, w = 2 pi freq."""
    w = 2.0 * math.pi * freq
    return 1.0 + depth * (np.sin(w * (t + exposure) + phase) - np.sin(w * t + phase)) / (w * exposure)


def _row_delay(v: float, height: int, readout_s: float) -> float:
    """Seconds after row 0 at which row ``v`` (pixels, clipped to the image) starts its exposure."""
    return min(max(float(v), 0.0), float(height - 1)) / height * readout_s


def render_view(
    camera: RenderedCamera, intr: CameraIntrinsics, pan: float, tilt: float,
    motes: Sequence[BlinkingMote], n_frames: int, rng: np.random.Generator,
    config: BlinkRenderConfig | None = None, statics: np.ndarray | None = None, t_start: float = 0.0,
) -> list[tuple[float, np.ndarray]]:
    """``(timestamp, frame)`` of the frames delivered while the head at (pan, tilt) radians
    records ``n_frames`` frame periods from ``t_start`` (dropped frames are missing)."""
    c = config or BlinkRenderConfig()
    s = camera.settings
    period = 1.0 / c.frame_rate_hz
    t = t_start + period * np.arange(n_frames)
    bg = camera.background(intr, pan, tilt)  # static texture (+ the scene's always-on distractors)
    h, w = bg.shape
    spots: list[tuple[float, float, np.ndarray, float]] = []  # (u, v, flux per frame, sigma)
    if motes:
        pts = np.array([m.position for m in motes], dtype=float)
        uv, front = base_to_pixel(intr, camera.base_directions(pts), pan, tilt)
        for k in np.flatnonzero(front & in_image(intr, uv, -10.0)).tolist():
            flux = c.led_flux * motes[k].on_fraction(t + _row_delay(uv[k, 1], h, c.readout_s), c.exposure_s)
            spots.append((float(uv[k, 0]), float(uv[k, 1]), flux, c.led_sigma_px))
    if statics is not None and len(statics):
        uv, front = base_to_pixel(intr, camera.base_directions(np.asarray(statics, float)), pan, tilt)
        for k in np.flatnonzero(front & in_image(intr, uv, -10.0)).tolist():
            phase = rng.uniform(0.0, 2.0 * math.pi)
            flux = c.static_flux * _flicker_mean(t + _row_delay(uv[k, 1], h, c.readout_s), c.exposure_s,
                                                 2.0 * c.mains_hz, c.flicker_depth, phase)
            spots.append((float(uv[k, 0]), float(uv[k, 1]), flux, c.static_sigma_px))
    for _ in range(c.glints):
        on = np.zeros(n_frames, dtype=bool)
        state = rng.random() < c.glint_on
        for i in range(n_frames):
            if rng.random() > c.glint_stay:
                state = rng.random() < c.glint_on
            on[i] = state
        level = rng.uniform(*c.glint_flux) * rng.uniform(0.5, 1.5, size=n_frames)
        spots.append((rng.uniform(5.0, w - 6.0), rng.uniform(5.0, h - 6.0), level * on, c.glint_sigma_px))
    frames: list[tuple[float, np.ndarray]] = []
    previous: np.ndarray | None = None
    fallen = n_frames if c.rate_fall_s is None else int(np.searchsorted(t - t_start, c.rate_fall_s - 1e-12))
    for i in range(n_frames):
        drop, dup = rng.random() < c.drop_rate, rng.random() < c.duplicate_rate
        du, dv = rng.normal(0.0, c.jitter_px, size=2)
        gain = 1.0 + c.ambient_sd * rng.standard_normal()
        stamp = float(t[i] + c.timestamp_jitter_s * rng.standard_normal())
        if drop or (i >= fallen and (i - fallen) % 2 == 1):
            continue
        if dup and previous is not None:
            frames.append((stamp, previous.copy()))
            continue
        img = bg * np.float32(gain)
        for u, v, flux, sigma in spots:
            if flux[i] > 0.0:
                add_spot(img, u + du, v + dv, float(flux[i]), sigma)
        noise_sd = np.sqrt(s.read_noise**2 + s.shot_gain * img)
        img += noise_sd * rng.standard_normal(img.shape, dtype=np.float32)
        previous = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        frames.append((stamp, previous))
    return frames


def points_at_pixels(intr: CameraIntrinsics, pan: float, tilt: float, uv: np.ndarray,
                     distance: np.ndarray | float = 10.0) -> np.ndarray:
    """(N, 3) base-frame points that a camera with ``intr`` at head (``pan``, ``tilt``) radians
    sees at pixels ``uv`` ((N, 2), OpenCV convention), ``distance`` (base units) from the
    camera (a base at the origin with the identity rotation, as a ``RenderedCamera`` posed
    so): e.g. two motes a sub-pixel or few-pixel distance apart, one crowded blob."""
    p, t = pixel_to_pan_tilt(intr, np.asarray(uv, float), pan, tilt)
    d = np.broadcast_to(np.asarray(distance, float), np.shape(p))
    return np.asarray(pan_tilt_bearing(p, t) * d[..., None])


def close_pairs(centres: np.ndarray, separation_px: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(2N, 2) pixels of N pairs of LEDs: pair k straddles ``centres[k]`` ((N, 2) px) at
    ``separation_px[k]`` apart in a uniformly random direction (rows 2k and 2k + 1)."""
    c = np.asarray(centres, float)
    ang = rng.uniform(0.0, math.pi, len(c))
    half = 0.5 * np.asarray(separation_px, float)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    return np.stack([c - half, c + half], axis=1).reshape(-1, 2)


def close_groups(n: int, size: int, width: float, height: float, rng: np.random.Generator,
                 others: np.ndarray | None = None, link_px: float = 4.0, clear_px: float = 4.0,
                 margin_px: float = 20.0) -> np.ndarray:
    """(n size, 2) pixels of ``n`` crowded groups of ``size`` LEDs (rows ``size k`` ..
    ``size k + size - 1``): each LED after a group's first (uniform in the image, ``margin_px``
    from its edges) lies ``link_px sqrt(U)`` px from a uniformly chosen earlier LED of the
    group in a uniformly random direction (a connected group at the ``link_px`` conflict
    criterion, spaced as uniformly scattered motes); no pixel of ``others`` ((M, 2)) or of an
    earlier group lies within ``clear_px`` of any LED of a group."""
    placed = np.zeros((0, 2)) if others is None else np.asarray(others, float).reshape(-1, 2)
    out: list[np.ndarray] = []
    while len(out) < n:
        pts = [np.array([rng.uniform(margin_px, width - margin_px), rng.uniform(margin_px, height - margin_px)])]
        for _ in range(size - 1):
            a = rng.uniform(0.0, 2.0 * math.pi)
            base = pts[int(rng.integers(len(pts)))]
            pts.append(base + link_px * math.sqrt(rng.uniform()) * np.array([math.cos(a), math.sin(a)]))
        g = np.array(pts)
        if not ((g >= 2.0).all() and (g[:, 0] <= width - 3.0).all() and (g[:, 1] <= height - 3.0).all()):
            continue
        if len(placed) and float(np.min(np.hypot(placed[:, None, 0] - g[None, :, 0],
                                                 placed[:, None, 1] - g[None, :, 1]))) < clear_px:
            continue
        out.append(g)
        placed = np.vstack([placed, g])
    return np.vstack(out) if out else np.zeros((0, 2))
