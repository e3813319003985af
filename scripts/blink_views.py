"""The seeded rendered view the blink Monte Carlos decode (a helper module, not a script).

Shared by ``scripts/blink_montecarlo.py`` (blind, pair, group and known-partner decodes)
and ``scripts/blink_candidates_montecarlo.py`` (candidate-restricted round views). A view
is 640 x 480 pixels, 65 deg HFOV (640 x 240 fields at twice the rate with ``fields``),
the head at a uniform pan and a tilt in [-0.6, 0.2] rad. :func:`render_motes` records it
with 5 % dropped frames, 1 % duplicated frames, 50 Hz mains flicker on three static lights
(depth 0.5 and 1.0), ``glints`` daylight false blobs, ambient gain noise, head jitter,
timestamp jitter, and mote clocks offset (random start) and drifting (50 ppm); with
``sync`` the motes start at a broadcast epoch instead (each off by up to +-2 ms, drifting
at 50 ppm sd) and the view is recorded a uniform 0..``resync_s`` s after it.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_decoder import SyncTiming
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_synchronized, motes_with_codes, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
from fgloc.survey.coded_readings import field_intrinsics


def view_camera(rng: np.random.Generator, fields: bool) -> tuple[CameraIntrinsics, float, float]:
    """The view's intrinsics (frames, or fields with ``fields``) and the head's (pan, tilt), rad."""
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    if fields:
        intr = field_intrinsics(intr)
    return intr, rng.uniform(-math.pi, math.pi), rng.uniform(-0.6, 0.2)


def video_label(fields: bool) -> str:
    """The video of a report's first line."""
    return "fields 640 x 240 at 59.94 Hz" if fields else "frames 640 x 480 at 29.97 Hz"


def render_motes(rng: np.random.Generator, intr: CameraIntrinsics, head_pan: float, head_tilt: float,
                 pts: np.ndarray, ids: np.ndarray, book: CodeBook, glints: int, fields: bool, sync: bool,
                 resync_s: float, n_frames: int, readout_s: float = 0.0, rate_fall_s: float | None = None,
                 ) -> tuple[list[tuple[float, np.ndarray]], BlinkRenderConfig, float, SyncTiming | None]:
    """Render one view of the motes ``ids`` (book indices) at ``pts`` (base frame) with the
    disturbances of the module docstring: (frames, render config, recording start s, sync timing).
    ``readout_s``, ``rate_fall_s``: rolling shutter and rate fall (:class:`BlinkRenderConfig`)."""
    pos = {f"n{int(i)}": pts[k] for k, i in enumerate(ids)}
    codes = {f"n{int(i)}": book.bits(int(i)) for i in ids}
    cfg = BlinkRenderConfig(glints=glints, duplicate_rate=0.01, readout_s=readout_s, rate_fall_s=rate_fall_s)
    if fields:  # twice the rate; each field collects the light of every second row: half the flux
        cfg = replace(cfg, frame_rate_hz=2.0 * cfg.frame_rate_hz, led_flux=0.5 * cfg.led_flux,
                      static_flux=0.5 * cfg.static_flux,
                      glint_flux=(0.5 * cfg.glint_flux[0], 0.5 * cfg.glint_flux[1]))
    period = round(1.0 / cfg.frame_rate_hz, 5)  # what the motes are told (10 us resolution)
    t_start = 0.0
    timing: SyncTiming | None = None
    if sync:
        t_start = float(rng.uniform(0.0, resync_s))  # since the last synchronized (re)start, epoch 0
        motes = motes_synchronized(pos, codes, period, rng)
        timing = SyncTiming(0.0, period, cfg.exposure_s)
    else:
        motes = motes_with_codes(pos, codes, period, rng)
    spp, stt = pixel_to_pan_tilt(intr, rng.uniform(20, 620, (3, 2)) * [1, intr.height / intr.width], head_pan, head_tilt)
    statics = pan_tilt_bearing(spp, stt) * 20.0
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    return render_view(cam, intr, head_pan, head_tilt, motes, n_frames, rng, cfg, statics, t_start), cfg, t_start, timing


def add_view_arguments(ap: argparse.ArgumentParser) -> None:
    """The flags both Monte Carlos share: runs, motes, book, glints, seed, video and samples."""
    ap.add_argument("--trials", type=int, default=250)
    ap.add_argument("--motes", type=int, default=40)
    ap.add_argument("--book", type=int, default=100)
    ap.add_argument("--glints", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fields", action="store_true", help="decode 59.94 Hz fields (640 x 240), not frames")
    ap.add_argument("--frames", type=int, default=None, help="frames per view (default 3L + 2)")
