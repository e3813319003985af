"""Crowd decoding leaves light refused when the LEDs it decoded do not explain it
(:func:`fgloc.camera.blink_crowd_decoding.crowd_readings`, steps 6 and 7)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.camera.blink_crowd_decoding import hull_distance, leftover_peaks
from fgloc.camera.blink_decoder import DecodedReading, RefusedBlob, decode_view
from fgloc.camera.blink_pairs import PairConfig
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_with_codes, points_at_pixels, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera, add_spot
from fgloc.survey.field_plans import frames_for
from tests.test_blink_fields_pairs import BOOK as BOOK100
from tests.test_blink_fields_pairs import FIELD, FIT, _field_view

BOOK = code_book(30)
INTR = CameraIntrinsics(fx=160, fy=160, cx=160, cy=120, width=320, height=240)
#: four LEDs of a 30-mote survey seen 90 deg wide (the 320 x 240 rig of scripts/coded_survey.py,
#: seed 3, cam1, as a view planned differently put them): a pair 3 px apart (codes 27, 5), a third
#: LED 7 px beside it (code 7) and a fourth 13 px away (code 15)
LEDS = {27: (103.34, 90.16), 5: (102.99, 93.16), 7: (109.46, 87.02), 15: (116.48, 92.17)}


def _reading(u: float, v: float) -> DecodedReading:
    return DecodedReading(0, u, v, 0.1, 0.0, 0.0, 5, None, ())


def test_hull_distance_is_the_distance_to_the_leds_convex_hull() -> None:
    """Against a brute-force minimum over a dense barycentric grid of the hull (point, segment,
    triangle; edges and corners included)."""
    rng = np.random.default_rng(3)
    g = np.linspace(0.0, 1.0, 401)
    grids = {1: np.ones((1, 1)), 2: np.column_stack([g, 1 - g]),
             3: np.array([(a, b, 1 - a - b) for a in g for b in g if a + b <= 1 + 1e-12])}
    for n in (1, 2, 3):
        for _ in range(30):
            pts = rng.uniform(0, 10, (n, 2))
            x = rng.uniform(-5, 15, 2)
            brute = float(np.min(np.linalg.norm(grids[n] @ pts - x, axis=1)))
            got = hull_distance(float(x[0]), float(x[1]), [_reading(*p) for p in pts])
            assert got == pytest.approx(brute, abs=0.02)
            assert got <= brute + 1e-9  # the samples lie in the hull: never nearer than the hull itself


def test_a_third_led_beside_a_decoded_pair_leaves_its_blob_refused() -> None:
    """Rendered (seed 18): the blob of the pair and its neighbour decodes as the pair (27, 5); the
    neighbour's light is left as a refused blob for the survey to chase, where both rules off
    (steps 6 and 7) lose it; step 7 alone refuses the neighbour's peak."""
    rng = np.random.default_rng(18)
    pan, tilt = 0.3, -0.2
    pts = points_at_pixels(INTR, pan, tilt, np.array(list(LEDS.values())), 5.0)
    cfg = BlinkRenderConfig()
    motes = motes_with_codes({f"m{i}": pts[k] for k, i in enumerate(LEDS)}, {f"m{i}": BOOK.bits(i) for i in LEDS},
                             round(1 / cfg.frame_rate_hz, 5), rng)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    frames = render_view(cam, INTR, pan, tilt, motes, frames_for(BOOK.length), rng, cfg)
    period = 1 / cfg.frame_rate_hz
    third = LEDS[7]
    off = decode_view(frames, period, BOOK, INTR, pan, tilt,
                      pairs=PairConfig(max_group=3, explain_px=math.inf, peak_px=math.inf))
    assert {r.index for r in off.readings} == {27, 5, 15}  # the case: the pair read, the third's blob taken with it
    assert not any(math.dist((r.u, r.v), third) < 12 for r in off.refused)
    peak = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig(max_group=3, explain_px=math.inf))
    assert [math.dist((r.u, r.v), third) < 1.5 for r in peak.refused] == [True]  # step 7 alone finds it too
    on = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig(max_group=3))
    assert {r.index for r in on.readings} == {27, 5, 15}  # the same readings, each on its own LED
    assert all(math.dist((r.u, r.v), LEDS[r.index]) < 1.0 for r in on.readings)
    left = [r for r in on.refused if math.dist((r.u, r.v), third) < 6]
    assert left and all(hull_distance(r.u, r.v, [x for x in on.readings if x.index in (27, 5)]) > 1.5 for r in left)


def _lit(spots: list[tuple[float, float, float]], noise: float = 2.0, seed: int = 0) -> np.ndarray:
    """A lit-difference image (max minus min, DN) of Gaussian spots (u, v, flux; sigma 1.2 px) on noise."""
    img = np.abs(np.random.default_rng(seed).normal(4.0, noise, (60, 80)))
    for u, v, flux in spots:
        add_spot(img, u, v, flux, 1.2)
    return img


def test_leftover_peaks_finds_light_off_the_decoded_leds() -> None:
    """Step 7 on a synthetic image: a pair decoded at (40, 30) and (41, 32.3) with a third spot
    5 px beside it (as cam0 saw n077, n097 and n081 at 3x in fields, 100 motes, seed 2): the third's
    peak is refused; nothing without it, nothing when it lies within ``peak_px`` of the pair, when
    it is dimmer than ``peak_fraction`` of the crowd, or when a reading or a refused blob is there.
    A third LED between the two LEDs of a wide pair is refused too."""
    cfg = PairConfig(max_group=3)
    pair = [_reading(40.0, 30.0), _reading(41.0, 32.3)]
    spots = [(40.0, 30.0, 800.0), (41.0, 32.3, 800.0)]
    third = (38.3, 25.4)
    got = leftover_peaks(_lit(spots + [(*third, 600.0)]), (40.0, 29.0), pair, [], 2.0, cfg)
    assert len(got) == 1 and got[0].kind == "ambiguous" and math.dist((got[0].u, got[0].v), third) < 1.0
    assert min(math.dist((got[0].u, got[0].v), (r.u, r.v)) for r in pair) > cfg.peak_px
    assert leftover_peaks(_lit(spots), (40.0, 29.0), pair, [], 2.0, cfg) == []
    near = (39.2, 28.6)  # 1.6 px from the nearer LED: its own light's shoulder, not another LED
    assert leftover_peaks(_lit(spots + [(*near, 600.0)]), (40.0, 29.0), pair, [], 2.0, cfg) == []
    faint = _lit(spots + [(*third, 100.0)])  # peak under a quarter of the crowd's
    assert leftover_peaks(faint, (40.0, 29.0), pair, [], 2.0, cfg) == []
    lit = _lit(spots + [(*third, 600.0)])
    assert leftover_peaks(lit, (40.0, 29.0), pair + [_reading(*third)], [], 2.0, cfg) == []
    assert leftover_peaks(lit, (40.0, 29.0), pair, [RefusedBlob(*third, "rejected", "x")], 2.0, cfg) == []
    # a third LED 2.4 px off the segment between a pair 11 px apart (n453 beside n507 and n386 at
    # 3x, 1000 motes): inside any hull margin, yet 5 px from either LED, and a peak of its own
    wide = [_reading(30.0, 30.0), _reading(38.6, 36.8)]
    between = (31.94, 34.64)
    assert hull_distance(*between, wide) < cfg.peak_px
    lit = _lit([(30.0, 30.0, 800.0), (38.6, 36.8, 800.0), (*between, 600.0)])
    got = leftover_peaks(lit, (34.0, 33.0), wide, [], 2.0, cfg)
    assert len(got) == 1 and math.dist((got[0].u, got[0].v), between) < 1.0
    assert leftover_peaks(_lit([(30.0, 30.0, 800.0), (38.6, 36.8, 800.0)]), (34.0, 33.0), wide, [], 2.0, cfg) == []


def test_rendered_field_crowds_peaks_only_at_unread_leds() -> None:
    """Rendered fields (the crowd decoder's own test scenes, light-curve fit on): pairs 2-5 px
    apart never get a peak refusal; crowds of three linked within 4-7 px that decode only in
    part do, and every one lies within 1 px of an LED no reading names (measured: 9 of 9 over
    168 views; none at a read LED)."""
    peaks = 0
    for uv_of, n, sizes, seeds in (("pairs", 5, (2.0, 3.5, 5.0), range(3)), ("groups", 3, (4.0, 7.0), range(4))):
        for size in sizes:
            for seed in seeds:
                for flux in (375.0, 1500.0):
                    frames, uv, ids, pan, tilt, period = _field_view(seed, uv_of, n, size, flux)
                    res = decode_view(frames, period, BOOK100, FIELD, pan, tilt, FIT, pairs=PairConfig(max_group=3))
                    read = {r.index for r in res.readings}
                    for r in res.refused:
                        if "another LED" not in r.reason:
                            continue
                        assert uv_of == "groups"
                        k = int(np.argmin(np.hypot(uv[:, 0] - r.u, uv[:, 1] - r.v)))
                        assert math.dist((r.u, r.v), uv[k]) < 1.0 and int(ids[k]) not in read
                        peaks += 1
    assert peaks >= 3  # the rule fires where it should (7 in these views, measured)
