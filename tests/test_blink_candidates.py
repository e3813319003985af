"""Candidate-restricted decoding of short recordings: right labels, refusals, the rule's math."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.blink_candidates import (
    Candidate,
    CandidateRule,
    candidate_distances,
    decode_candidates,
    label_samples,
    rotation_bits,
)
from fgloc.camera.blink_codes import CodeBook, bits_of, code_book, hamming, rotate
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_with_codes, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera

INTR = CameraIntrinsics.from_fov(320, 240, 50.0)
BOOK = code_book(100)
L = BOOK.length


def _frames(seed: int, uv: np.ndarray, ids: list[int], n_frames: int, book: CodeBook = BOOK, glints: int = 0,
            drop: float = 0.05) -> tuple[list[tuple[float, np.ndarray]], float, float, float]:
    """A rendered view of motes ``ids`` at pixels ``uv`` (drops, 1 % repeats, two flickering lamps)."""
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    p, t = pixel_to_pan_tilt(INTR, uv, pan, tilt)
    pts = pan_tilt_bearing(p, t) * rng.uniform(3.0, 20.0, len(ids))[:, None]
    pos = {f"m{k}": pts[k] for k in range(len(ids))}
    cfg = BlinkRenderConfig(glints=glints, drop_rate=drop, duplicate_rate=0.01)
    motes = motes_with_codes(pos, {f"m{k}": book.bits(i) for k, i in enumerate(ids)},
                             round(1 / cfg.frame_rate_hz, 5), rng)
    sp, st = pixel_to_pan_tilt(INTR, np.array([[60.0, 60.0], [250.0, 180.0]]), pan, tilt)
    statics = pan_tilt_bearing(sp, st) * 30.0
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    return render_view(cam, INTR, pan, tilt, motes, n_frames, rng, cfg, statics), 1 / cfg.frame_rate_hz, pan, tilt


def _brute_distance(samples: np.ndarray, word: int, length: int) -> int:
    """Fewest mismatching clean samples of ``samples`` (sample i at bit i mod L) over rotations."""
    best = len(samples) + 1
    for r in range(length):
        bits = bits_of(rotate(word, r, length), length)
        best = min(best, sum(1 for i, s in enumerate(samples.tolist()) if s >= 0 and s != bits[i % length]))
    return best


@pytest.mark.parametrize("seed", range(5))
def test_restricted_distances_match_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(L + 2, 3 * L + 3))
    samples = rng.integers(-1, 2, n).astype(np.int8)
    idx = [int(k) for k in rng.choice(len(BOOK), 7, replace=False)]
    d, rot = candidate_distances(samples, np.arange(n) % L, rotation_bits(BOOK, idx))
    for c, k in enumerate(idx):
        assert d[c] == _brute_distance(samples, BOOK.words[k], L)
        bits = bits_of(rotate(BOOK.words[k], int(rot[c]), L), L)
        assert d[c] == sum(1 for i, s in enumerate(samples.tolist()) if s >= 0 and s != bits[i % L])


def test_clean_rotated_word_labels_exactly_and_other_words_keep_the_book_distance() -> None:
    idx = [4, 11, 37, 80]
    table = rotation_bits(BOOK, idx)
    for c, k in enumerate(idx):
        r = 5 + c
        samples = np.array([bits_of(rotate(BOOK.words[k], r, L), L)[i % L] for i in range(L + 2)], np.int8)
        d, _ = candidate_distances(samples, np.arange(L + 2) % L, table)
        assert d[c] == 0
        # every other word is at least the book distance away on a full window (3), here more
        # samples: never less than the minimum rotation Hamming distance
        for o, k2 in enumerate(idx):
            if o != c:
                full = min(hamming(rotate(BOOK.words[k], r, L), rotate(BOOK.words[k2], q, L)) for q in range(L))
                assert d[o] >= full >= 3
        row, why = label_samples(samples, np.arange(L + 2) % L, L, table, CandidateRule())
        assert row == c, why


def test_erasure_budget_and_errors() -> None:
    idx = [2, 50]
    table = rotation_bits(BOOK, idx)
    tight = CandidateRule(max_unread=1, book_margin=0)
    clean = np.array([bits_of(BOOK.words[2], L)[i % L] for i in range(L + 2)], np.int8)
    one = clean.copy()
    one[5] = -1  # bit 5 read once only: one unread position
    assert label_samples(one, np.arange(L + 2) % L, L, table, tight)[0] == 0
    two = one.copy()
    two[9] = -1
    row, why = label_samples(two, np.arange(L + 2) % L, L, table, tight)
    assert row is None and "never read cleanly" in why
    assert label_samples(two, np.arange(L + 2) % L, L, table, CandidateRule(max_unread=2, book_margin=0))[0] == 0
    wrong = clean.copy()
    wrong[3] ^= 1
    row, why = label_samples(wrong, np.arange(L + 2) % L, L, table, CandidateRule())
    assert row is None and "matches no candidate" in why


def _close_words() -> tuple[int, int, int, int, list[int]]:
    """Two book words a, b and rotations ra, rb at the book distance 3, and the differing positions."""
    for a in range(len(BOOK)):
        for b in range(len(BOOK)):
            if a == b:
                continue
            for rb in range(L):
                wa, wb = BOOK.words[a], rotate(BOOK.words[b], rb, L)
                if hamming(wa, wb) == 3:
                    diff = [p for p in range(L) if bits_of(wa, L)[p] != bits_of(wb, L)[p]]
                    return a, b, 0, rb, diff
    raise AssertionError("the book has no pair at distance 3")


def test_book_margin_refuses_a_non_candidate_that_unread_bits_and_one_error_would_turn_into_a_candidate() -> None:
    a, b, _, rb, diff = _close_words()
    bits_b = bits_of(rotate(BOOK.words[b], rb, L), L)
    samples = np.array([bits_b[i % L] for i in range(L)], np.int8)  # mote b (no candidate) lit, L samples
    samples[diff[0]] = -1
    samples[diff[1]] = -1  # two of the three differing bits unread
    samples[diff[2]] ^= 1  # and one wrong sample: every clean sample now agrees with candidate a
    pos = np.arange(L) % L
    table = rotation_bits(BOOK, [a])
    others = rotation_bits(BOOK, [k for k in range(len(BOOK)) if k != a])
    assert candidate_distances(samples, pos, table)[0][0] == 0
    unguarded = CandidateRule(max_unread=2, book_margin=0)
    assert label_samples(samples, pos, L, table, unguarded, others)[0] == 0  # the mislabel rule 4 prevents
    row, why = label_samples(samples, pos, L, table, CandidateRule(), others)
    assert row is None and "book margin" in why
    # the other book words' distances on these samples, brute force: b is one sample away
    d_others = candidate_distances(samples, pos, others)[0]
    assert int(d_others.min()) == 1
    assert min(_brute_distance(samples, BOOK.words[k], L) for k in range(len(BOOK)) if k != a) == 1


def test_rule_refuses_unsafe_budgets() -> None:
    with pytest.raises(ValueError):
        CandidateRule(max_errors=1, max_unread=2, book_margin=0)
    CandidateRule(max_errors=1, max_unread=2)  # with the book margin the guard does not rest on the budget
    with pytest.raises(ValueError):
        CandidateRule(margin=0)


def test_candidates_too_close_in_the_window_are_refused() -> None:
    # a hand-made book whose two words differ in one bit: no margin in any window
    a = 0b1100101000110100
    b = a ^ 1
    book = CodeBook(L, (a, b))
    samples = np.array([bits_of(a, L)[i % L] for i in range(L + 2)], np.int8)
    row, why = label_samples(samples, np.arange(L + 2) % L, L, rotation_bits(book, [0, 1]), CandidateRule())
    assert row is None and "within the margin" in why
    # alone, the same samples label word a
    assert label_samples(samples, np.arange(L + 2) % L, L, rotation_bits(book, [0]), CandidateRule())[0] == 0


@pytest.mark.parametrize("k", [L + 2, 2 * L + 2])
def test_labels_right_on_rendered_short_recordings(k: int) -> None:
    uv = np.array([[50.0, 200.0], [160.3, 120.7], [280.0, 40.0], [100.0, 100.0], [220.0, 190.0]])
    ids = [3, 17, 42, 64, 99]
    frames, period, pan, tilt = _frames(1, uv, ids, k, glints=4)
    rng = np.random.default_rng(7)
    cands = [Candidate(i, uv[m, 0] + rng.normal(0, 2), uv[m, 1] + rng.normal(0, 2), 8.0) for m, i in enumerate(ids)]
    cands += [Candidate(j, uv[m, 0] + 5.0, uv[m, 1] - 3.0, 8.0) for m, j in enumerate([5, 23, 61])]  # dark decoys
    res = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt)
    got = {r.index: r for r in res.readings}
    assert set(got) <= set(ids) and len(got) >= 4  # a miss is allowed, a wrong ID is not
    for m, i in enumerate(ids):
        if i in got:
            assert math.hypot(got[i].u - uv[m, 0], got[i].v - uv[m, 1]) < 0.5
            p, t = pixel_to_pan_tilt(INTR, uv[m], pan, tilt)
            assert abs(math.remainder(got[i].pan - float(p), 2 * math.pi)) < 2e-3 and abs(got[i].tilt - float(t)) < 2e-3
    assert set(res.missed) == set(ids + [5, 23, 61]) - set(got)
    assert res.samples == k


def test_non_candidate_led_at_the_spot_is_refused() -> None:
    uv = np.array([[100.0, 100.0], [200.0, 150.0]])
    frames, period, pan, tilt = _frames(3, uv, [8, 70], L + 2, drop=0.0)
    # mote 70 is lit (it missed the pause) where candidates 8 and 12 are predicted: it is no candidate
    cands = [Candidate(8, 100.0, 100.0, 8.0), Candidate(12, 201.0, 151.0, 8.0), Candidate(44, 204.0, 148.0, 8.0)]
    res = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt)
    assert [r.index for r in res.readings] == [8]
    assert any(math.hypot(rf.u - 200.0, rf.v - 150.0) < 2.0 and "matches no candidate" in rf.reason
               for rf in res.refused)
    assert set(res.missed) == {12, 44}


def test_candidates_predicted_near_no_blob_are_unseen_and_blobs_without_candidates_refused() -> None:
    uv = np.array([[100.0, 100.0], [200.0, 150.0]])
    frames, period, pan, tilt = _frames(4, uv, [8, 70], L + 2, drop=0.0)
    cands = [Candidate(8, 101.0, 99.0, 6.0), Candidate(30, 40.0, 200.0, 6.0)]
    res = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt)
    assert [r.index for r in res.readings] == [8]
    assert res.missed == (30,) and res.unseen == (30,)
    assert any("no candidate predicted here" in rf.reason and math.hypot(rf.u - 200.0, rf.v - 150.0) < 2.0
               for rf in res.refused)


def test_drops_are_erasures_within_the_budget() -> None:
    uv = np.array([[60.0, 60.0], [120.0, 90.0], [180.0, 120.0], [240.0, 150.0], [90.0, 180.0], [200.0, 60.0]])
    ids = [1, 9, 27, 33, 58, 91]
    frames, period, pan, tilt = _frames(6, uv, ids, L + 2, drop=0.2)
    assert len(frames) < L + 2  # frames were dropped
    cands = [Candidate(i, uv[m, 0], uv[m, 1], 6.0) for m, i in enumerate(ids)]
    res = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt)
    assert {r.index for r in res.readings} <= set(ids)
    assert res.erased > 0
    tight = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt, CandidateRule(max_unread=1))
    assert {r.index for r in tight.readings} <= {r.index for r in res.readings}
    loose = decode_candidates(frames, period, BOOK, cands, INTR, pan, tilt, CandidateRule(max_unread=5))
    assert {r.index for r in res.readings} <= {r.index for r in loose.readings} <= set(ids)


def test_whole_book_without_predictions_reads_full_recordings_like_the_blind_decoder() -> None:
    from fgloc.camera.blink_decoder import decode_view

    uv = np.array([[50.0, 200.0], [160.3, 120.7], [280.0, 40.0], [100.0, 100.0], [220.0, 190.0]])
    ids = [3, 17, 42, 64, 99]
    frames, period, pan, tilt = _frames(2, uv, ids, 3 * L + 2, glints=4)
    blind = decode_view(frames, period, BOOK, INTR, pan, tilt)
    res = decode_candidates(frames, period, BOOK, [Candidate(i) for i in range(len(BOOK))], INTR, pan, tilt)
    assert {r.index for r in blind.readings} <= {r.index for r in res.readings} <= set(ids)


def test_bad_candidates_are_refused() -> None:
    frames, period, pan, tilt = _frames(5, np.array([[100.0, 100.0]]), [8], L + 2)
    with pytest.raises(ValueError):
        decode_candidates(frames, period, BOOK, [Candidate(8), Candidate(8)], INTR, pan, tilt)
    with pytest.raises(ValueError):
        decode_candidates(frames, period, BOOK, [Candidate(100)], INTR, pan, tilt)
