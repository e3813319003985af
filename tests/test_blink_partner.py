"""Known-partner decoding: the last LED of a crowded blob from the wide recording, its partners known."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import bits_of, code_book, rotate
from fgloc.camera.blink_decoder import decode_view
from fgloc.camera.blink_partner import decode_partner, decode_partner_view, explain_partner
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_with_codes, points_at_pixels, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
from fgloc.survey.field_plans import frames_for
from tests.test_blink_pairs import _stack  # the pair tests' synthetic samples (same book)

BOOK = code_book(100)
INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
TOL_PX = 0.3  #: a partner's centroid (rendered, 1.2 px LEDs)
NOISE = 2.0 * math.sqrt(2.0)


def _bits(w: int, r: int) -> np.ndarray:
    return bits_of(rotate(BOOK.words[w], r, BOOK.length), BOOK.length).astype(np.int64)


def test_explain_partner_matches_brute_force() -> None:
    L = BOOK.length
    rng = np.random.default_rng(1)
    for _ in range(20):
        a, b = (int(x) for x in rng.choice(100, 2, replace=False))
        ra, rb = (int(x) for x in rng.integers(0, L, 2))
        c = _bits(a, ra) + _bits(b, rb)
        hit, why = explain_partner(BOOK, c, [a])
        # brute force: every (rotation of a, rotated word) explanation and its distance
        dists = sorted((int(np.abs(c - _bits(a, x) - _bits(w, y)).sum()), w, y, x)
                       for x in range(L) for w in range(100) for y in range(L))
        dists += [(int(np.abs(c - _bits(a, x)).sum()), -1, -1, x) for x in range(L)]
        dists.sort()
        exact = [d for d in dists if d[0] == 0]
        unique = len(exact) == 1 and exact[0][1] != a and sorted(d[0] for d in dists)[1] >= 3
        assert (hit is not None) == unique, why
        if hit is not None:
            assert hit[0] == b and hit[1] == rb and hit[2] == (ra,)


def test_remainder_no_book_word_and_known_word_refused() -> None:
    c = _bits(3, 0) + _bits(41, 7)
    assert explain_partner(BOOK, c, [3])[0] is not None
    assert explain_partner(BOOK, c, [41])[0] is not None
    # a known mote that is not in the blob: the remainder is no book word (or not unique)
    hit, why = explain_partner(BOOK, c, [5])
    assert hit is None and why
    # the partner showing the known word itself
    twice = _bits(3, 0) + _bits(3, 5)
    hit, why = explain_partner(BOOK, twice, [3])
    assert hit is None
    with pytest.raises(ValueError):
        explain_partner(BOOK, c, [3, 3])


@pytest.mark.parametrize("sep", [1.0, 2.0, 3.0, 4.0])
def test_synthetic_partner_label_and_centroid(sep: float) -> None:
    a, b = (20.0 - sep / 2, 20.3), (20.0 + sep / 2, 20.3)
    stack, valid, pos = _stack([(3, 0), (41, 7)], [a, b], seed=int(10 * sep))
    res = decode_partner(stack, valid, pos, 20.0, 20.0, BOOK, NOISE, [(3, a)])
    assert res.ok and res.uv is not None, res.reason
    assert res.index == 41 and res.rotation == 7 and math.dist(res.uv, b) < TOL_PX
    back = decode_partner(stack, valid, pos, 20.0, 20.0, BOOK, NOISE, [(41, b)])
    assert back.ok and back.index == 3 and back.uv is not None and math.dist(back.uv, a) < TOL_PX


def test_synthetic_wrong_known_partner_refused() -> None:
    a, b = (19.0, 20.0), (21.0, 20.0)
    stack, valid, pos = _stack([(3, 0), (41, 7)], [a, b], seed=3)
    for wrong in range(100):
        if wrong in (3, 41):
            continue
        res = decode_partner(stack, valid, pos, 20.0, 20.0, BOOK, NOISE, [(wrong, a)])
        assert not res.ok, (wrong, res.index)
    # the right word at the wrong pixel (another LED's reading): refused by the anchor
    far = decode_partner(stack, valid, pos, 20.0, 20.0, BOOK, NOISE, [(3, (23.0, 22.0))])
    assert not far.ok and "given pixel" in far.reason


def test_synthetic_third_led_refused() -> None:
    uv = [(19.0, 20.0), (21.0, 20.0), (20.0, 21.7)]
    for seed, rots in enumerate([(0, 3, 9), (1, 6, 12), (2, 8, 14)]):
        stack, valid, pos = _stack([(5, rots[0]), (17, rots[1]), (60, rots[2])], uv, seed=seed)
        for k in (5, 17, 60):
            res = decode_partner(stack, valid, pos, 20.0, 20.3, BOOK, NOISE, [(k, uv[[5, 17, 60].index(k)])])
            assert not res.ok, (k, res.index)


def test_synthetic_group_of_three_two_known() -> None:
    uv = [(19.0, 20.0), (21.5, 20.0), (20.2, 22.0)]
    words = [(5, 0), (17, 6), (60, 12)]
    stack, valid, pos = _stack(words, uv, seed=5)
    done = 0
    for last in range(3):
        known = [(words[k][0], uv[k]) for k in range(3) if k != last]
        res = decode_partner(stack, valid, pos, 20.0, 20.5, BOOK, NOISE, known)
        if res.ok:
            assert res.index == words[last][0] and res.uv is not None and math.dist(res.uv, uv[last]) < TOL_PX
            done += 1
        # one known of three: the remainder is two words, never one
        assert not decode_partner(stack, valid, pos, 20.0, 20.5, BOOK, NOISE, known[:1]).ok
    assert done >= 1  # words 5, 17 near another explanation: refused, never guessed


def _render(seed: int, sep: float, third: bool = False) -> tuple[list, np.ndarray, np.ndarray, float]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    c = np.array([rng.uniform(40, 280), rng.uniform(40, 200)])
    ang = rng.uniform(0, math.pi)
    d = 0.5 * sep * np.array([math.cos(ang), math.sin(ang)])
    uv = [c - d, c + d] + ([c + [0.0, 2.5]] if third else [])
    uv += [np.array([rng.uniform(20, 300), rng.uniform(20, 220)]) for _ in range(6)]
    uv_a = np.array(uv)
    ids = rng.choice(100, len(uv_a), replace=False)
    pts = points_at_pixels(INTR, pan, tilt, uv_a, rng.uniform(3.0, 20.0, len(uv_a)))
    cfg = BlinkRenderConfig(glints=6, duplicate_rate=0.01)
    motes = motes_with_codes({f"m{k}": pts[k] for k in range(len(ids))},
                             {f"m{k}": BOOK.bits(int(i)) for k, i in enumerate(ids)},
                             round(1 / cfg.frame_rate_hz, 5), rng)
    statics = points_at_pixels(INTR, pan, tilt, np.array([[60.0, 60.0], [250.0, 180.0]]), 30.0)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    frames = render_view(cam, INTR, pan, tilt, motes, frames_for(BOOK.length), rng, cfg, statics)
    assert decode_view(frames, 1 / cfg.frame_rate_hz, BOOK, INTR, pan, tilt) is not None
    return frames, uv_a, ids, 1 / cfg.frame_rate_hz


@pytest.mark.parametrize("sep", [1.0, 2.0, 3.0, 4.0])
def test_rendered_pairs_labelled(sep: float) -> None:
    hits = 0
    for seed in range(5):
        frames, uv, ids, period = _render(seed, sep)
        c = 0.5 * (uv[0] + uv[1])
        for k in (0, 1):
            res = decode_partner_view(frames, period, BOOK, float(c[0]), float(c[1]),
                                      [(int(ids[k]), (float(uv[k][0]), float(uv[k][1])))])
            if res.ok:
                assert res.index == int(ids[1 - k]) and res.uv is not None
                assert math.dist(res.uv, uv[1 - k]) < TOL_PX
                hits += 1
            # a known mote that is not in the blob: never a label
            wrong = next(int(i) for i in range(100) if i not in ids)
            bad = decode_partner_view(frames, period, BOOK, float(c[0]), float(c[1]),
                                      [(wrong, (float(uv[k][0]), float(uv[k][1])))])
            assert not bad.ok, bad.index
    assert hits >= 4  # of 10 (margin 3: some count words lie near another explanation, refused)


def test_rendered_third_led_in_the_aperture_refused() -> None:
    for seed in range(3):
        frames, uv, ids, period = _render(10 + seed, 2.0, third=True)
        c = 0.5 * (uv[0] + uv[1])
        for k in (0, 1):
            res = decode_partner_view(frames, period, BOOK, float(c[0]), float(c[1]),
                                      [(int(ids[k]), (float(uv[k][0]), float(uv[k][1])))])
            assert not res.ok, (res.index, ids[:3])


def test_every_other_known_word_refused_on_counts() -> None:
    """No (pair, wrong known) combination of the first words labels a partner unless the
    count word really decomposes with that known word."""
    L = BOOK.length
    for a, b in itertools.combinations(range(8), 2):
        c = _bits(a, 0) + _bits(b, 3)
        for wrong in range(8, 40):
            hit, _ = explain_partner(BOOK, c, [wrong])
            if hit is not None:  # only if the sum really is wrong's word + hit's word
                assert any(np.array_equal(c, _bits(wrong, x) + _bits(hit[0], hit[1])) for x in range(L))
