"""Video faults of the blink renderer: a rolling shutter and a rate fall, and what the decoder makes of them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.camera.blink_decoder import decode_view, unsampled_positions
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkingMote, BlinkRenderConfig, motes_with_codes, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera

INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
BOOK = code_book(100)
L = BOOK.length
QUIET = BlinkRenderConfig(drop_rate=0.0, duplicate_rate=0.0, timestamp_jitter_s=0.0, jitter_px=0.0, ambient_sd=0.0)
CAM = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))


def _points(uv: np.ndarray, pan: float, tilt: float) -> np.ndarray:
    p, t = pixel_to_pan_tilt(INTR, uv, pan, tilt)
    return np.asarray(pan_tilt_bearing(p, t) * 10.0)


def _lit(frames: list[tuple[float, np.ndarray]], u: float, v: float) -> np.ndarray:
    """Per frame, whether the LED at (u, v) is lit (its peak well above the background)."""
    out = []
    for _, img in frames:
        patch = img[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2].astype(float)
        out.append(patch.max() - float(np.median(img)) > 40.0)
    return np.array(out)


def test_rolling_shutter_delays_a_lower_led_by_its_row() -> None:
    period = 1.0 / QUIET.frame_rate_hz
    bits = BOOK.bits(7)
    uv = np.array([[100.0, 20.0], [200.0, 20.0 + INTR.height / 2]])
    pts = _points(uv, 0.0, 0.0)
    # both LEDs blink the same word from the same instant, half an exposure into a bit
    motes = [BlinkingMote(f"m{k}", pts[k], bits, period, -0.25 * QUIET.exposure_s) for k in range(2)]
    rng = np.random.default_rng(0)
    ccd = render_view(CAM, INTR, 0.0, 0.0, motes, 2 * L, rng, QUIET)
    top, low = _lit(ccd, *uv[0]), _lit(ccd, *uv[1])
    assert np.array_equal(top, low) and 0 < top.sum() < len(top)  # a CCD: both rows see the same bit
    # a readout of two frame periods: the lower LED, half the image further down, is sampled one period later
    cmos = render_view(CAM, INTR, 0.0, 0.0, motes, 2 * L, np.random.default_rng(0),
                       BlinkRenderConfig(**{**QUIET.__dict__, "readout_s": 2.0 * period}))
    top, low = _lit(cmos, *uv[0]), _lit(cmos, *uv[1])
    assert np.array_equal(low[:-1], top[1:]) and not np.array_equal(low, top)


def test_rate_fall_delivers_every_second_frame_from_its_time() -> None:
    period = 1.0 / QUIET.frame_rate_hz
    cfg = BlinkRenderConfig(**{**QUIET.__dict__, "rate_fall_s": 5 * period})
    frames = render_view(CAM, INTR, 0.0, 0.0, [], 20, np.random.default_rng(1), cfg, t_start=3.0)
    stamps = np.array([t for t, _ in frames]) - 3.0
    assert np.allclose(stamps, period * np.array([0, 1, 2, 3, 4, 5, 7, 9, 11, 13, 15, 17, 19]))
    # before the fall the video is the full-rate one, frame for frame
    full = render_view(CAM, INTR, 0.0, 0.0, [], 20, np.random.default_rng(1), QUIET, t_start=3.0)
    assert len(full) == 20 and all(np.array_equal(frames[i][1], full[i][1]) for i in range(6))


def _view(seed: int, cfg: BlinkRenderConfig, n_frames: int) -> tuple[list[tuple[float, np.ndarray]], np.ndarray,
                                                                      list[int], float, float]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    uv = np.column_stack([np.linspace(30, 290, 8), rng.uniform(20, 220, 8)])
    ids = [int(i) for i in rng.choice(100, 8, replace=False)]
    pts = _points(uv, pan, tilt)
    motes = motes_with_codes({f"m{k}": pts[k] for k in range(8)}, {f"m{k}": BOOK.bits(i) for k, i in enumerate(ids)},
                             round(1 / cfg.frame_rate_hz, 5), rng)
    return render_view(CAM, INTR, pan, tilt, motes, n_frames, rng, cfg), uv, ids, pan, tilt


@pytest.mark.parametrize("seed", range(3))
def test_decoder_reads_through_a_rolling_shutter(seed: int) -> None:
    cfg = BlinkRenderConfig(readout_s=1.0 / 29.97)  # the whole frame time: the worst CMOS readout
    frames, uv, ids, pan, tilt = _view(seed, cfg, 3 * L + 2)
    res = decode_view(frames, 1 / cfg.frame_rate_hz, BOOK, INTR, pan, tilt)
    got = {r.index: (r.u, r.v) for r in res.readings}
    for i, (u, v) in got.items():  # every reading is the right mote, at its pixel
        assert i in ids and math.hypot(u - uv[ids.index(i)][0], v - uv[ids.index(i)][1]) <= 2.0
    assert len(got) >= 7


@pytest.mark.parametrize("seed", range(3))
def test_rate_fall_leaves_odd_bits_unread_and_nothing_is_guessed(seed: int) -> None:
    # at half rate a word of even length is sampled at one parity of its bits only: refused, never guessed
    assert L % 2 == 0
    cfg = BlinkRenderConfig(rate_fall_s=0.0)
    frames, uv, ids, pan, tilt = _view(seed, cfg, 6 * L + 4)
    res = decode_view(frames, 1 / cfg.frame_rate_hz, BOOK, INTR, pan, tilt)
    assert res.readings == () or all(r.index in ids and math.hypot(r.u - uv[ids.index(r.index)][0],
                                                                   r.v - uv[ids.index(r.index)][1]) <= 2.0
                                     for r in res.readings)
    assert len(res.readings) == 0
    assert res.unsampled == L // 2  # the decode says why: half the bit positions never seen


def test_a_full_rate_view_leaves_no_position_unsampled() -> None:
    frames, *_, pan, tilt = _view(0, BlinkRenderConfig(), 3 * L + 2)
    assert decode_view(frames, 1 / 29.97, BOOK, INTR, pan, tilt).unsampled == 0
    assert unsampled_positions(np.array([0, 2, 4, 6]), 8) == 4 and unsampled_positions(np.arange(9), 8) == 0


def test_survey_warns_once_per_camera_of_a_steady_frame_loss(caplog: pytest.LogCaptureFixture) -> None:
    from types import SimpleNamespace

    from fgloc.survey.clock import CameraTiming
    from fgloc.survey.coded_recording import check_steady_loss
    from fgloc.survey.coded_settings import CodedStats

    timing = CameraTiming()
    coded = SimpleNamespace(book=BOOK, camera=timing, stats=CodedStats())
    period = timing.frame_period_s
    img = np.zeros((2, 2), np.uint8)
    rng = np.random.default_rng(4)
    full = [(100.0 + k * period, img) for k in range(3 * L + 2) if rng.random() > 0.05]  # 5 % random drops
    half = [(100.0 + k * period, img) for k in range(0, 3 * L + 2, 2)]
    short = [(100.0 + k * period, img) for k in range(0, L + 2, 2)]  # too short to tell
    with caplog.at_level("WARNING", logger="fgloc.survey.coded_recording"):
        check_steady_loss(coded, "cam0", "w000", full)  # type: ignore[arg-type]
        check_steady_loss(coded, "cam0", "w001", short)  # type: ignore[arg-type]
        assert coded.stats.rate_fall_views == 0 and not caplog.records
        for vid in ("w002", "w003"):
            check_steady_loss(coded, "cam0", vid, half)  # type: ignore[arg-type]
        check_steady_loss(coded, "cam1", "w000", half)  # type: ignore[arg-type]
    assert coded.stats.rate_fall_views == 3 and coded.stats.rate_fall_cameras == ["cam0", "cam1"]
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 2 and warned[0].startswith(f"cam0 view w002: {L // 2} of the {L} bit positions got no frame")
