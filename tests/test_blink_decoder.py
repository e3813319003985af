"""Blink decoder on seeded rendered views: right IDs, refused pairs, no mislabels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import CodeBook, code_book, sync_code_book
from fgloc.camera.blink_decoder import (
    DecodedReading,
    RefusedBlob,
    SyncTiming,
    ViewDecode,
    decode_view,
    decode_windows,
    sample_stack,
    supplement_decode,
)
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import (
    BlinkingMote,
    BlinkRenderConfig,
    motes_synchronized,
    motes_with_codes,
    render_view,
)
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


# ----- synchronized start, sliding windows --------------------------------------------------
SYNC_BOOK = sync_code_book(100)


def _sync_view(seed: int, uv: np.ndarray, ids: list[int], t_start: float, n_frames: int, glints: int = 0,
               drop: float = 0.05) -> tuple[list[tuple[float, np.ndarray]], float, float, BlinkRenderConfig]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    p, t = pixel_to_pan_tilt(INTR, uv, pan, tilt)
    pts = pan_tilt_bearing(p, t) * rng.uniform(3.0, 20.0, len(ids))[:, None]
    pos = {f"m{k}": pts[k] for k in range(len(ids))}
    cfg = BlinkRenderConfig(glints=glints, drop_rate=drop, duplicate_rate=0.01)
    period = round(1 / cfg.frame_rate_hz, 5)
    motes = motes_synchronized(pos, {f"m{k}": SYNC_BOOK.bits(i) for k, i in enumerate(ids)}, period, rng)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    return render_view(cam, INTR, pan, tilt, motes, n_frames, rng, cfg, None, t_start), pan, tilt, cfg


@pytest.mark.parametrize("seed", range(4))
def test_synchronized_decode_right_ids_within_the_timing_budget(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    n = 20
    uv = np.column_stack([rng.uniform(12, 308, n), rng.uniform(12, 228, n)])
    ids = [int(i) for i in rng.choice(100, size=n, replace=False)]
    t_start = float(rng.uniform(0.0, 10.0))  # since the (re)start: drift up to 50 ppm sd accumulates
    frames, pan, tilt, cfg = _sync_view(300 + seed, uv, ids, t_start, frames_for(SYNC_BOOK.length), glints=6)
    period = 1 / cfg.frame_rate_hz
    sync = SyncTiming(0.0, round(period, 5), cfg.exposure_s)
    res = decode_view(frames, period, SYNC_BOOK, INTR, pan, tilt, sync=sync)
    truth = dict(zip(ids, uv))
    # whole views can lose many motes when every sample falls near a bit edge (see docs): only half asked
    assert len(res.readings) >= n // 2
    for r in res.readings:
        assert r.index in truth and math.hypot(r.u - truth[r.index][0], r.v - truth[r.index][1]) < 2.0
    # an epoch off by 0.4 bit (inside the half-bit budget): still only right IDs
    off = SyncTiming(0.4 * sync.bit_period_s, sync.bit_period_s, cfg.exposure_s)
    res_off = decode_view(frames, period, SYNC_BOOK, INTR, pan, tilt, sync=off)
    assert len(res_off.readings) >= n // 2
    assert all(r.index in truth and math.hypot(r.u - truth[r.index][0], r.v - truth[r.index][1]) < 2.0
               for r in res_off.readings)
    with pytest.raises(ValueError):
        decode_view(frames, period, BOOK, INTR, pan, tilt, sync=sync)  # a rotation-free book needs no epoch
    with pytest.raises(ValueError):
        decode_view(frames, period, SYNC_BOOK, INTR, pan, tilt)


FOUR_UV = np.array([[60.0, 60.0], [160.0, 120.0], [260.0, 200.0], [100.0, 180.0]])
FOUR_IDS = [11, 22, 33, 44]


def _four_motes(n_frames: int) -> tuple[list[tuple[float, np.ndarray]], float, float, float]:
    """Four motes (:data:`FOUR_UV`, codes :data:`FOUR_IDS`) rendered for ``n_frames`` frames
    without drops, head at (0.2, -0.3) rad: (frames, frame period s, pan, tilt)."""
    rng = np.random.default_rng(7)
    pan, tilt = 0.2, -0.3
    p, t = pixel_to_pan_tilt(INTR, FOUR_UV, pan, tilt)
    pos = {f"m{j}": pan_tilt_bearing(p[j], t[j]) * 10.0 for j in range(4)}
    cfg = BlinkRenderConfig(drop_rate=0.0)
    period = 1 / cfg.frame_rate_hz
    motes = motes_with_codes(pos, {f"m{j}": BOOK.bits(i) for j, i in enumerate(FOUR_IDS)}, round(period, 5), rng)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    return render_view(cam, INTR, pan, tilt, motes, n_frames, rng, cfg), period, pan, tilt


def test_sliding_window_catches_what_the_first_window_missed() -> None:
    uv, ids = FOUR_UV, FOUR_IDS
    L = BOOK.length
    k = frames_for(L)
    frames, period, pan, tilt = _four_motes(k + L)
    # the grabber lost every frame of one bit position in the first window: that window reads no mote
    lost = [f for j, f in enumerate(frames) if not (j < k and j % L == 5 and j > 0)]
    first = decode_view([f for f in lost if f[0] < (k - 0.5) * period], period, BOOK, INTR, pan, tilt)
    assert first.readings == ()
    res = decode_windows(lost, period, BOOK, INTR, pan, tilt, window=k)
    assert sorted(r.index for r in res.readings) == ids
    for r in res.readings:
        j = ids.index(r.index)
        assert math.hypot(r.u - uv[j, 0], r.v - uv[j, 1]) < 0.3


def test_sliding_windows_merge_never_guesses(monkeypatch: pytest.MonkeyPatch) -> None:
    import fgloc.camera.blink_decoder as bd

    def reading(code: int, u: float, v: float, on: int = 10) -> DecodedReading:
        return DecodedReading(code, u, v, 0.05, 0.0, 0.0, on)

    windows = iter([
        ViewDecode((reading(1, 10.0, 10.0), reading(2, 50.0, 50.0), reading(3, 90.0, 90.0)),
                   (RefusedBlob(120.0, 20.0, "duplicate", "code 4 decoded from 2 blobs", 4),), 50, 0),
        ViewDecode((reading(1, 10.2, 10.1, 12), reading(2, 70.0, 50.0), reading(5, 90.5, 90.0),
                    reading(4, 120.0, 20.0)), (), 50, 0),
    ])
    monkeypatch.setattr(bd, "decode_view", lambda *a, **k: next(windows))
    frames = [(i / 30.0, np.zeros((2, 2), np.uint8)) for i in range(66)]
    res = bd.decode_windows(frames, 1 / 30.0, BOOK, INTR, 0.0, 0.0, window=50)
    assert [(r.index, r.on_samples) for r in res.readings] == [(1, 12)]  # agreeing windows: the better reading
    kinds = {(f.code, f.kind) for f in res.refused}
    assert (2, "duplicate") in kinds  # one code at two places
    assert (3, "ambiguous") in kinds and (5, "ambiguous") in kinds  # one blob, two codes
    assert (4, "duplicate") in kinds  # a duplicate in any window is refused


def test_sliding_windows_report_each_refused_blob_once(monkeypatch: pytest.MonkeyPatch) -> None:
    import fgloc.camera.blink_decoder as bd

    glint = RefusedBlob(200.0, 30.0, "rejected", "word is no rotation of a book code")
    windows = iter([ViewDecode((), (glint,), 50, 0), ViewDecode((), (RefusedBlob(200.3, 30.1, "rejected", "x"),), 50, 0)])
    monkeypatch.setattr(bd, "decode_view", lambda *a, **k: next(windows))
    frames = [(i / 30.0, np.zeros((2, 2), np.uint8)) for i in range(66)]
    res = bd.decode_windows(frames, 1 / 30.0, BOOK, INTR, 0.0, 0.0, window=50)
    assert res.readings == () and res.refused == (glint,)


def test_the_first_window_keeps_a_mote_a_late_lamp_spoils() -> None:
    """A lamp switched on next to a mote after the first 2L + 2 frames spoils that mote's blob in
    the whole recording's decode; supplemented by the first frames' decode
    (:func:`supplement_decode`, the adaptive length's ``first_window "kept"``) it is read, at its
    pixel, and every other mote as the whole decode read it."""
    uv = FOUR_UV
    L = BOOK.length
    frames, period, pan, tilt = _four_motes(frames_for(L))
    yy, xx = np.mgrid[0:INTR.height, 0:INTR.width]
    lamp = 120.0 * np.exp(-((xx - 162.0) ** 2 + (yy - 121.0) ** 2) / (2 * 1.5**2))
    late = [(tf, np.clip(img.astype(np.float64) + (lamp[..., None] if img.ndim == 3 else lamp), 0, 255).astype(img.dtype))
            if j >= 2 * L + 2 else (tf, img) for j, (tf, img) in enumerate(frames)]
    first = decode_view(late[:2 * L + 2], period, BOOK, INTR, pan, tilt)
    whole = decode_view(late, period, BOOK, INTR, pan, tilt)
    assert 22 in {r.index for r in first.readings} and 22 not in {r.index for r in whole.readings}
    merged = supplement_decode(whole, first)
    got = {r.index: r for r in merged.readings}
    assert sorted(got) == sorted({r.index for r in whole.readings} | {22})
    assert all(got[r.index] == r for r in whole.readings)
    assert math.hypot(got[22].u - uv[1, 0], got[22].v - uv[1, 1]) < 0.3
    assert not any(math.hypot(f.u - got[22].u, f.v - got[22].v) <= 2.0 for f in merged.refused)  # no refusal left there
    assert (merged.samples, merged.erased) == (whole.samples, whole.erased)


def test_the_first_window_adds_only_what_the_whole_decode_lacks() -> None:
    """:func:`supplement_decode` keeps every reading and refusal of the whole decode but those at
    an added reading, and adds none of a code the whole decode read (anywhere) or refused as
    duplicate, nor one within 2 px of a reading of the whole decode."""

    def reading(code: int, u: float, v: float) -> DecodedReading:
        return DecodedReading(code, u, v, 0.05, 0.0, 0.0, 10)

    whole = ViewDecode((reading(1, 10.0, 10.0), reading(2, 50.0, 50.0)),
                       (RefusedBlob(90.0, 90.0, "ambiguous", "two LEDs"), RefusedBlob(120.0, 20.0, "duplicate", "x", 4),
                        RefusedBlob(200.0, 30.0, "rejected", "glint")), 62, 3)
    first = ViewDecode((reading(1, 30.0, 30.0), reading(3, 90.4, 90.2), reading(4, 120.0, 20.0), reading(5, 51.0, 50.5),
                        reading(6, 150.0, 150.0)), (), 42, 2)
    got = supplement_decode(whole, first)
    assert [(r.index, r.u) for r in got.readings] == [(1, 10.0), (2, 50.0), (3, 90.4), (6, 150.0)]
    assert [f.u for f in got.refused] == [120.0, 200.0]  # the merged blob at code 3 is read now
    assert (got.samples, got.erased) == (62, 3)
    assert supplement_decode(whole, ViewDecode((), (), 42, 0)) is whole
