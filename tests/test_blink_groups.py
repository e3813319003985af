"""Group decoding: three LEDs in one blob labelled by their code words, or refused; never guessed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_codes import bits_of, code_book, rotate
from fgloc.camera.blink_decoder import decode_view
from fgloc.camera.blink_groups import decode_group
from fgloc.camera.blink_pairs import PairConfig
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.drivers.blink_frames import close_groups

BOOK = code_book(100)
INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
TOL_PX = 0.25  #: stated tolerance of a group-decoded centroid (1.2 px LEDs, 1500 DN, 2 DN noise)
LABEL_PX = 1.0  #: any reading farther than this from the mote its code names is a mislabel
NOISE = 2.0 * math.sqrt(2.0)  #: per-pixel noise of a frame difference of the synthetic stacks (DN)
from tests.test_blink_pairs import _stack, render_pixels  # noqa: E402  (the same synthetic samples)

GROUPS3 = PairConfig(max_group=3)


def _exclusive(words: list[tuple[int, int]]) -> list[int]:
    """Per LED, the positions of the code length where only it is lit."""
    L = BOOK.length
    b = np.array([bits_of(rotate(BOOK.words[w], r, L), L) for w, r in words], int)
    return [int(((b[k] == 1) & (b.sum(axis=0) == 1)).sum()) for k in range(len(words))]


def _decodable_words(rng: np.random.Generator, need: int = 2) -> list[tuple[int, int]]:
    """Three distinct rotated words, each with at least ``need`` exclusive positions."""
    while True:
        ids = rng.choice(100, 3, replace=False)
        words = [(int(i), int(rng.integers(BOOK.length))) for i in ids]
        if min(_exclusive(words)) >= need:
            return words


@pytest.mark.parametrize("scale", [1.0, 1.6, 2.4])
def test_synthetic_group_three_ids_and_centroids(scale: float) -> None:
    """A triangle of three LEDs (sides ~ 1.7 to 4 px): all three IDs, each centroid within TOL_PX."""
    uv = [(20.0 - scale, 20.0), (20.0 + scale, 20.2), (20.1, 20.0 + 1.5 * scale)]
    words = _decodable_words(np.random.default_rng(int(10 * scale)))
    stack, valid, pos = _stack(words, uv, seed=int(10 * scale))
    res = decode_group(stack, valid, pos, 20.0, 20.5, BOOK, NOISE, GROUPS3)
    assert res.ok and res.index is not None and res.uv is not None, res.reason
    got = dict(zip(res.index, res.uv))
    assert set(got) == {w for w, _ in words}
    for (w, _), p in zip(words, uv):
        assert math.dist(got[w], p) < TOL_PX


def test_synthetic_too_few_exclusive_samples_refused() -> None:
    """An LED whose word lies inside the other two's union is never lit alone: refused; a
    decodable group is refused when more exclusive samples are asked for than exist."""
    rng = np.random.default_rng(5)
    L = BOOK.length
    uv = [(18.0, 20.0), (22.0, 20.0), (20.0, 23.0)]
    while True:
        words = _decodable_words(rng, 0)
        if min(_exclusive(words)) == 0 and sorted(_exclusive(words))[1] >= 2:
            break
    stack, valid, pos = _stack(words, uv, seed=1)
    res = decode_group(stack, valid, pos, 20.0, 21.0, BOOK, NOISE, GROUPS3)
    assert not res.ok
    while True:  # a decodable group with more all-off samples than its scarcest LED's exclusive ones
        words = _decodable_words(rng, 3)
        bits = np.array([bits_of(rotate(BOOK.words[w], r, L), L) for w, r in words], int)
        if int((bits.sum(axis=0) == 0).sum()) > min(_exclusive(words)):
            break
    stack, valid, pos = _stack(words, uv, seed=2)
    ok = decode_group(stack, valid, pos, 20.0, 21.0, BOOK, NOISE, GROUPS3)
    assert ok.ok, ok.reason
    more = decode_group(stack, valid, pos, 20.0, 21.0, BOOK, NOISE,
                        PairConfig(max_group=3, min_exclusive=min(ok.exclusive) + 1))
    assert not more.ok and "exclusive" in more.reason, more.reason


def test_synthetic_four_leds_refused() -> None:
    uv = [(18.0, 19.0), (22.0, 19.0), (18.5, 22.5), (21.8, 22.2)]
    rng = np.random.default_rng(9)
    for seed in range(4):
        words = _decodable_words(rng, 2) + [(int(rng.choice([w for w in range(100)])), int(rng.integers(16)))]
        if len({w for w, _ in words}) < 4:
            continue
        stack, valid, pos = _stack(words, uv, seed=seed)
        res = decode_group(stack, valid, pos, 20.0, 20.5, BOOK, NOISE, GROUPS3)
        assert not res.ok, res.index


def _rendered(seed: int, n_groups: int, singles: int, size: int = 3, glints: int = 10,
              ) -> tuple[list, np.ndarray, np.ndarray, float, float, float]:
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    uv = close_groups(n_groups, size, 320, 240, rng, clear_px=12.0)
    uv = np.vstack([uv, np.column_stack([rng.uniform(20, 300, singles), rng.uniform(20, 220, singles)])])
    return render_pixels(rng, pan, tilt, uv, glints)


def test_rendered_groups_labelled_and_off_by_default() -> None:
    """Rendered 320 x 240 views (glints, flicker, drops) with four groups of three: with
    ``max_group=2`` no group is read as a group; with 3, every reading lies within LABEL_PX
    of its mote (mislabels 0), group readings within TOL_PX, naming the other two."""
    hits = 0
    for seed in range(3):
        frames, uv, ids, pan, tilt, period = _rendered(seed, 4, 4)
        truth = {int(i): uv[k] for k, i in enumerate(ids)}
        plain = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=PairConfig())
        assert not any(r.group for r in plain.readings)
        res = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=GROUPS3)
        for r in res.readings:
            assert math.dist((r.u, r.v), truth[r.index]) < LABEL_PX  # mislabels 0
            if r.group:
                k = int(np.flatnonzero(ids == r.index)[0])
                assert k < 12 and set(r.group) == {int(ids[m]) for m in range(3 * (k // 3), 3 * (k // 3) + 3)} - {
                    r.index}
                assert math.dist((r.u, r.v), truth[r.index]) < TOL_PX
                hits += 1
    assert hits >= 12  # of 36 LEDs in groups (12 groups)


def test_rendered_four_leds_refused() -> None:
    """Crowded groups of four are never read as groups (nor mislabelled)."""
    for seed in range(2):
        frames, uv, ids, pan, tilt, period = _rendered(seed + 20, 3, 3, size=4, glints=0)
        truth = {int(i): uv[k] for k, i in enumerate(ids)}
        res = decode_view(frames, period, BOOK, INTR, pan, tilt, pairs=GROUPS3)
        assert not {r.index for r in res.readings if r.group} & {int(i) for i in ids[:12]}
        assert all(math.dist((r.u, r.v), truth[r.index]) < LABEL_PX for r in res.readings)
