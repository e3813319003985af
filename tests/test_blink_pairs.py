"""Pair decoding: two LEDs in one blob labelled by their code words, or refused; never guessed."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import CodeBook, bits_of, code_book, rotate
from fgloc.camera.blink_decoder import decode_view, decode_windows
from fgloc.camera.blink_pairs import PairConfig, decode_pair, explain_counts, unique_pair
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import (
    BlinkRenderConfig,
    close_pairs,
    motes_with_codes,
    points_at_pixels,
    render_view,
)
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera, add_spot
from fgloc.survey.field_plans import frames_for

BOOK = code_book(100)
SMALL = code_book(13)  # L = 12: small enough to enumerate every pair of rotated words
INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
TOL_PX = 0.25  #: stated tolerance of a pair-decoded centroid (rendered, 1.2 px LEDs, 1500 DN)
LABEL_PX = 1.0  #: any reading farther than this from the mote its code names is a mislabel


def _counts(book: CodeBook, a: int, ra: int, b: int, rb: int) -> np.ndarray:
    return (bits_of(rotate(book.words[a], ra, book.length), book.length).astype(np.int8)
            + bits_of(rotate(book.words[b], rb, book.length), book.length).astype(np.int8))


def test_explain_counts_matches_brute_force() -> None:
    """Every explanation within 2 count errors, against a plain enumeration of all pairs."""
    L = SMALL.length
    rots = [(i, k, bits_of(rotate(w, k, L), L).astype(int)) for i, w in enumerate(SMALL.words) for k in range(L)]
    rng = np.random.default_rng(3)
    for _ in range(30):
        (i, ri, a), (j, rj, b) = (rots[int(x)] for x in rng.choice(len(rots), 2, replace=False))
        c = a + b
        if rng.random() < 0.5:  # and some count words with an error
            p = int(rng.integers(L))
            c[p] = (c[p] + 1) % 3
        want = {(x[0], x[1], -1, -1, int(np.abs(c - x[2]).sum())) for x in rots if np.abs(c - x[2]).sum() <= 2}
        for (m, x), (n, y) in itertools.combinations_with_replacement(enumerate(rots), 2):
            d = int(np.abs(c - x[2] - y[2]).sum())
            if d <= 2:
                want.add((x[0], x[1], y[0], y[1], d))
        for budget in (0, 1, 2):
            got = {(e.a, e.ra, e.b, e.rb, e.distance) for e in explain_counts(SMALL, c, budget)}
            assert got == {w for w in want if w[4] <= budget}


def test_unique_pair_rule() -> None:
    """Exactly one pair and nothing else within 2 count errors; otherwise refused with a reason."""
    found_unique = found_ambiguous = False
    for i, j in itertools.combinations(range(12), 2):
        for rj in (0, 5):
            c = _counts(BOOK, i, 0, j, rj)
            e, why = unique_pair(BOOK, c)
            near = explain_counts(BOOK, c, 2)
            if e is not None:
                found_unique = True
                assert {e.a, e.b} == {i, j} and len(near) == 1 and near[0].distance == 0
            else:
                found_ambiguous = True
                assert len(near) > 1 and why
    assert found_unique and found_ambiguous
    single = bits_of(BOOK.words[7], BOOK.length).astype(np.int8)
    assert unique_pair(BOOK, single)[0] is None  # one word alone is no pair
    assert "single" in unique_pair(BOOK, single)[1] or "not unique" in unique_pair(BOOK, single)[1]


def _stack(words: list[tuple[int, int]], uv: list[tuple[float, float]], seed: int = 0, n: int | None = None,
           flux: float = 1500.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Synthetic samples (41 x 41 px, textured background, 2 DN noise) of LEDs with
    ``words`` (book index, rotation), exactly aligned with the samples."""
    L = BOOK.length
    n = n or frames_for(L)
    rng = np.random.default_rng(seed)
    bg = 60.0 + 20.0 * rng.random((41, 41))
    stack = np.zeros((n, 41, 41), np.float32)
    for s in range(n):
        img = bg * (1.0 + 0.02 * rng.standard_normal())
        for (w, r), (u, v) in zip(words, uv):
            if bits_of(rotate(BOOK.words[w], r, L), L)[s % L]:
                add_spot(img, u, v, flux, 1.2)
        stack[s] = img + 2.0 * rng.standard_normal(img.shape)
    return stack, np.ones(n, bool), np.arange(n) % L


@pytest.mark.parametrize("sep", [0.8, 1.5, 2.5, 3.5])
def test_synthetic_pair_both_ids_and_centroids(sep: float) -> None:
    a, b = (20.0 - sep / 2, 20.3), (20.0 + sep / 2, 20.3)
    stack, valid, pos = _stack([(3, 0), (41, 7)], [a, b], seed=int(10 * sep))
    res = decode_pair(stack, valid, pos, 20.0, 20.0, BOOK, 2.0 * math.sqrt(2.0))
    assert res.ok and res.index is not None and res.uv is not None, res.reason
    got = dict(zip(res.index, res.uv))
    assert set(got) == {3, 41}
    assert math.dist(got[3], a) < TOL_PX and math.dist(got[41], b) < TOL_PX


def test_synthetic_non_unique_counts_refused_and_unique_accepted() -> None:
    """Two LEDs on one pixel: the sides cannot be told, so only the count word decides."""
    nonunique, unique = (0, 2), (19, 27)  # found by a search over words 0..29, second word rotated by 5
    assert len(explain_counts(BOOK, _counts(BOOK, *nonunique[:1], 0, nonunique[1], 5), 0)) > 1
    assert unique_pair(BOOK, _counts(BOOK, unique[0], 0, unique[1], 5))[0] is not None
    for (i, j), ok in ((nonunique, False), (unique, True)):
        stack, valid, pos = _stack([(i, 0), (j, 5)], [(20.2, 19.8), (20.2, 19.8)], seed=4)
        res = decode_pair(stack, valid, pos, 20.0, 20.0, BOOK, 2.0 * math.sqrt(2.0))
        assert res.ok == ok, res.reason
        if ok:
            assert res.rule == "counts" and res.index is not None and set(res.index) == {i, j}
        else:
            assert "not unique" in res.reason


def test_synthetic_three_leds_refused() -> None:
    uv = [(19.0, 20.0), (21.0, 20.0), (20.0, 21.7)]
    for seed, rots in enumerate([(0, 3, 9), (1, 6, 12), (2, 8, 14)]):
        stack, valid, pos = _stack([(5, rots[0]), (17, rots[1]), (60, rots[2])], uv, seed=seed)
        res = decode_pair(stack, valid, pos, 20.0, 20.3, BOOK, 2.0 * math.sqrt(2.0))
        assert not res.ok, res.index


def test_synthetic_too_few_exclusive_samples_refused() -> None:
    """A pair whose first word lies inside the second (never lit alone) has no exclusive
    samples for it: refused, even when its count word is unique."""
    L = BOOK.length
    hit = next((i, j, r) for i, j in itertools.permutations(range(100), 2) for r in range(L)
               if BOOK.words[i] & ~rotate(BOOK.words[j], r, L) & ((1 << L) - 1) == 0)
    i, j, r = hit
    stack, valid, pos = _stack([(i, 0), (j, r)], [(18.5, 20.0), (21.5, 20.0)], seed=2)
    res = decode_pair(stack, valid, pos, 20.0, 20.0, BOOK, 2.0 * math.sqrt(2.0))
    assert not res.ok
    # and a pair with exclusive samples is refused when more are asked for than exist
    stack, valid, pos = _stack([(3, 0), (41, 7)], [(18.5, 20.0), (21.5, 20.0)], seed=2)
    ok = decode_pair(stack, valid, pos, 20.0, 20.0, BOOK, 2.0 * math.sqrt(2.0))
    assert ok.ok
    more = decode_pair(stack, valid, pos, 20.0, 20.0, BOOK, 2.0 * math.sqrt(2.0),
                       PairConfig(min_exclusive=max(ok.exclusive) + 1))
    assert not more.ok and "exclusive" in more.reason


def _rendered(seed: int, n_pairs: int, singles: int, glints: int = 10, extra: int = 0,
              triple: bool = False) -> tuple[list, np.ndarray, np.ndarray, float, float, float]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    centres = np.column_stack([rng.uniform(25, 295, n_pairs), rng.uniform(25, 215, n_pairs)])
    uv = close_pairs(centres, rng.uniform(1.0, 3.5, n_pairs), rng)
    if triple:
        uv = np.vstack([uv, centres[:1] + [0.0, 1.8]])
    uv = np.vstack([uv, np.column_stack([rng.uniform(20, 300, singles), rng.uniform(20, 220, singles)])])
    return render_pixels(rng, pan, tilt, uv, glints, extra)


def render_pixels(rng: np.random.Generator, pan: float, tilt: float, uv: np.ndarray, glints: int,
                  extra: int = 0) -> tuple[list, np.ndarray, np.ndarray, float, float, float]:
    """One rendered view at (pan, tilt): motes with random book IDs at pixels ``uv`` (3-20 units
    away), two static lights, ``glints`` glints, 1 % repeated frames; 3L + 2 + ``extra`` frames.
    Returns (frames, uv, ids, pan, tilt, frame period)."""
    ids = rng.choice(100, len(uv), replace=False)
    pts = points_at_pixels(INTR, pan, tilt, uv, rng.uniform(3.0, 20.0, len(uv)))
    cfg = BlinkRenderConfig(glints=glints, duplicate_rate=0.01)
    pos = {f"m{k}": pts[k] for k in range(len(ids))}
    motes = motes_with_codes(pos, {f"m{k}": BOOK.bits(int(i)) for k, i in enumerate(ids)},
                             round(1 / cfg.frame_rate_hz, 5), rng)
    statics = points_at_pixels(INTR, pan, tilt, np.array([[60.0, 60.0], [250.0, 180.0]]), 30.0)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    frames = render_view(cam, INTR, pan, tilt, motes, frames_for(BOOK.length) + extra, rng, cfg, statics)
    return frames, uv, ids, pan, tilt, 1 / cfg.frame_rate_hz


def test_rendered_pairs_labelled_and_off_by_default() -> None:
    hits = 0
    for seed in range(3):
        frames, uv, ids, pan, tilt, period = _rendered(seed, 4, 4)
        plain = decode_view(frames, period, BOOK, INTR, pan, tilt)
        assert not {int(i) for i in ids[:8]} & {r.index for r in plain.readings}  # off: pairs refused
        res = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig())
        truth = {int(i): uv[k] for k, i in enumerate(ids)}
        for r in res.readings:
            assert math.dist((r.u, r.v), truth[r.index]) < LABEL_PX  # mislabels 0
            if r.partner is not None:
                assert math.dist((r.u, r.v), truth[r.index]) < TOL_PX
                k = int(np.flatnonzero(ids == r.index)[0])
                assert int(ids[k ^ 1]) == r.partner and k < 8
                hits += 1
    assert hits >= 16  # of 24 LEDs in pairs (12 pairs)


def test_rendered_three_leds_refused() -> None:
    frames, uv, ids, pan, tilt, period = _rendered(7, 1, 3, glints=0, triple=True)
    res = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig())
    read = {r.index for r in res.readings}
    assert not read & {int(ids[0]), int(ids[1]), int(ids[2])}
    truth = {int(i): uv[k] for k, i in enumerate(ids)}
    assert all(math.dist((r.u, r.v), truth[r.index]) < LABEL_PX for r in res.readings)


def test_windows_keep_both_readings_of_a_pair() -> None:
    frames, uv, ids, pan, tilt, period = _rendered(1, 3, 2, extra=BOOK.length)
    res = decode_windows(frames, period, BOOK, INTR, pan, tilt, frames_for(BOOK.length), pairs=PairConfig())
    partners = [r for r in res.readings if r.partner is not None]
    assert partners and all(any(o.index == r.partner for o in partners) for r in partners)
    truth = {int(i): uv[k] for k, i in enumerate(ids)}
    assert all(math.dist((r.u, r.v), truth[r.index]) < (TOL_PX if r.partner is not None else LABEL_PX)
               for r in res.readings)
