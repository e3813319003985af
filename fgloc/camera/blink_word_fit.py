"""Second look at one LED the level decoder refused: fit every code word's light curve.

The level decoder (:func:`fgloc.camera.blink_decoder.read_blob`) reads a sample as a bit
only when its flux lies within ``level_band`` of the blob's off or on level, and it asks
the off level to be the background's. Two kinds of real, isolated motes fail it:

* **A bit edge inside the exposure.** The camera integrates ``[t, t + exposure]``; a mote
  whose bit clock puts an edge inside that window shows, at every transition, a level
  between off and on, and at the same positions in every period (mote and camera clocks
  agree to ~50 ppm). With a 2 ms exposure and 59.94 Hz fields that is 12 % of the motes.
* **A textured background.** The aperture's background is the median of a surrounding
  annulus; where the texture under the LED differs from it, the off level is offset by
  a few DN per pixel, and a weak LED is taken for a light that never goes dark.

This module fits, for every word ``w`` of the book at every rotation ``r``, the light
curve of an exposure that may straddle one bit edge::

    flux_i = off + a * w[(i + r) mod L] + c * w[(i + r + 1) mod L],   a, c >= 0

(``c / (a + c)`` is the share of the exposure after the edge; ``off`` absorbs a
background offset) by linear least squares over the delivered samples, and accepts the
best word only when all of these hold; otherwise the blob stays refused:

1. every bit position has a delivered sample, and the amplitude ``a + c`` is at least
   ``min_snr`` flux sigmas;
2. every sample lies within ``max_residual`` x amplitude of the fitted curve (a flipped
   bit, a glint crossing or a second LED leaves a sample about half an amplitude or more
   off; a flickering lamp fits no word);
3. the best fit of every *other* word leaves a residual sum of squares at least
   ``min_margin`` noise variances larger (unconstrained fits of the rivals: a rival can
   only look closer than it is, never farther);
4. with an edge inside the exposure (``a, c > 0``), the same holds for every **pair of
   different words** whose count word is within ``pair_distance`` counts of the fit's
   (``w[p + r] + w[p + r + 1]`` per bit position ``p``), fitted as two LEDs,
   ``off + a' * w_i + c' * w_j``. Near ``c = a`` the edge model is itself a blend of two
   copies of one word, and two equally bright motes in one blob whose words add up to
   those copies fit it just as well: in a 100-word book 17 % of (word, rotation)s have such
   a pair. (Measured: a 1000-mote survey read two motes 0.8 px apart as a third mote's
   word this way; the pair decoder, :mod:`fgloc.camera.blink_pairs`, reads them.)

Rotations of one word are the same mote (the book is rotation-free), so rule 3 compares
words, not rotations. Nothing is corrected: the word is read only when the light curve
names one word by a wide margin. Synchronized books are not second-looked (their
alignment is known; see :mod:`fgloc.camera.blink_decoder`).

Fluxes in DN (aperture sums); pixels OpenCV convention.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_pairs import explain_counts


@dataclass(frozen=True)
class WordFitConfig:
    """Acceptance rules of the light-curve fit (fractions of the fitted amplitude; noise variances)."""

    max_residual: float = 0.2  #: every sample within this x amplitude of the fitted curve
    min_margin: float = 100.0  #: rival words' residual sum of squares exceeds the best's by this many noise variances
    on_share: float = 0.75  #: samples fitted at least this x amplitude above off give the centroid
    #: rule 4: pairs of words whose count word is within this many counts of the fit's are rivals
    pair_distance: int = 1


@dataclass(frozen=True)
class WordFit:
    """The accepted word of one blob: book ``index``, rotation, fitted levels and which samples were lit."""

    index: int
    rotation: int
    off: float
    amplitude: float
    edge_share: float  #: c / (a + c): share of the exposure after a bit edge (0: no edge inside)
    margin: float  #: rival words' extra residual sum of squares, in noise variances
    lit: np.ndarray  #: (N,) bool: delivered samples fitted at least ``on_share`` x amplitude above off


@functools.lru_cache(maxsize=8)
def _rotation_table(book: CodeBook) -> tuple[np.ndarray, np.ndarray]:
    """(bits (H, L) float with row ``j * L + r`` = word ``j`` rotated so that column ``p`` is
    bit ``(p + r) mod L``, word index (H,))."""
    length = book.length
    rows = [np.roll(book.bits(j), -r) for j in range(len(book)) for r in range(length)]
    return np.array(rows, dtype=np.float64), np.repeat(np.arange(len(book)), length)


def fit_word(flux: np.ndarray, valid: np.ndarray, book: CodeBook, noise: float,
             min_snr: float, config: WordFitConfig | None = None,
             elsewhere: Callable[[int], bool] | None = None) -> WordFit | str:
    """Fit every rotation of every word of the rotation-free ``book`` to a blob's per-sample
    ``flux`` (``valid``: delivered samples; sample ``i`` sits at bit position ``i mod L``)
    and return the accepted :class:`WordFit`, or the reason (one line) none is accepted.
    ``noise``: the flux sigma of one sample from pixel noise (DN); the residual scatter of
    the best fit is used instead where larger. ``elsewhere(j)``: word ``j``'s mote is known
    to be elsewhere (read away from this blob), so no rival pair of rule 4 holds it."""
    cfg = config or WordFitConfig()
    if book.synchronized:
        raise ValueError("the light-curve fit reads rotation-free books only")
    length = book.length
    idx = np.flatnonzero(valid)
    if len(np.unique(idx % length)) < length:
        return "a bit position has no delivered sample"
    y = np.asarray(flux, dtype=np.float64)[idx]
    table, word = _rotation_table(book)
    cur = table[:, idx % length]  # (H, N)
    nxt = table[:, (idx + 1) % length]
    n = float(idx.size)
    # normal equations of [1, cur, nxt] per hypothesis (cur, nxt are 0/1: cur.cur = sum cur)
    s_c, s_n, s_cn = cur.sum(1), nxt.sum(1), (cur * nxt).sum(1)
    gram = np.empty((table.shape[0], 3, 3))
    gram[:, 0, 0] = n
    gram[:, 0, 1] = gram[:, 1, 0] = gram[:, 1, 1] = s_c
    gram[:, 0, 2] = gram[:, 2, 0] = gram[:, 2, 2] = s_n
    gram[:, 1, 2] = gram[:, 2, 1] = s_cn
    rhs = np.stack([np.full(table.shape[0], y.sum()), cur @ y, nxt @ y], axis=1)
    gram += 1e-9 * np.eye(3)
    beta = np.linalg.solve(gram, rhs[..., None])[..., 0]  # (H, 3): off, a, c
    yy = float(y @ y)
    rss = np.maximum(yy - (beta * rhs).sum(1), 0.0)
    # an edge at the exposure's border: the constrained optimum has c = 0 ([1, cur]; a = 0 is
    # the next rotation's c = 0), so those fits are candidates too
    det2 = n * s_c - s_c**2
    ok2 = det2 > 1e-9
    a2 = np.where(ok2, (n * rhs[:, 1] - s_c * rhs[:, 0]) / np.where(ok2, det2, 1.0), -1.0)
    off2 = (rhs[:, 0] - a2 * s_c) / n
    rss2 = np.where(ok2 & (a2 >= 0.0), np.maximum(yy - off2 * rhs[:, 0] - a2 * rhs[:, 1], 0.0), np.inf)
    cand = np.where((beta[:, 1] >= 0.0) & (beta[:, 2] >= 0.0), rss, np.inf)
    two = rss2 < cand
    cand = np.minimum(cand, rss2)
    if not np.isfinite(cand).any():
        return "no word fits with a positive amplitude"
    best = int(np.argmin(cand))
    off, a, c = (float(off2[best]), float(a2[best]), 0.0) if two[best] else (float(v) for v in beta[best])
    amp = a + c
    fitted = off + a * cur[best] + c * nxt[best]
    resid = y - fitted
    sigma = max(noise, float(np.sqrt(cand[best] / max(n - 3.0, 1.0))))
    if amp < min_snr * noise:
        return f"fitted amplitude {amp:.0f} < {min_snr} x {noise:.1f}"
    worst = float(np.max(np.abs(resid))) / amp
    if worst > cfg.max_residual:
        return f"a sample {worst:.2f} of the amplitude off the best word's light curve"
    rivals = word != word[best]
    # rivals unconstrained: a rival can only look closer than it is, never farther
    margin = float(np.min(rss[rivals]) - cand[best]) / sigma**2 if rivals.any() else math.inf
    if margin < cfg.min_margin:
        return f"another word fits nearly as well (margin {margin:.0f} < {cfg.min_margin:.0f} noise variances)"
    if a > 0.0 and c > 0.0:
        pair = _pair_rival(y, idx, table[best], book, cfg.pair_distance, elsewhere)
        if pair is not None and (pair[0] - cand[best]) / sigma**2 < cfg.min_margin:
            return (f"two LEDs, words {pair[1]} and {pair[2]}, fit nearly as well (margin"
                    f" {(pair[0] - cand[best]) / sigma**2:.0f} < {cfg.min_margin:.0f} noise variances)")
    lit = np.zeros(valid.size, dtype=bool)
    lit[idx] = (fitted - off) >= cfg.on_share * amp
    return WordFit(int(word[best]), best % length, off, amp, c / amp if amp > 0 else 0.0, margin, lit)


def _pair_rival(y: np.ndarray, idx: np.ndarray, bits: np.ndarray, book: CodeBook, distance: int,
                elsewhere: Callable[[int], bool] | None = None) -> tuple[float, int, int] | None:
    """Rule 4's best rival: (residual sum of squares, word i, word j) of the best unconstrained
    two-LED fit ``off + a' * w_i + c' * w_j`` (i != j, neither ``elsewhere``) over the pairs whose
    count word lies within ``distance`` counts of ``bits + bits`` shifted by one position
    (``bits``: the accepted word at its rotation, per bit position); None without such a pair."""
    counts = bits + np.roll(bits, -1)
    best: tuple[float, int, int] | None = None
    for e in explain_counts(book, counts.astype(np.int8), distance):
        if e.b < 0 or e.a == e.b or (elsewhere is not None and (elsewhere(e.a) or elsewhere(e.b))):
            continue
        wa = np.roll(book.bits(e.a), -e.ra).astype(np.float64)[idx % book.length]
        wb = np.roll(book.bits(e.b), -e.rb).astype(np.float64)[idx % book.length]
        x = np.stack([np.ones_like(wa), wa, wb], axis=1)
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        rss = float(np.sum((y - x @ coef) ** 2))
        if best is None or rss < best[0]:
            best = (rss, e.a, e.b)
    return best
