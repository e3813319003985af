"""Crowd decoding leaves a blob refused when the LEDs it decoded do not explain its light
(:func:`fgloc.camera.blink_crowd_decoding.crowd_readings`, step 6)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.camera.blink_crowd_decoding import hull_distance
from fgloc.camera.blink_decoder import DecodedReading, decode_view
from fgloc.camera.blink_pairs import PairConfig
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_with_codes, points_at_pixels, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
from fgloc.survey.field_plans import frames_for

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
    neighbour's light is left as a refused blob for the survey to chase, where the rule off loses it."""
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
    off = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig(max_group=3, explain_px=math.inf))
    assert {r.index for r in off.readings} == {27, 5, 15}  # the case: the pair read, the third's blob taken with it
    assert not any(math.dist((r.u, r.v), third) < 12 for r in off.refused)
    on = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig(max_group=3))
    assert {r.index for r in on.readings} == {27, 5, 15}  # the same readings, each on its own LED
    assert all(math.dist((r.u, r.v), LEDS[r.index]) < 1.0 for r in on.readings)
    left = [r for r in on.refused if math.dist((r.u, r.v), third) < 6]
    assert left and all(hull_distance(r.u, r.v, [x for x in on.readings if x.index in (27, 5)]) > 1.5 for r in left)
