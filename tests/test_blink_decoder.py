"""Blink decoder on seeded rendered views: right IDs, refused pairs, no mislabels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import CodeBook, code_book
from fgloc.camera.blink_decoder import ViewDecode, decode_view, sample_stack
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkingMote, BlinkRenderConfig, motes_with_codes, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
from fgloc.survey.field_plans import frames_for

INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
BOOK = code_book(100)


def _view(seed: int, uv: np.ndarray, ids: list[int], book: CodeBook = BOOK, glints: int = 0,
          drop: float = 0.05) -> tuple[ViewDecode, float, float]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    p, t = pixel_to_pan_tilt(INTR, uv, pan, tilt)
    pts = pan_tilt_bearing(p, t) * rng.uniform(3.0, 20.0, len(ids))[:, None]
    pos = {f"m{k}": pts[k] for k in range(len(ids))}
    cfg = BlinkRenderConfig(glints=glints, drop_rate=drop, duplicate_rate=0.01)
    motes = motes_with_codes(pos, {f"m{k}": book.bits(i) for k, i in enumerate(ids)}, round(1 / cfg.frame_rate_hz, 5), rng)
    sp, st = pixel_to_pan_tilt(INTR, np.array([[60.0, 60.0], [250.0, 180.0]]), pan, tilt)
    statics = pan_tilt_bearing(sp, st) * 30.0
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    frames = render_view(cam, INTR, pan, tilt, motes, frames_for(book.length), rng, cfg, statics)
    return decode_view(frames, 1 / cfg.frame_rate_hz, book, INTR, pan, tilt), pan, tilt


def test_ids_centroids_and_angles() -> None:
    uv = np.array([[50.0, 200.0], [160.3, 120.7], [280.0, 40.0], [100.0, 100.0], [220.0, 190.0]])
    ids = [3, 17, 42, 64, 99]
    res, pan, tilt = _view(1, uv, ids)
    got = {r.index: r for r in res.readings}
    assert set(got) <= set(ids) and len(got) >= 4  # a miss is allowed, a wrong ID is not
    for k, i in enumerate(ids):
        if i in got:
            r = got[i]
            assert math.hypot(r.u - uv[k, 0], r.v - uv[k, 1]) < 0.3
            p, t = pixel_to_pan_tilt(INTR, uv[k], pan, tilt)
            assert abs(math.remainder(r.pan - float(p), 2 * math.pi)) < 1e-3 and abs(r.tilt - float(t)) < 1e-3


def test_pair_closer_than_the_detector_separates_is_reported_not_guessed() -> None:
    uv = np.array([[150.0, 120.0], [152.2, 120.6], [60.0, 60.0 + 100.0]])
    res, _, _ = _view(2, uv, [5, 6, 7])
    assert not any(r.index in (5, 6) for r in res.readings)
    assert any(math.hypot(a.u - 151.0, a.v - 120.3) < 3.0 for a in res.ambiguous())


def test_duplicate_codes_both_refused() -> None:
    uv = np.array([[100.0, 60.0], [200.0, 180.0], [160.0, 120.0]])
    res, _, _ = _view(3, uv, [8, 8, 9], drop=0.0)
    assert all(r.index != 8 for r in res.readings)
    assert sum(1 for f in res.refused if f.kind == "duplicate") == 2


def test_sample_stack_erases_drops_and_repeats() -> None:
    a, b = np.zeros((2, 2), np.uint8), np.ones((2, 2), np.uint8)
    stack, valid = sample_stack([(0.0, a), (0.1, b), (0.2, b), (0.4, a)], 0.1)
    assert list(valid) == [True, True, False, False, True]


@pytest.mark.parametrize("seed", range(12))
def test_no_mislabels_over_seeded_views(seed: int) -> None:
    """~25 decodes per view, 5 % drops, flicker, glints: every reading names the right mote."""
    rng = np.random.default_rng(100 + seed)
    n = 25
    uv = np.column_stack([rng.uniform(12, 308, n), rng.uniform(12, 228, n)])
    ids = [int(i) for i in rng.choice(100, size=n, replace=False)]
    res, _, _ = _view(100 + seed, uv, ids, glints=6)
    truth = dict(zip(ids, uv))
    for r in res.readings:
        assert r.index in truth
        assert math.hypot(r.u - truth[r.index][0], r.v - truth[r.index][1]) < 2.0


def test_mote_on_fraction_is_exact() -> None:
    m = BlinkingMote("n", np.zeros(3), np.array([1, 0, 1, 1], np.uint8), bit_period_s=1.0, t0=0.0)
    assert m.on_fraction(np.array([0.0, 0.5, 1.0, 1.5, 4.0]), 1.0).tolist() == [1.0, 0.5, 0.0, 0.5, 1.0]
