"""Decode a short recording whose blobs may only be a few known motes (radio-separation rounds).

In a radio-separation round the base station pauses every mote but one colour class, so
the lit motes of a round view are class members whose IDs are known and whose directions
were predicted from the wide pass (:mod:`fgloc.survey.coded_separation`). A blob then has
a tiny candidate set, and a recording of ``K'`` samples (as few as ``L + 2``) can label it
where a blind decode against the whole book needs all ``L`` bit positions read cleanly in
``3L + 2`` samples (:func:`fgloc.camera.blink_decoder.decode_view`).

**Input.** The frames of one view (timestamps, seconds; nominal period = bit period), the
rotation-free :class:`~fgloc.camera.blink_codes.CodeBook` and the candidates
(:class:`Candidate`: book index, optional predicted pixel and radius, px). Samples, blobs,
levels and the one-LED tests are exactly the blind decoder's
(:func:`~fgloc.camera.blink_decoder.sample_stack`, :func:`~fgloc.camera.blink_decoder.read_blob`):
each sample ``s_i`` (``i = 0..K'-1``) of a blob is 1, 0 or erased.

**Rule** (:class:`CandidateRule`, :func:`label_samples`). A blob's *candidates in range*
are those predicted within their ``radius_px`` of its centre (or predicted nowhere: any
blob). For a candidate word ``w`` and rotation ``r`` the *mismatches* are

    d(w, r) = #{ i : s_i not erased and s_i != bits(rotate(w, r))[i mod L] }

(every clean sample counts, so a bit read twice must agree twice), and ``d(w) = min_r
d(w, r)`` (:func:`candidate_distances`). The blob is labelled with candidate ``c`` only if

1. at most ``max_unread`` (default 3) of the ``L`` bit positions have no clean sample
   (erasure budget: drops, repeated frames, samples between the levels);
2. ``d(c) <= max_errors`` (default 0: every clean sample agrees with one rotation of ``c``);
3. every other candidate in range has ``d >= d(c) + margin`` (default 2) at every rotation;
4. every other word of the book (the non-candidates, and candidates out of range) has
   ``d >= d(c) + book_margin`` (default 2) at every rotation, on the same clean samples.

Otherwise it is refused with the reason, never guessed. Rule 4 is the guard against a lit
mote that is no candidate (one that missed the pause): if the blob is book word ``x`` read
with ``e`` wrong samples, ``d(x) <= e``, so labelling it ``c`` needs ``e >= d(c) +
book_margin``: with the defaults two wrong samples, whatever the unread positions hide
(the blind decoder needs three, on a full word). Unread positions only cost labels whose
word some other book word matches there. With ``book_margin = 0`` (rule 4 off) the guard
comes from the book distance 3 alone: another word differs from every rotation of ``c``
in >= 3 positions, so in >= ``3 - max_unread`` read ones, and ``max_errors + max_unread``
must then stay below 3. Rotation is free (motes are not synchronized); a candidate's word
is primitive, so its rotations differ, but any rotation labels the same ID.

**Output** (:class:`CandidateDecode`). Readings as the blind decoder's
(:meth:`~fgloc.camera.blink_decoder.BlobSamples.reading`: centroid over the clean on
samples, (pan, tilt) by the exact pixel composition); one candidate labelled on two blobs
is refused on both (duplicate); blobs with no candidate in range are refused; candidates
not labelled are *missed*, and those predicted within range of no blob at all are also
listed as *unseen*.

Rotation-free books only. Pixels: OpenCV convention; angles radians.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fgloc.camera.blink_codes import MIN_DISTANCE, CodeBook, bits_of, rotate
from fgloc.camera.blink_decoder import (
    DecodedReading,
    DecoderConfig,
    RefusedBlob,
    read_blob,
    sample_stack,
)
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_detection import detect_led


@dataclass(frozen=True)
class Candidate:
    """A mote that may be lit in the view: book ``index``, and where it is predicted
    (pixel ``u``, ``v``; None: anywhere) within ``radius_px``."""

    index: int
    u: float | None = None
    v: float | None = None
    radius_px: float = math.inf

    def near(self, u: float, v: float) -> bool:
        """Whether a blob centred at (``u``, ``v``) px is in this candidate's range."""
        if self.u is None or self.v is None:
            return True
        return math.hypot(u - self.u, v - self.v) <= self.radius_px


@dataclass(frozen=True)
class CandidateRule:
    """Thresholds of the rule (module docstring): mismatching samples, margin, unread bits."""

    max_errors: int = 0  #: mismatching clean samples the label may have
    margin: int = 2  #: every other candidate in range at least this many mismatches more
    max_unread: int = 3  #: bit positions (of L) allowed without a clean sample
    book_margin: int = 2  #: every other book word at least this many mismatches more (0: not checked)
    decoder: DecoderConfig = field(default_factory=DecoderConfig)  #: levels and one-LED tests

    def __post_init__(self) -> None:
        if self.max_errors < 0 or self.max_unread < 0 or self.margin < 1 or self.book_margin < 0:
            raise ValueError(f"rule: errors {self.max_errors}, unread {self.max_unread}, book margin "
                             f"{self.book_margin} >= 0, margin {self.margin} >= 1")
        if self.book_margin == 0 and self.max_errors + self.max_unread >= MIN_DISTANCE:
            raise ValueError(f"rule: max_errors + max_unread ({self.max_errors} + {self.max_unread}) must stay "
                             f"below the book distance {MIN_DISTANCE}: another book word could be labelled unread")


@dataclass(frozen=True)
class CandidateDecode:
    """What one view gave: readings, refused blobs, candidates missed (and of those, unseen:
    predicted within range of no blob), sample count and erased samples."""

    readings: tuple[DecodedReading, ...]
    refused: tuple[RefusedBlob, ...]
    missed: tuple[int, ...]
    unseen: tuple[int, ...]
    samples: int
    erased: int


def rotation_bits(book: CodeBook, indices: Sequence[int]) -> np.ndarray:
    """(C, L, L) int8: ``[c, r, p]`` = bit ``p`` (transmission order) of word ``indices[c]``
    rotated left by ``r`` (:func:`fgloc.camera.blink_codes.rotate`)."""
    return _book_rotation_bits(book.length, book.words)[np.asarray(list(indices), dtype=np.int64)]


@functools.lru_cache(maxsize=8)
def _book_rotation_bits(length: int, words: tuple[int, ...]) -> np.ndarray:
    """:func:`rotation_bits` of every word of a book (cached per book)."""
    out = np.zeros((len(words), length, length), np.int8)
    for c, w in enumerate(words):
        for r in range(length):
            out[c, r] = bits_of(rotate(w, r, length), length)
    out.setflags(write=False)
    return out


def candidate_distances(samples: np.ndarray, positions: np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate of ``table`` (:func:`rotation_bits`), the fewest mismatching clean
    samples over rotations and the rotation reaching it (first on ties): ``samples`` (N,)
    1/0/-1 (erased), ``positions`` (N,) bit position of each sample (``i mod L``)."""
    clean = np.asarray(samples) >= 0
    s = np.asarray(samples)[clean].astype(np.int8)
    pred = table[:, :, np.asarray(positions)[clean]]  # (C, L, n_clean)
    d = (pred != s[None, None, :]).sum(axis=2)
    rot = d.argmin(axis=1)
    return d.min(axis=1), rot


def label_samples(samples: np.ndarray, positions: np.ndarray, length: int, table: np.ndarray,
                  rule: CandidateRule, others: np.ndarray | None = None) -> tuple[int | None, str]:
    """The rule of the module docstring for one blob: (row of ``table`` labelled, "") or
    (None, why). ``table``: the candidates in range (:func:`rotation_bits`); ``others``: the
    rest of the book (rule 4; None or ``book_margin`` 0: not checked)."""
    clean = np.asarray(samples) >= 0
    unread = length - len(set(np.asarray(positions)[clean].tolist()))
    if unread > rule.max_unread:
        return None, f"{unread} of {length} bits never read cleanly (budget {rule.max_unread})"
    if not len(table):
        return None, "no candidate in range"
    d, _ = candidate_distances(samples, positions, table)
    order = np.argsort(d, kind="stable")
    best = int(order[0])
    if d[best] > rule.max_errors:
        return None, f"matches no candidate ({int(d[best])} mismatching samples at best)"
    if len(order) > 1 and d[order[1]] < d[best] + rule.margin:
        return None, (f"two candidates within the margin ({int(d[best])} and {int(d[order[1]])} mismatches,"
                      f" margin {rule.margin})")
    if rule.book_margin and others is not None and len(others):
        d_other, _ = candidate_distances(samples, positions, others)
        if int(d_other.min()) < d[best] + rule.book_margin:
            return None, (f"another book word within the book margin ({int(d_other.min())} mismatches against "
                          f"{int(d[best])}, margin {rule.book_margin})")
    return best, ""


def decode_candidates(
    frames: Sequence[tuple[float, np.ndarray]], period: float, book: CodeBook, candidates: Sequence[Candidate],
    intr: CameraIntrinsics, head_pan: float, head_tilt: float, rule: CandidateRule | None = None,
) -> CandidateDecode:
    """Label the blobs of ``frames`` with ``candidates`` only (see the module docstring).
    ``period`` s; head (pan, tilt) rad as read back. Candidate indices must be distinct
    book indices; the book must be rotation-free."""
    rule = rule or CandidateRule()
    if book.synchronized:
        raise ValueError("candidate decoding needs a rotation-free book")
    idx = [c.index for c in candidates]
    if len(set(idx)) != len(idx) or any(not 0 <= k < len(book) for k in idx):
        raise ValueError(f"candidates: distinct book indices 0..{len(book) - 1} ({idx})")
    stack, valid = sample_stack(frames, period)
    n = int(valid.size)
    erased = int(n - valid.sum())
    unseen_all = tuple(sorted(idx))
    if valid.sum() < book.length:
        return CandidateDecode((), (), unseen_all, unseen_all, n, erased)
    positions = np.arange(n) % book.length
    good = stack[valid]
    det = detect_led(good.max(axis=0), good.min(axis=0), rule.decoder.detector)
    refused: list[RefusedBlob] = [RefusedBlob(b.u, b.v, "ambiguous", f"unresolved blob: {b.reason}")
                                  for b in det.rejected if "elongation" in b.reason]
    table = rotation_bits(book, idx)
    every = _book_rotation_bits(book.length, book.words) if rule.book_margin else None
    seen: set[int] = set()
    labelled: list[DecodedReading] = []
    for blob in det.candidates:
        near = [k for k, c in enumerate(candidates) if c.near(blob.u, blob.v)]
        seen.update(idx[k] for k in near)
        if not near:
            refused.append(RefusedBlob(blob.u, blob.v, "rejected", "no candidate predicted here"))
            continue
        got = read_blob(stack, valid, blob, float(det.noise_sigma), rule.decoder)
        if isinstance(got, RefusedBlob):
            refused.append(got)
            continue
        others = None if every is None else every[np.setdiff1d(np.arange(len(book)), [idx[k] for k in near])]
        row, why = label_samples(got.bits, positions, book.length, table[near], rule, others)
        if row is None:
            refused.append(RefusedBlob(blob.u, blob.v, "rejected", why))
            continue
        labelled.append(got.reading(idx[near[row]], intr, head_pan, head_tilt))
    counts = Counter(r.index for r in labelled)
    readings = []
    for r in labelled:
        if counts[r.index] > 1:
            refused.append(RefusedBlob(r.u, r.v, "duplicate", f"code {r.index} labelled on {counts[r.index]} blobs",
                                       r.index))
        else:
            readings.append(r)
    got_ids = {r.index for r in readings}
    missed = tuple(sorted(k for k in idx if k not in got_ids))
    unseen = tuple(sorted(k for k in idx if k not in seen))
    return CandidateDecode(tuple(sorted(readings, key=lambda r: r.index)), tuple(refused), missed, unseen, n, erased)
