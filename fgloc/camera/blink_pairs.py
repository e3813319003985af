"""Pair decoding: one blob made of two blinking LEDs, labelled by their two code words.

Two motes closer than the detector separates merge into one blob, which the view
decoder (:func:`fgloc.camera.blink_decoder.decode_view`) refuses as ambiguous. The blob
blinks the **sum** of the two code words: per sample 0, 1 or 2 LEDs are lit. Where the
words differ, samples exist in which only one of the two LEDs is lit (its *exclusive*
samples). :func:`decode_pair` labels such a blob as a pair, never by guessing:

1. **Levels.** The blob's flux per sample in its footprint within a ``2 radius_px + 1``
   square (the pixels where its mean lit image reaches ``aperture_fraction`` of its peak,
   :func:`footprint`: far less noise than the whole square), the static background
   measured per pixel on the both-off samples and scaled by each sample's ambient gain
   (:func:`_background_free`), must show three equally spaced
   levels: off, one LED, two LEDs (equally bright within ``max_level_skew`` of the step).
   Each sample within ``level_band`` x step of a level gets that count, anything between
   is an erasure; more than one sample above the two-LED level (a third LED) refuses.
2. **Which LED.** The centroids of the one-LED samples (minus the mean both-off image)
   must form two compact clusters (:func:`_sides`); a sample between them is an erasure.
3. **Each LED's word.** Per LED: count 2 -> 1, count 0 -> 0, a one-LED sample -> 1 on its
   side and 0 on the other, folded modulo L (complete, no conflicts). Each word must
   **exactly** equal a rotation of a book word and the two words must differ: each LED
   keeps the book's distance 3 (another labelling needs three wrong bits in one word).
4. **LEDs too close to tell apart** (step 2 finds no two clusters): the count word
   alone, which must equal ``bits(rot(w_a, r_a)) + bits(rot(w_b, r_b))`` for exactly one
   pair of book words at one pair of rotations, with every other explanation (another
   pair, the same word twice, a single word; every rotation) at least ``margin`` count
   errors away (:func:`explain_counts`, :func:`unique_pair`; exhaustive over the book).
5. **Centroids.** Each LED needs ``min_exclusive`` exclusive samples (and the blob as
   many both-off samples); its centroid is that of its mean exclusive image minus the
   mean both-off image; its per-sample centroids must agree within
   ``max_centroid_spread_px`` (one LED), and the both-on image must be centred between
   the two within ``max_both_px`` (two LEDs, not three).

Rotation-free books only. Pixels: OpenCV convention; fluxes DN.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.camera.blink_codes import CodeBook, rotations


@dataclass(frozen=True)
class PairConfig:
    """Pair-decoding thresholds (pixels; fractions of the one-LED flux step)."""

    radius_px: int = 5  #: aperture half-width around the blob centre (both LEDs inside)
    group_px: float = 4.0  #: refused blobs this close form one candidate pair
    single_px: float = 2.5  #: no candidate pair this close to a decoded single LED
    neighbour_px: float = 12.0  #: a lone refused blob is tried as a pair with a decoded single LED this close
    same_px: float = 1.0  #: a pair LED with a decoded single LED's code this close to it is that LED
    level_band: float = 0.3  #: a sample within this x step of a level is that count
    max_level_skew: float = 0.2  #: |one-LED level - midpoint of off and two-LED| over the step
    min_snr: float = 12.0  #: one-LED step in flux-noise sigmas
    max_off_level: float = 0.2  #: off level over the step above which the blob is no LED pair
    margin: int = 3  #: every other explanation at least this many count errors away
    min_exclusive: int = 3  #: clean exclusive samples per LED, and both-off samples
    max_centroid_spread_px: float = 0.35  #: robust spread of one LED's exclusive-sample centroids
    max_both_px: float = 0.5  #: both-on centroid vs the midpoint of the two LEDs
    #: an LED centroid within this many px of the aperture's edge is refused: its light is cut
    #: off there (on the 320 x 240 rig a centroid 5.3 px from the centre of an r = 5 aperture lay
    #: 2.3 px off its LED, nearer another mote); the neighbour rule's wider aperture may read it
    edge_px: float = 1.0
    min_gap_px: float = 0.5  #: one-LED centroid clusters at least this far apart to tell the sides
    gap_spreads: float = 5.0  #: ... and at least this many times their robust spread
    max_group: int = 2  #: 3: a refused pair is tried as three LEDs (:mod:`fgloc.camera.blink_groups`)
    group_radius_px: int = 7  #: aperture half-width for a group of three
    group_min_snr: float = 8.0  #: one-LED step in flux-noise sigmas, group aperture (level band 2.4 sigma)
    min_template_sigmas: float = 8.0  #: one-LED templates this many noise sigmas apart to read a two-LED sample
    #: flux aperture: the blob's footprint, where its mean lit image reaches this fraction of
    #: its peak (0: the whole square; :func:`footprint`)
    aperture_fraction: float = 0.1
    #: a refused blob more than this many px from the LEDs its candidate decoded to stays refused
    #: (:func:`fgloc.camera.blink_crowd_decoding.crowd_readings`, step 6)
    explain_px: float = 1.5
    #: a peak of lit light more than this many px from every decoded LED (a crowd's and every
    #: reading's) is refused as another LED (step 7 of :mod:`fgloc.camera.blink_crowd_decoding`; inf: off)
    peak_px: float = 2.5
    peak_fraction: float = 0.25  #: ... when at least this fraction of the crowd's brightest pixel
    peak_sigmas: float = 10.0  #: ... and this many noise sigmas above the window's median


@dataclass(frozen=True)
class PairExplanation:
    """A way to write a count word: words ``a`` (rotation ``ra``) + ``b`` (rotation ``rb``),
    ``b`` = -1 for a single word, at L1 ``distance`` (count errors) from the observation."""

    a: int
    ra: int
    b: int
    rb: int
    distance: int


@dataclass(frozen=True)
class PairResult:
    """A decoded pair (``uv[k]`` the centroid of book word ``index[k]``) or a refusal ``reason``."""

    index: tuple[int, int] | None
    uv: tuple[tuple[float, float], tuple[float, float]] | None
    sigma_px: tuple[float, float]
    exclusive: tuple[int, int]
    reason: str = ""
    rule: str = ""  #: "sides" (each LED's own word) or "counts" (the count word alone)

    @property
    def ok(self) -> bool:
        return self.index is not None


@functools.lru_cache(maxsize=8)
def _rotation_table(length: int, words: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bits (M, L) int8 of every rotation of every word, word index (M,), rotation (M,))."""
    rows, idx, rot = [], [], []
    for i, w in enumerate(words):
        for k, r in enumerate(rotations(w, length)):
            rows.append([(r >> (length - 1 - j)) & 1 for j in range(length)])
            idx.append(i)
            rot.append(k)
    return np.array(rows, np.int8), np.array(idx, np.int64), np.array(rot, np.int64)


@functools.lru_cache(maxsize=8)
def _sorted_rows(length: int, words: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The rows of :func:`_rotation_table` packed into integers (first bit most significant),
    sorted, and the row index of each."""
    bits, _, _ = _rotation_table(length, words)
    packed = bits.astype(np.int64) @ (np.int64(1) << np.arange(length - 1, -1, -1, dtype=np.int64))
    order = np.argsort(packed, kind="stable")
    return packed[order], order


@functools.lru_cache(maxsize=8)
def _flip_masks(length: int, flips: int) -> np.ndarray:
    """Every integer with exactly ``flips`` of its low ``length`` bits set."""
    return np.array([sum(1 << p for p in ps) for ps in itertools.combinations(range(length), flips)], np.int64)


def explain_counts(book: CodeBook, counts: np.ndarray, max_distance: int = 2) -> list[PairExplanation]:
    """Every explanation of the count word ``counts`` ((L,), values 0..2, position 0 = first
    folded sample) within ``max_distance`` count errors (L1): single rotated words, and
    unordered pairs of rotated words (the same word twice included), sorted by distance.
    Exhaustive over the book: for a first word ``a`` the L1 distance of ``a + b`` is the number
    of positions where ``counts - a`` is -1 or 2 plus the Hamming distance of ``b`` from
    ``clip(counts - a, 0, 1)``, so every ``b`` within the budget left is looked up among the
    book's rotated words (sorted, packed into integers) instead of compared with each."""
    if book.synchronized:
        raise ValueError("pair decoding needs a rotation-free book")
    c = np.asarray(counts, np.int8)
    if c.shape != (book.length,):
        raise ValueError(f"count word of length {c.size}, book length {book.length}")
    bits, idx, rot = _rotation_table(book.length, book.words)
    out: list[PairExplanation] = []
    single = np.abs(c[None, :] - bits).sum(axis=1)
    for m in np.flatnonzero(single <= max_distance).tolist():
        out.append(PairExplanation(int(idx[m]), int(rot[m]), -1, -1, int(single[m])))
    resid = c[None, :] - bits  # (M, L) in -1..2
    bad = ((resid < 0) | (resid > 1)).sum(axis=1)
    cand = np.flatnonzero(bad <= max_distance)
    packed, order = _sorted_rows(book.length, book.words)
    weights = np.int64(1) << np.arange(book.length - 1, -1, -1, dtype=np.int64)
    target = np.clip(resid[cand], 0, 1).astype(np.int64) @ weights  # (K,) the b each a needs
    found: dict[tuple[int, int], int] = {}
    for flips in range(max_distance + 1):
        keep = bad[cand] + flips <= max_distance
        if not keep.any():
            continue
        masks, firsts = _flip_masks(book.length, flips), cand[keep]
        query = (target[keep][:, None] ^ masks[None, :]).ravel()  # (first word, flip) row-major
        lo = np.searchsorted(packed, query, "left")
        hi = np.searchsorted(packed, query, "right")
        for q in np.flatnonzero(hi > lo).tolist():
            a = int(firsts[q // masks.size])
            for b in order[lo[q]:hi[q]].tolist():
                found.setdefault((min(a, b), max(a, b)), int(bad[a]) + flips)
    for (ra, rb), d in found.items():
        out.append(PairExplanation(int(idx[ra]), int(rot[ra]), int(idx[rb]), int(rot[rb]), d))
    out.sort(key=lambda e: e.distance)
    return out


def unique_pair(book: CodeBook, counts: np.ndarray, margin: int = 3) -> tuple[PairExplanation | None, str]:
    """The one pair of distinct words that explains ``counts`` exactly, with every other
    explanation at least ``margin`` count errors away; otherwise (None, why)."""
    ex = explain_counts(book, counts, margin - 1)
    exact = [e for e in ex if e.distance == 0]
    if not exact:
        return None, "count word is no sum of two book words"
    if len(ex) > 1:
        return None, (f"{len(exact)} exact and {len(ex) - len(exact)} near explanations"
                      f" (within {margin - 1} count errors): not unique")
    e = exact[0]
    if e.b < 0:
        return None, "count word is a single book word"
    if e.a == e.b:
        return None, "count word is one word twice"
    return e, ""


def _three_levels(f: np.ndarray) -> tuple[float, float, float]:
    """Off, one-LED and two-LED levels of fluxes ``f`` (1-D three-medians, started at the extremes)."""
    lo, hi = float(np.min(f)), float(np.max(f))
    c = np.array([lo, 0.5 * (lo + hi), hi])
    for _ in range(30):
        lab = np.argmin(np.abs(f[:, None] - c[None, :]), axis=1)
        new = np.array([float(np.median(f[lab == k])) if (lab == k).any() else c[k] for k in range(3)])
        if np.allclose(new, c):
            break
        c = new
    return float(c[0]), float(c[1]), float(c[2])


def _centroid(img: np.ndarray, u0: float, v0: float, r: int = 3, clamp: bool = False) -> tuple[float, float] | None:
    """Intensity-weighted centroid (negative pixels clipped) of ``img`` in a (2r+1)^2 window
    around (u0, v0) (array coordinates), iterated twice; None when the window leaves ``img``
    (``clamp``: the window is shifted to stay inside it) or holds no light."""
    u, v = u0, v0
    for _ in range(2):
        cu, cv = int(round(u)), int(round(v))
        if clamp:
            cu, cv = min(max(cu, r), img.shape[1] - r - 1), min(max(cv, r), img.shape[0] - r - 1)
        if not (r <= cu < img.shape[1] - r and r <= cv < img.shape[0] - r):
            return None
        win = np.clip(img[cv - r: cv + r + 1, cu - r: cu + r + 1], 0.0, None)
        tot = float(win.sum())
        if tot <= 0.0:
            return None
        ys, xs = np.mgrid[-r: r + 1, -r: r + 1]
        u, v = cu + float((win * xs).sum()) / tot, cv + float((win * ys).sum()) / tot
    return u, v


def _spot(img: np.ndarray, pad: int, r: int) -> tuple[float, float] | None:
    """Centroid of one LED's image ``img`` (a patch with its centre at (pad, pad)): coarse in
    the (2r+1)^2 window kept inside the patch, refined in the 7 x 7 window around it (an LED
    up to r px off the patch centre; the small window keeps the clipped noise of the large
    one from pulling it to the centre). None as :func:`_centroid`."""
    first = _centroid(img, pad, pad, r, clamp=True)
    return _centroid(img, *first) if first is not None else None


def _refuse(why: str, exclusive: tuple[int, int] = (0, 0)) -> PairResult:
    return PairResult(None, None, (math.nan, math.nan), exclusive, why)


def _background_free(big: np.ndarray, valid: np.ndarray, ring: np.ndarray, core: np.ndarray,
                     off_and_one: Callable[[np.ndarray], tuple[float, float]] | None = None,
                     fraction: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patch stack ``big`` (N, h, w) minus its static background, each sample's flux in the
    aperture, and the aperture (a mask within ``core``). The background is the per-pixel mean
    of the darkest third of the samples
    (by a first flux in ``core`` minus the ``ring`` median), each sample scaled by its
    ambient gain (median ratio of its ``ring`` pixels to their median over the samples):
    over an aperture of ~100 px a textured background moves with the ambient light by
    as much as an LED, so it is measured, not assumed flat. ``off_and_one`` gives the off and
    the one-LED level of the first fluxes (default: of three levels, off / one / two LEDs).
    ``fraction`` > 0: the aperture is the blob's own footprint, the ``core`` pixels where the
    mean lit image (background-free samples with a first flux above the midpoint of the off
    and one-LED levels) reaches ``fraction`` of its peak (:func:`footprint`); 0: all of ``core``."""
    ref = np.median(big[valid][:, ring], axis=0)
    usable = ref > 5.0
    if usable.sum() >= 8:
        gain = np.median(big[:, ring][:, usable] / ref[usable][None, :], axis=1)
    else:
        gain = np.ones(big.shape[0])
    gain[~valid] = 1.0
    first = (big[:, core] - np.median(big[:, ring], axis=1)[:, None]).sum(axis=1)
    c0, c1 = off_and_one(first[valid]) if off_and_one is not None else _three_levels(first[valid])[:2]
    dark = np.flatnonzero(valid & (first < 0.5 * (c0 + c1)))
    bg = (big[dark] / gain[dark, None, None]).mean(axis=0)
    sub = big - gain[:, None, None] * bg[None]
    aperture = core
    if fraction > 0.0:
        lit = valid & (first >= 0.5 * (c0 + c1))
        if lit.any():
            aperture = footprint(sub[lit].mean(axis=0), core, fraction)
    return sub, sub[:, aperture].sum(axis=1), aperture


def footprint(lit_image: np.ndarray, core: np.ndarray, fraction: float) -> np.ndarray:
    """The pixels of ``core`` where ``lit_image`` (a background-free mean lit image) reaches
    ``fraction`` of its peak over ``core``: the LEDs' own footprint, an aperture that sums their
    light with far less noise than the whole square (for a Gaussian spot, ``fraction`` 0.1
    keeps 90 % of the flux on ~2 pi sigma^2 ln 10 px; two LEDs lit in different shares of
    the samples keep different shares of theirs, by at most ``fraction`` x the ratio of the
    shares, which the equal-level tests bound). All of ``core`` when the peak is not positive."""
    peak = float(lit_image[core].max())
    if peak <= 0.0:
        return core
    return core & (lit_image >= fraction * peak)


def _fold(values: np.ndarray, positions: np.ndarray, length: int) -> tuple[np.ndarray | None, str]:
    """Fold per-sample values (-1: erased) modulo ``length``: (word, "") or (None, why)."""
    word = np.full(length, -1, np.int8)
    for i in np.flatnonzero(values >= 0).tolist():
        p = int(positions[i])
        if word[p] == -1:
            word[p] = values[i]
        elif word[p] != values[i]:
            return None, "samples one period apart disagree"
    if (word < 0).any():
        return None, f"{int((word < 0).sum())} of {length} positions never read cleanly"
    return word, ""


def _spread(pu: np.ndarray, pv: np.ndarray) -> float:
    """Robust 2-D spread (1.4826 x MAD per axis, combined) of points (pu, pv), px."""
    return float(np.hypot(1.4826 * np.median(np.abs(pu - np.median(pu))),
                          1.4826 * np.median(np.abs(pv - np.median(pv)))))


def cut_aperture(stack: np.ndarray, u: float, v: float, r: int
                 ) -> tuple[np.ndarray, int, np.ndarray, np.ndarray, tuple[int, int]] | None:
    """Every sample's (2 pad + 1)^2 window (pad = r + 4) around pixel (u, v), with its
    background ring (Chebyshev distance > r + 1) and flux core (<= r) masks and the window's
    centre pixel (cu, cv); None when the window leaves the image."""
    h, w = stack.shape[1:]
    cu, cv = int(round(u)), int(round(v))
    pad = r + 4
    if not (pad <= cu < w - pad and pad <= cv < h - pad):
        return None
    big = stack[:, cv - pad: cv + pad + 1, cu - pad: cu + pad + 1]
    yy, xx = np.mgrid[-pad: pad + 1, -pad: pad + 1]
    cheb = np.maximum(abs(yy), abs(xx))
    return big, pad, cheb > r + 1, cheb <= r, (cu, cv)


def background_free_aperture(
    stack: np.ndarray, valid: np.ndarray, u: float, v: float, r: int, noise_sigma: float,
    off_and_one: Callable[[np.ndarray], tuple[float, float]] | None = None, fraction: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float, int, tuple[int, int]] | None:
    """The window around pixel (u, v) (:func:`cut_aperture`) minus its static background
    (:func:`_background_free`), each sample's flux in the aperture (the ``r`` core, or with
    ``fraction`` > 0 the blob's footprint in it), the flux noise (DN: the per-pixel
    frame-difference ``noise_sigma`` over the aperture), the window's pad and the image
    pixel of its corner (ox, oy); None when the window leaves the image."""
    cut = cut_aperture(stack, u, v, r)
    if cut is None:
        return None
    big, pad, ring, core, (cu, cv) = cut
    big, flux, aperture = _background_free(big, valid, ring, core, off_and_one, fraction)
    return big, flux, float(noise_sigma) * math.sqrt(aperture.sum() * 2.0), pad, (cu - pad, cv - pad)


def count_and_singles(big: np.ndarray, flux: np.ndarray, valid: np.ndarray, positions: np.ndarray,
                      levels: tuple[float, ...], step: float, cfg: PairConfig, length: int, pad: int, r: int,
                      off_name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list] | str:
    """Each delivered sample's lit-LED count (the level within ``cfg.level_band`` steps; -1
    none), the folded count word, the mean all-off image, the one-LED samples and their
    centroids on it; a refusal reason instead (fold failed, too few all-off samples, a
    one-LED sample without a centroid)."""
    count = np.full(flux.size, -1, np.int8)
    for k, lev in enumerate(levels):
        count[valid & (np.abs(flux - lev) <= cfg.level_band * step)] = k
    cword, why = _fold(count, positions, length)
    if cword is None:
        return why
    off = count == 0
    if int(off.sum()) < cfg.min_exclusive:
        return f"{int(off.sum())} {off_name} samples"
    dark = big[off].mean(axis=0)
    singles = np.flatnonzero(count == 1)
    cents = [_spot(big[i] - dark, pad, r) for i in singles.tolist()]
    if any(c is None for c in cents):
        return "one-LED sample without a centroid"
    return count, cword, dark, singles, cents


def exclusive_centroids(big: np.ndarray, dark: np.ndarray, only: list[np.ndarray], pad: int, r: int,
                        max_spread_px: float) -> tuple[list[tuple[float, float]], list[float]] | str:
    """Each LED's centroid (array coordinates of the aperture ``big``) on the mean of its
    exclusive samples ``only[k]`` minus the dark mean, and its standard error from the
    per-sample centroids (px). A refusal reason instead when a centroid falls at the aperture
    edge or the per-sample centroids spread more than ``max_spread_px`` (not one LED)."""
    uv: list[tuple[float, float]] = []
    sig: list[float] = []
    for sel in only:
        img = big[sel].mean(axis=0) - dark
        c = _spot(img, pad, r)
        if c is None:
            return "exclusive centroid at the aperture edge"
        per = [_centroid(big[i] - dark, *c) for i in sel.tolist()]
        if any(p is None for p in per):
            return "exclusive sample without a centroid"
        pu = np.array([p[0] for p in per if p is not None])
        pv = np.array([p[1] for p in per if p is not None])
        if _spread(pu, pv) > max_spread_px:
            return f"exclusive centroids vary ({_spread(pu, pv):.2f} px): not one LED"
        uv.append(c)
        sig.append(float(np.hypot(np.std(pu), np.std(pv)) / math.sqrt(pu.size)))
    return uv, sig


def _sides(cents: np.ndarray, cfg: PairConfig) -> tuple[np.ndarray | None, str]:
    """Which LED each one-LED sample shows, from its centroid ((K, 2) px): 0 / 1, or -1 for a
    centroid between the two clusters. None when the samples do not form two compact,
    clearly separated clusters (then the count word alone must decide)."""
    if len(cents) < 4:
        return None, f"{len(cents)} one-LED samples"
    d = cents - np.median(cents, axis=0)
    _, _, vt = np.linalg.svd(d, full_matrices=False)
    x = d @ vt[0]
    lo, hi = float(x.min()), float(x.max())
    for _ in range(30):  # 1-D two-medians along the principal axis
        mid = 0.5 * (lo + hi)
        a, b = x[x <= mid], x[x > mid]
        if a.size == 0 or b.size == 0:
            return None, "one cluster"
        nlo, nhi = float(np.median(a)), float(np.median(b))
        if (nlo, nhi) == (lo, hi):
            break
        lo, hi = nlo, nhi
    mid = 0.5 * (lo + hi)
    side = (x > mid).astype(np.int8)
    spreads = [_spread(cents[side == k, 0], cents[side == k, 1]) for k in (0, 1)]
    ca = np.median(cents[side == 0], axis=0)
    cb = np.median(cents[side == 1], axis=0)
    gap = float(np.hypot(*(ca - cb)))
    need = max(cfg.min_gap_px, cfg.gap_spreads * max(spreads))
    if max(spreads) > cfg.max_centroid_spread_px or gap < need:
        return None, f"one-LED centroids {gap:.2f} px apart, spread {max(spreads):.2f} px: sides unclear"
    side[np.abs(x - mid) < 0.25 * (hi - lo)] = -1  # between the clusters: which LED is unknown
    return side, ""


def decode_pair(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, u: float, v: float, book: CodeBook,
    noise_sigma: float, config: PairConfig | None = None,
) -> PairResult:
    """Decode the blob at pixel (``u``, ``v``) of the sample ``stack`` ((N, H, W) float,
    ``valid`` (N,) delivered samples, ``positions`` (N,) fold position 0..L-1 of each
    sample) as two LEDs (see the module docstring). ``noise_sigma``: per-pixel noise of
    a frame difference (DN), as :func:`fgloc.camera.led_detection.detect_led` reports it."""
    cfg = config or PairConfig()
    r = cfg.radius_px
    window = background_free_aperture(stack, valid, u, v, r, noise_sigma, fraction=cfg.aperture_fraction)
    if window is None:
        return _refuse("too close to the image border")
    big, flux, noise, pad, (ox, oy) = window
    f = flux[valid]
    c0, c1, c2 = _three_levels(f)
    step = 0.5 * (c2 - c0)
    if step < cfg.min_snr * noise:
        return _refuse(f"one-LED step {step:.0f} < {cfg.min_snr} x {noise:.1f}")
    if abs(c0) > cfg.max_off_level * step + 4.0 * noise:
        return _refuse(f"never dark (off level {c0:.0f} of step {step:.0f})")
    skew = abs(c1 - 0.5 * (c0 + c2)) / step
    if skew > cfg.max_level_skew:
        return _refuse(f"levels not 0, 1, 2 LEDs (one-LED level off the midpoint by {skew:.2f} step)")
    above = int(np.count_nonzero(valid & (flux > c2 + cfg.level_band * step)))
    if above > 1:
        return _refuse(f"{above} samples brighter than two LEDs")
    length = book.length
    counted = count_and_singles(big, flux, valid, positions, (c0, c1, c2), step, cfg, length, pad, r, "both-off")
    if isinstance(counted, str):
        return _refuse(counted)
    count, cword, dark, singles, cents = counted
    side, why_sides = _sides(np.array(cents, float), cfg)
    bits, _, _ = _rotation_table(length, book.words)
    if side is not None:  # each LED's own word, from the samples that show it alone
        words = []
        for k in (0, 1):
            b = np.full(flux.size, -1, np.int8)
            b[count == 0] = 0
            b[count == 2] = 1
            b[singles[side == k]] = 1
            b[singles[side == 1 - k]] = 0
            wk, why = _fold(b, positions, length)
            if wk is None:
                return _refuse(f"LED {k}: {why}")
            hit = book.identify(int("".join(str(int(x)) for x in wk), 2))
            if hit is None:
                return _refuse(f"LED {k}: word is no rotation of a book code")
            words.append(hit)
        if words[0][0] == words[1][0]:
            return _refuse("both LEDs show one word")
        rows = [words[k][0] * length + words[k][1] for k in (0, 1)]
        only = [singles[side == k] for k in (0, 1)]
        ids = (words[0][0], words[1][0])
        rule = "sides"
    else:  # sides unclear: the count word alone, unique against the whole book with margin
        hit2, why = unique_pair(book, cword, cfg.margin)
        if hit2 is None:
            return _refuse(f"{why_sides}; {why}")
        rows = [hit2.a * length + hit2.ra, hit2.b * length + hit2.rb]
        wa, wb = bits[rows[0]][positions], bits[rows[1]][positions]
        only = [np.flatnonzero((count == 1) & (wa == 1) & (wb == 0)),
                np.flatnonzero((count == 1) & (wa == 0) & (wb == 1))]
        ids = (hit2.a, hit2.b)
        rule = "counts"
    wa, wb = bits[rows[0]][positions], bits[rows[1]][positions]
    both = (count == 2) & (wa == 1) & (wb == 1)
    excl = (int(only[0].size), int(only[1].size))
    if min(excl) < cfg.min_exclusive:
        return _refuse(f"exclusive samples {excl[0]} / {excl[1]}: fewer than {cfg.min_exclusive}", excl)
    found = exclusive_centroids(big, dark, only, pad, r, cfg.max_centroid_spread_px)
    if isinstance(found, str):
        return _refuse(found, excl)
    uv, sig = found
    edge = max(max(abs(x - pad), abs(y - pad)) for x, y in uv)
    if edge > r - cfg.edge_px:  # an LED at the aperture's edge is cut off there: its centroid is biased
        return _refuse(f"an LED {edge:.1f} px from the aperture centre, within {cfg.edge_px:g} px of its edge", excl)
    if both.any():
        cb = _centroid(big[both].mean(axis=0) - dark, pad, pad, r)
        mid = (0.5 * (uv[0][0] + uv[1][0]), 0.5 * (uv[0][1] + uv[1][1]))
        off_mid = math.inf if cb is None else math.hypot(cb[0] - mid[0], cb[1] - mid[1])
        if off_mid > cfg.max_both_px:
            return _refuse(f"both-on centroid {off_mid:.2f} px from the pair's midpoint: not two LEDs", excl)
    return PairResult(ids, ((uv[0][0] + ox, uv[0][1] + oy), (uv[1][0] + ox, uv[1][1] + oy)),
                      (sig[0], sig[1]), excl, rule=rule)
