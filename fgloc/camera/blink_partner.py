"""Known-partner decoding: the last unread LED of a crowded blob, its partners already read.

A crowded blob of the wide view holds ``n`` LEDs (2: a pair; 3: a group) that the view
decoder refuses. Once ``n - 1`` of them have been read alone in a radio round (their book
index and pixel known, :mod:`fgloc.survey.field_plan_cover`), the last one is decoded from
the wide recording that already exists, by the pair decoder's measurements
(:mod:`fgloc.camera.blink_pairs`: background-free aperture fluxes, equally spaced levels
0..n LEDs, the folded count word) and far fewer explanations than a blind pair decode:

1. **Levels.** As the pair (group) decoder: ``n + 1`` equally spaced levels (off, one
   LED, ..., ``n`` LEDs; the top level may never occur for ``n = 3``), the one-LED step
   ``min_snr`` (8) noise sigmas, dark when off, at most one sample above the top level (a
   further LED refuses). Each sample's count folds into the count word (every position).
2. **Explanations.** For every rotation of every known word, the remainder ``counts -
   sum(known rotated bits)`` is compared with every rotation of every book word (the known
   words included: the partner showing a known word is an explanation that refuses) and
   with no LED at all. The blob is labelled only if exactly one explanation is exact, its
   word is no known word, and every other explanation is at least ``margin`` count errors
   away. A known mote that is not in the blob leaves a remainder that is no book word.
3. **Anchors.** Under that explanation, the samples where only the unknown LED is lit
   (its exclusive samples, at least ``min_exclusive``) give its centroid (mean exclusive
   image minus the mean all-off image, per-sample centroids agreeing within
   ``max_centroid_spread_px``); each known LED's own exclusive samples, where it has
   ``min_exclusive``, must put it within ``known_px`` of its given pixel.

Rotation-free books only. Pixels: OpenCV convention (the wide view's); fluxes DN.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_decoder import sample_stack
from fgloc.camera.blink_groups import _levels, led_levels
from fgloc.camera.blink_pairs import (
    PairConfig,
    _rotation_table,
    background_free_aperture,
    count_and_singles,
    exclusive_centroids,
)
from fgloc.camera.led_detection import DetectorConfig, detect_led


@dataclass(frozen=True)
class PartnerConfig:
    """Known-partner thresholds; the level, aperture and centroid ones are the pair decoder's."""

    #: the pair decoder's thresholds, the one-LED step gate at 8 noise sigmas (the group
    #: decoder's; level band 2.4 sigma): a count error cannot label, only refuse (margin)
    pair: PairConfig = PairConfig(min_snr=8.0)
    margin: int = 3  #: every other explanation at least this many count errors away
    known_px: float = 1.0  #: a known LED's exclusive centroid within this of its given pixel


@dataclass(frozen=True)
class PartnerResult:
    """The decoded partner (book ``index``, rotation, pixel ``uv``) or a refusal ``reason``."""

    index: int | None
    uv: tuple[float, float] | None
    sigma_px: float
    exclusive: int
    reason: str = ""
    rotation: int = -1

    @property
    def ok(self) -> bool:
        return self.index is not None


def _refuse(why: str, exclusive: int = 0) -> PartnerResult:
    return PartnerResult(None, None, math.nan, exclusive, why)


def explain_partner(book: CodeBook, counts: np.ndarray, known: Sequence[int], margin: int = 3
                    ) -> tuple[tuple[int, int, tuple[int, ...]] | None, str]:
    """The unique partner of ``known`` (book indices) in the count word ``counts`` ((L,),
    0..len(known)+1): ``(index, rotation, known rotations)`` when exactly one (rotations of
    the known words, rotated book word) explains ``counts`` exactly, that word is no known
    word, and every other explanation (any rotations, any book word, or no partner) is at
    least ``margin`` count errors (L1) away; otherwise (None, why). Exhaustive."""
    if book.synchronized:
        raise ValueError("known-partner decoding needs a rotation-free book")
    length = book.length
    c = np.asarray(counts, np.int64)
    if c.shape != (length,):
        raise ValueError(f"count word of length {c.size}, book length {length}")
    if not known or len(set(known)) != len(known):
        raise ValueError(f"known partners must be distinct book indices ({list(known)})")
    bits, idx, rot = _rotation_table(length, book.words)
    combos = list(itertools.product(range(length), repeat=len(known)))
    s = np.zeros((len(combos), length), np.int64)
    for j, k in enumerate(known):
        s += bits[np.array([k * length + r[j] for r in combos])]
    res = c[None, :] - s  # (R, L)
    d = np.abs(res[:, None, :] - bits[None, :, :]).sum(axis=2)  # (R, M)
    none = np.abs(res).sum(axis=1)  # no partner at all
    exact = np.argwhere(d == 0)
    if len(exact) == 0:
        return None, "remainder is no book word"
    if len(exact) > 1 or (none == 0).any():
        return None, f"{len(exact) + int((none == 0).sum())} exact explanations: not unique"
    ri, m = (int(x) for x in exact[0])
    word = int(idx[m])
    if word in known:
        return None, "remainder is a known word"
    d[ri, m] = margin  # the explanation itself
    near = int((d < margin).sum() + (none < margin).sum())
    if near:
        return None, f"{near} other explanations within {margin - 1} count errors: not unique"
    return (word, int(rot[m]), tuple(int(x) for x in combos[ri])), ""


def decode_partner(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, u: float, v: float, book: CodeBook,
    noise_sigma: float, known: Sequence[tuple[int, tuple[float, float]]], config: PartnerConfig | None = None,
) -> PartnerResult:
    """Decode the last LED of the blob at pixel (``u``, ``v``) of the sample ``stack``
    ((N, H, W) float, ``valid`` (N,) delivered samples, ``positions`` (N,) fold position of
    each sample, as :func:`fgloc.camera.blink_pairs.decode_pair`), given ``known``: the
    ``(book index, (u, v) pixel)`` of every other LED of the blob (one for a pair, two for a
    group of three), read in radio rounds; see the module docstring. ``noise_sigma``:
    per-pixel noise of a frame difference (DN)."""
    cfg = config or PartnerConfig()
    pc = cfg.pair
    n = len(known) + 1
    if n not in (2, 3):
        raise ValueError(f"one or two known partners ({len(known)})")
    r = pc.radius_px if n == 2 else pc.group_radius_px

    def off_and_one(f: np.ndarray) -> tuple[float, float]:
        lv = _levels(f, n + 1)
        return float(lv[0]), float(lv[1])

    window = background_free_aperture(stack, valid, u, v, r, noise_sigma, off_and_one)
    if window is None:
        return _refuse("too close to the image border")
    big, flux, noise, pad, (ox, oy) = window
    fitted = led_levels(flux, valid, n, pc, noise, pc.min_snr if n == 2 else pc.group_min_snr, ideal=True)
    if isinstance(fitted, str):
        return _refuse(fitted)
    levels, step = fitted
    length = book.length
    counted = count_and_singles(big, flux, valid, positions, tuple(float(x) for x in levels), step, pc, length,
                                pad, r, "all-off")
    if isinstance(counted, str):
        return _refuse(counted)
    count, cword, dark, _, _ = counted
    hit, why = explain_partner(book, cword, [k for k, _ in known], cfg.margin)
    if hit is None:
        return _refuse(why)
    word, rotation, known_rot = hit
    bits, _, _ = _rotation_table(length, book.words)
    lit = np.array([bits[word * length + rotation][positions]]
                   + [bits[k * length + kr][positions] for (k, _), kr in zip(known, known_rot)])  # (n, N)
    alone = [np.flatnonzero((count == 1) & (lit[j] == 1) & (lit.sum(axis=0) == 1)) for j in range(n)]
    excl = int(alone[0].size)
    if excl < pc.min_exclusive:
        return _refuse(f"{excl} exclusive samples: fewer than {pc.min_exclusive}", excl)
    anchored = [j for j in range(1, n) if alone[j].size >= pc.min_exclusive]
    found = exclusive_centroids(big, dark, [alone[j] for j in [0, *anchored]], pad, r, pc.max_centroid_spread_px)
    if isinstance(found, str):
        return _refuse(found, excl)
    uv, sig = found
    for (j, (cu_j, cv_j)) in zip(anchored, uv[1:]):
        ku, kv = known[j - 1][1]
        off = math.hypot(cu_j + ox - ku, cv_j + oy - kv)
        if off > cfg.known_px:
            return _refuse(f"known LED {known[j - 1][0]} {off:.2f} px from its given pixel", excl)
    return PartnerResult(word, (uv[0][0] + ox, uv[0][1] + oy), sig[0], excl, rotation=rotation)


def decode_partner_view(
    frames: Sequence[tuple[float, np.ndarray]], period: float, book: CodeBook, u: float, v: float,
    known: Sequence[tuple[int, tuple[float, float]]], config: PartnerConfig | None = None,
    detector: DetectorConfig | None = None,
) -> PartnerResult:
    """:func:`decode_partner` on a recorded view: ``frames`` ((time s, image) pairs at frame
    ``period`` s, rotation-free book, sample ``i`` at fold position ``i mod L``), the blob at
    (``u``, ``v``) (e.g. a blob the view decoder refused), the noise from the detector."""
    stack, valid = sample_stack(frames, period)
    if valid.sum() < book.length:
        return _refuse(f"{int(valid.sum())} samples")
    good = stack[valid]
    noise = float(detect_led(good.max(axis=0), good.min(axis=0), detector or DetectorConfig()).noise_sigma)
    return decode_partner(stack, valid, np.arange(valid.size) % book.length, u, v, book, noise, known, config)
