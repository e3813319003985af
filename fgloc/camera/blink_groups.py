"""Group decoding: one blob made of three blinking LEDs, labelled by their three code words.

The generalization of :mod:`fgloc.camera.blink_pairs` to a crowded group of ``k = 3``
motes (``PairConfig(max_group=3)``; off by default). The blob blinks the **sum** of the
three code words: per sample 0..3 LEDs are lit. :func:`decode_group` labels it with the
pair decoder's discipline, never by guessing:

1. **Levels.** Flux per sample in the blob's footprint within a ``2 group_radius_px + 1``
   square, footprint and static background as for pairs, must show four equally spaced levels (off, one, two,
   three LEDs; each within ``max_level_skew`` of the step), or three when no sample has
   all three lit. More than one sample above the three-LED level (a fourth LED) refuses.
2. **Which LED.** The centroids of the one-LED samples must form three compact, clearly
   separated clusters (:func:`_three_sides`); a sample between clusters is an erasure.
   There is no count-word-alone rule for groups: each LED is identified by position.
3. **Two-LED samples.** The LED that is off is the one whose template (mean one-LED image
   of its cluster) leaves the other two's sum closest to the sample, by a margin of half
   the squared template difference, with the templates at least ``min_template_sigmas``
   noise sigmas apart (:func:`_off_led`); anything else is an erasure.
4. **Each LED's word.** Count 0 -> 0, count 3 -> 1, one- and two-LED samples by step 2/3,
   folded modulo L (complete, no conflicts). Each word must **exactly** equal a rotation
   of a book word; the three words must be distinct; and their sum must explain the
   count of every sample read (the whole group's per-sample lit count).
5. **Centroids.** Each LED needs ``min_exclusive`` exclusive samples (and as many all-off
   samples); centroids and the one-LED spread check as for pairs. The mean image of each
   set of two or three LEDs lit together must be centred within ``max_both_px`` of their
   mean position (these LEDs, not a fourth).

Rotation-free books only. Pixels: OpenCV convention; fluxes DN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_pairs import (
    PairConfig,
    _centroid,
    _fold,
    _rotation_table,
    _spread,
    background_free_aperture,
    count_and_singles,
    exclusive_centroids,
)


@dataclass(frozen=True)
class GroupResult:
    """A decoded group (``uv[k]`` the centroid of book word ``index[k]``) or a refusal ``reason``."""

    index: tuple[int, ...] | None
    uv: tuple[tuple[float, float], ...] | None
    sigma_px: tuple[float, ...]
    exclusive: tuple[int, ...]
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.index is not None


def _refuse(why: str, exclusive: tuple[int, ...] = (0, 0, 0)) -> GroupResult:
    return GroupResult(None, None, (math.nan,) * 3, exclusive, why)


def led_levels(flux: np.ndarray, valid: np.ndarray, n: int, cfg: PairConfig, noise: float, min_snr: float,
               ideal: bool = False) -> tuple[np.ndarray, float] | str:
    """The flux levels of a blob of ``n`` LEDs (``n + 1`` levels: off, one, ..., all lit) and its
    one-LED step (DN), or why the blob is no ``n`` equally bright LEDs.

    The levels of the ``valid`` samples' fluxes must be equally spaced within
    ``cfg.max_level_skew`` of the step; for three LEDs, all lit together may never occur (then
    four levels are fitted as three and the top one extrapolated). The step must be
    ``min_snr`` noise sigmas (``noise``: the aperture's flux noise), the off level dark, and at
    most one sample above the top level. ``ideal``: the levels returned are the equally
    spaced ones from the off level, not the fitted ones."""
    skew = math.inf
    for top in ((3, 2) if n == 3 else (n,)):
        c = _levels(flux[valid], top + 1)
        step = (c[top] - c[0]) / top
        skew = max(abs(c[k] - (c[0] + k * step)) / step for k in range(1, top)) if step > 0 else math.inf
        if skew <= cfg.max_level_skew:
            break
    else:
        return f"levels not 0..{n} LEDs (off the equal spacing by {skew:.2f} step)"
    if ideal or top < n:
        c = c[0] + step * np.arange(n + 1.0)
    if step < min_snr * noise:
        return f"one-LED step {step:.0f} < {min_snr} x {noise:.1f}"
    if abs(c[0]) > cfg.max_off_level * step + 4.0 * noise:
        return f"never dark (off level {c[0]:.0f} of step {step:.0f})"
    above = int(np.count_nonzero(valid & (flux > c[n] + cfg.level_band * step)))
    if above > 1:
        return f"{above} samples brighter than {n} LEDs"
    return c, float(step)


def _levels(f: np.ndarray, n: int) -> np.ndarray:
    """``n`` levels of fluxes ``f`` (1-D n-medians started equally spaced between the extremes)."""
    lo, hi = float(np.min(f)), float(np.max(f))
    c = lo + (hi - lo) * np.arange(n) / (n - 1)
    for _ in range(40):
        lab = np.argmin(np.abs(f[:, None] - c[None, :]), axis=1)
        new = np.array([float(np.median(f[lab == k])) if (lab == k).any() else c[k] for k in range(n)])
        if np.allclose(new, c):
            break
        c = new
    return c


def _off_and_one(f: np.ndarray) -> tuple[float, float]:
    """The off and one-LED levels among four (off, one, two, three LEDs)."""
    c = _levels(f, 4)
    return float(c[0]), float(c[1])


def _three_sides(cents: np.ndarray, cfg: PairConfig) -> tuple[np.ndarray | None, str]:
    """Which of three LEDs each one-LED sample shows, from its centroid ((K, 2) px): 0..2,
    or -1 for a centroid not clearly nearest one cluster (nearest more than a third of the
    second nearest). None when the samples do not form three compact, separated clusters."""
    if len(cents) < 6:
        return None, f"{len(cents)} one-LED samples"
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for start in range(len(cents)):  # three-medians from farthest-point seeds at every start
        seeds = [start]
        for _ in range(2):
            d = np.min([np.hypot(*(cents - cents[s]).T) for s in seeds], axis=0)
            seeds.append(int(np.argmax(d)))
        ctr = cents[seeds].astype(float)
        for _ in range(30):
            dist = np.hypot(cents[:, None, 0] - ctr[None, :, 0], cents[:, None, 1] - ctr[None, :, 1])
            lab = np.argmin(dist, axis=1)
            if any(not (lab == k).any() for k in range(3)):
                break
            new = np.array([np.median(cents[lab == k], axis=0) for k in range(3)])
            if np.allclose(new, ctr):
                break
            ctr = new
        dist = np.hypot(cents[:, None, 0] - ctr[None, :, 0], cents[:, None, 1] - ctr[None, :, 1])
        lab = np.argmin(dist, axis=1)
        cost = float(dist.min(axis=1).sum())
        if all((lab == k).any() for k in range(3)) and (best is None or cost < best[0] - 1e-9):
            best = (cost, ctr, lab)
    if best is None:
        return None, "fewer than three clusters"
    _, ctr, lab = best
    spreads = [_spread(cents[lab == k, 0], cents[lab == k, 1]) for k in range(3)]
    gaps = [float(np.hypot(*(ctr[a] - ctr[b]))) for a, b in ((0, 1), (0, 2), (1, 2))]
    need = max(cfg.min_gap_px, cfg.gap_spreads * max(spreads))
    if max(spreads) > cfg.max_centroid_spread_px or min(gaps) < need:
        return None, (f"one-LED centroids {min(gaps):.2f} px apart, spread {max(spreads):.2f} px:"
                      " three LEDs unclear")
    dist = np.sort(np.hypot(cents[:, None, 0] - ctr[None, :, 0], cents[:, None, 1] - ctr[None, :, 1]), axis=1)
    side = lab.astype(np.int8)
    side[dist[:, 0] > dist[:, 1] / 3.0] = -1
    return side, ""


def _off_led(img: np.ndarray, templates: np.ndarray, sigma: float, cfg: PairConfig) -> int:
    """Which LED is off in a two-LED sample ``img`` (background-free patch), from the three
    one-LED ``templates`` (3, h, w): the hypothesis whose model (sum of the other two)
    fits best, by at least half the squared difference to the runner-up's model, which
    must be ``cfg.min_template_sigmas`` noise sigmas (per pixel ``sigma``) from it; else -1."""
    tot = templates.sum(axis=0)
    r = np.array([float(np.sum((img - (tot - templates[j])) ** 2)) for j in range(3)])
    order = np.argsort(r)
    j, j2 = int(order[0]), int(order[1])
    d2 = float(np.sum((templates[j] - templates[j2]) ** 2))
    if math.sqrt(d2) < cfg.min_template_sigmas * sigma or r[j2] - r[j] < 0.5 * d2:
        return -1
    return j


def decode_group(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, u: float, v: float, book: CodeBook,
    noise_sigma: float, config: PairConfig | None = None,
) -> GroupResult:
    """Decode the blob at pixel (``u``, ``v``) of the sample ``stack`` as three LEDs (see the
    module docstring; arguments as :func:`fgloc.camera.blink_pairs.decode_pair`)."""
    if book.synchronized:
        raise ValueError("group decoding needs a rotation-free book")
    cfg = config or PairConfig()
    r = cfg.group_radius_px
    window = background_free_aperture(stack, valid, u, v, r, noise_sigma, _off_and_one, cfg.aperture_fraction)
    if window is None:
        return _refuse("too close to the image border")
    big, flux, noise, pad, (ox, oy) = window
    fitted = led_levels(flux, valid, 3, cfg, noise, cfg.group_min_snr)
    if isinstance(fitted, str):
        return _refuse(fitted)
    c, step = fitted
    length = book.length
    counted = count_and_singles(big, flux, valid, positions, tuple(float(x) for x in c[:4]), step, cfg, length,
                                pad, r, "all-off")
    if isinstance(counted, str):
        return _refuse(counted)
    count, cword, dark, singles, cents = counted
    side, why = _three_sides(np.array(cents, float), cfg)
    if side is None:
        return _refuse(why)
    if any(int((side == k).sum()) < 2 for k in range(3)):
        return _refuse("an LED with fewer than two one-LED samples")
    templates = np.array([(big[singles[side == k]] - dark).mean(axis=0) for k in range(3)])
    sigma = float(noise_sigma)
    lit = np.full((3, flux.size), -1, np.int8)
    lit[:, count == 0] = 0
    lit[:, count == 3] = 1
    for k in range(3):
        lit[k, singles[side == k]] = 1
        lit[k, singles[side >= 0][side[side >= 0] != k]] = 0
    for i in np.flatnonzero(count == 2).tolist():
        j = _off_led(big[i] - dark, templates, sigma, cfg)
        if j >= 0:
            lit[:, i] = 1
            lit[j, i] = 0
    words: list[tuple[int, int]] = []
    for k in range(3):
        wk, why = _fold(lit[k], positions, length)
        if wk is None:
            return _refuse(f"LED {k}: {why}")
        hit = book.identify(int("".join(str(int(x)) for x in wk), 2))
        if hit is None:
            return _refuse(f"LED {k}: word is no rotation of a book code")
        words.append(hit)
    if len({wd[0] for wd in words}) < 3:
        return _refuse("two LEDs show one word")
    bits, _, _ = _rotation_table(length, book.words)
    wb = np.array([bits[wd[0] * length + wd[1]][positions] for wd in words])  # (3, N)
    read = count >= 0
    if (wb.sum(axis=0)[read] != count[read]).any():
        return _refuse("the three words do not explain the lit count")
    only = [np.flatnonzero((count == 1) & (wb[k] == 1) & (wb.sum(axis=0) == 1)) for k in range(3)]
    excl = tuple(int(o.size) for o in only)
    if min(excl) < cfg.min_exclusive:
        return _refuse(f"exclusive samples {' / '.join(map(str, excl))}: fewer than {cfg.min_exclusive}", excl)
    found = exclusive_centroids(big, dark, only, pad, r, cfg.max_centroid_spread_px)
    if isinstance(found, str):
        return _refuse(found, excl)
    uv, sig = found
    pts = np.array(uv)
    for subset in ((0, 1), (0, 2), (1, 2), (0, 1, 2)):  # LEDs lit together: these, not a fourth
        on = np.ones(flux.size, bool) & read & (count == len(subset))
        for k in range(3):
            on &= wb[k] == (1 if k in subset else 0)
        if not on.any():
            continue
        cb = _centroid(big[on].mean(axis=0) - dark, pad, pad, r)
        mid = pts[list(subset)].mean(axis=0)
        off_mid = math.inf if cb is None else math.hypot(cb[0] - mid[0], cb[1] - mid[1])
        if off_mid > cfg.max_both_px:
            return _refuse(f"LEDs {subset} lit together centred {off_mid:.2f} px from their mean: not these LEDs",
                           excl)
    return GroupResult(tuple(wd[0] for wd in words), tuple((p[0] + ox, p[1] + oy) for p in uv), tuple(sig), excl)
