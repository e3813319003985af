"""Crowds in the blink Monte Carlo: pairs, groups of three and known-partner decodes (a helper module).

Placement of crowded pairs, and the per-view statistics and printed summary of pair
decodes (:mod:`fgloc.camera.blink_pairs`), group decodes (:mod:`fgloc.camera.blink_groups`)
and known-partner decodes (:mod:`fgloc.camera.blink_partner`) for
``scripts/blink_montecarlo.py --pairs|--groups [--partner]``. Pixels are view pixels (u
right, v down); angle errors are pan x cos tilt and tilt, rad in the sums, deg printed. A
reading is right when its index is the mote's and its centroid is within 2 px of the
mote's true pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_decoder import DecodedReading, ViewDecode
from fgloc.camera.blink_partner import PartnerConfig, decode_partner_view

SEP_BINS = (0.0, 1.0, 2.0, 3.0, 4.0)  #: pair separation bins (px) of the resolved-share table
THIRD_BINS = (4.0, 6.0, 8.0, 12.0, math.inf)  #: bins (px) of the nearest third mote to either LED of a pair


def pair_pixels(rng: np.random.Generator, others: np.ndarray, n: int, width: int, height: int) -> np.ndarray:
    """(2n, 2) pixels of ``n`` crowded pairs (rows 2k, 2k + 1): separation ``4 sqrt(U)`` px in a
    random direction; no mote placed before within 4 px of either (exactly two: the field
    plan's criterion)."""
    placed = np.asarray(others, float)
    out: list[np.ndarray] = []
    while len(out) < n:
        c = np.array([rng.uniform(20, width - 20), rng.uniform(20, height - 20)])
        a = rng.uniform(0, math.pi)
        d = 4.0 * math.sqrt(rng.uniform()) * np.array([math.cos(a), math.sin(a)])
        pair = np.array([c - 0.5 * d, c + 0.5 * d])
        if len(placed) and min(np.min(np.hypot(*(placed - p).T)) for p in pair) < 4.0:
            continue
        out.append(pair)
        placed = np.vstack([placed, pair])
    return np.vstack(out)


def pair_stats(readings: tuple, ids: np.ndarray, uv: np.ndarray, n_single: int, found: set,
               isolated: np.ndarray, pans: np.ndarray, tilts: np.ndarray) -> dict[str, float]:
    """Pair decodes of one view: resolved pairs (per separation bin), by which rule, and the
    pixel and angle errors of their readings; pixel errors of isolated single readings."""
    got = {r.index: r for r in readings}
    st: dict[str, float] = {"pair_n": 0, "pair_resolved": 0, "pair_sq_u": 0.0, "pair_sq_v": 0.0,
                            "pair_n_px": 0, "pair_sq_x": 0.0, "pair_sq_y": 0.0, "single_sq_u": 0.0,
                            "single_sq_v": 0.0, "single_n_px": 0, "pair_one": 0}
    for b in range(len(SEP_BINS) - 1):
        st[f"pair_n_b{b}"] = st[f"pair_res_b{b}"] = 0
    for b in range(len(THIRD_BINS) - 1):
        st[f"pair_n_t{b}"] = st[f"pair_res_t{b}"] = 0
    for k in range(n_single, len(ids), 2):
        sep = float(np.hypot(*(uv[k] - uv[k + 1])))
        b = min(int(np.searchsorted(SEP_BINS, sep, side="right")) - 1, len(SEP_BINS) - 2)
        rest = np.delete(uv, [k, k + 1], axis=0)
        third = min(float(np.min(np.hypot(*(rest - uv[m]).T))) for m in (k, k + 1)) if len(rest) else math.inf
        t = min(int(np.searchsorted(THIRD_BINS, third, side="right")) - 1, len(THIRD_BINS) - 2)
        st["pair_n"] += 1
        st[f"pair_n_b{b}"] += 1
        st[f"pair_n_t{t}"] += 1
        ok = [int(ids[m]) in found and got[int(ids[m])].partner is not None for m in (k, k + 1)]
        st["pair_one"] += sum(ok) == 1
        if all(ok):
            st["pair_resolved"] += 1
            st[f"pair_res_b{b}"] += 1
            st[f"pair_res_t{t}"] += 1
            for m in (k, k + 1):
                _add_errors(st, "pair", got[int(ids[m])], uv[m], pans[m], tilts[m])
    for k in range(n_single):
        r = got.get(int(ids[k]))
        if isolated[k] and r is not None and int(ids[k]) in found:
            st["single_sq_u"] += (r.u - uv[k][0]) ** 2
            st["single_sq_v"] += (r.v - uv[k][1]) ** 2
            st["single_n_px"] += 1
    return st


def print_pairs(tot: dict[str, float], p: str) -> None:
    """Print the pair rows of the summed statistics ``tot`` (keys of :func:`pair_stats`, prefix ``p``)."""
    n, res = tot[p + "pair_n"], tot[p + "pair_resolved"]
    npx, nsx = max(tot[p + "pair_n_px"], 1), max(tot[p + "single_n_px"], 1)
    print(f"  pair decodes {n:.0f}: resolved {res:.0f} ({res / max(n, 1):.2%}),"
          f" one of two read {tot[p + 'pair_one']:.0f}")
    print("  resolved by separation: " + by_bins(tot, p, SEP_BINS, "pair_res_b", "pair_n_b"))
    print("  resolved by nearest third mote: " + by_bins(tot, p, THIRD_BINS, "pair_res_t", "pair_n_t"))
    print(f"  centroid error RMS, u / v (px): pair LEDs {math.sqrt(tot[p + 'pair_sq_u'] / npx):.3f} / "
          f"{math.sqrt(tot[p + 'pair_sq_v'] / npx):.3f} ({npx:.0f}); isolated single LEDs "
          f"{math.sqrt(tot[p + 'single_sq_u'] / nsx):.3f} / {math.sqrt(tot[p + 'single_sq_v'] / nsx):.3f} ({nsx:.0f})")
    print(f"  pair angle error RMS, pan (x cos tilt) / tilt: {math.degrees(math.sqrt(tot[p + 'pair_sq_x'] / npx)):.5f}"
          f" / {math.degrees(math.sqrt(tot[p + 'pair_sq_y'] / npx)):.5f} deg")


def by_bins(tot: dict[str, float], p: str, bins: Sequence[float], resolved: str, count: str) -> str:
    """``"A-B px R% of N, ..."``: per bin of ``bins`` (px), the share of the summed ``tot`` keys
    ``p + count + bin`` that ``p + resolved + bin`` resolved."""
    return ", ".join(f"{bins[b]:.0f}-{bins[b + 1]:.0f} px {tot[f'{p}{resolved}{b}'] / max(tot[f'{p}{count}{b}'], 1):.1%}"
                     f" of {tot[f'{p}{count}{b}']:.0f}" for b in range(len(bins) - 1))


FOURTH_BINS = THIRD_BINS  #: bins (px) of the nearest fourth mote to any LED of a group


def group_stats(readings: tuple, ids: np.ndarray, uv: np.ndarray, g0: int, found: set,
                pans: np.ndarray, tilts: np.ndarray) -> dict[str, float]:
    """Group decodes of one view (rows ``g0``.. in threes): resolved groups (all three read
    within 2 px as a group), by the nearest fourth mote, partial groups, and the pixel and
    angle errors of their readings."""
    got = {r.index: r for r in readings}
    st: dict[str, float] = {"grp_n": 0, "grp_resolved": 0, "grp_partial": 0, "grp_sq_u": 0.0, "grp_sq_v": 0.0,
                            "grp_n_px": 0, "grp_sq_x": 0.0, "grp_sq_y": 0.0}
    for b in range(len(FOURTH_BINS) - 1):
        st[f"grp_n_t{b}"] = st[f"grp_res_t{b}"] = 0
    for k in range(g0, len(ids), 3):
        mem = [k, k + 1, k + 2]
        rest = np.delete(uv, mem, axis=0)
        fourth = min(float(np.min(np.hypot(*(rest - uv[m]).T))) for m in mem) if len(rest) else math.inf
        t = min(int(np.searchsorted(FOURTH_BINS, fourth, side="right")) - 1, len(FOURTH_BINS) - 2)
        st["grp_n"] += 1
        st[f"grp_n_t{t}"] += 1
        ok = [int(ids[m]) in found and bool(got[int(ids[m])].group) for m in mem]
        st["grp_partial"] += 0 < sum(int(int(ids[m]) in found) for m in mem) < 3
        if all(ok):
            st["grp_resolved"] += 1
            st[f"grp_res_t{t}"] += 1
            for m in mem:
                _add_errors(st, "grp", got[int(ids[m])], uv[m], pans[m], tilts[m])
    return st


def print_groups(tot: dict[str, float], p: str) -> None:
    """Print the group rows of the summed statistics ``tot`` (keys of :func:`group_stats`, prefix ``p``)."""
    n, res = tot[p + "grp_n"], tot[p + "grp_resolved"]
    npx = max(tot[p + "grp_n_px"], 1)
    print(f"  group decodes {n:.0f}: resolved {res:.0f} ({res / max(n, 1):.2%}),"
          f" partly read (1 or 2 of 3) {tot[p + 'grp_partial']:.0f}")
    print("  resolved by nearest fourth mote: " + by_bins(tot, p, FOURTH_BINS, "grp_res_t", "grp_n_t"))
    print(f"  centroid error RMS, u / v (px): group LEDs {math.sqrt(tot[p + 'grp_sq_u'] / npx):.3f} / "
          f"{math.sqrt(tot[p + 'grp_sq_v'] / npx):.3f} ({npx:.0f}); angle error RMS, pan (x cos tilt) / tilt: "
          f"{math.degrees(math.sqrt(tot[p + 'grp_sq_x'] / npx)):.5f} / {math.degrees(math.sqrt(tot[p + 'grp_sq_y'] / npx)):.5f} deg")


PARTNER_MARGINS = (3, 2)  #: margins (count errors) of the known-partner decodes measured side by side


def partner_stats(rng: np.random.Generator, frames: list[tuple[float, np.ndarray]], period: float, book: CodeBook,
                  plain: ViewDecode, readings: tuple, ids: np.ndarray, uv: np.ndarray, first: int,
                  size: int) -> dict[str, float]:
    """Known-partner decodes of one view: for each crowded group (rows ``first``.. in
    ``size``s), ``size - 1`` random members are known (book index, true pixel + 0.1 px sd:
    a round reading) and the last is decoded from the blob the plain decoder refused
    nearest the first known pixel (within 4 px), once per margin of PARTNER_MARGINS (keys
    ``ptn{margin}_*``). Resolved: the right index within 2 px; mislabelled: any other
    label. Also, per group, the same decode with the first known member replaced by a mote
    of the view outside the group (a wrong "known" partner): any label counts as
    ``wrong_labelled``. By the nearest other mote (THIRD_BINS) and among the groups the
    blind pair (group) decoder left unresolved (``cond_*``)."""
    st: dict[str, float] = {}
    for m in PARTNER_MARGINS:
        for k in ("n", "ok", "mislabelled", "noblob", "wrong_n", "wrong_labelled", "cond_n", "cond_ok"):
            st[f"ptn{m}_{k}"] = 0
        for b in range(len(THIRD_BINS) - 1):
            st[f"ptn{m}_n_t{b}"] = st[f"ptn{m}_ok_t{b}"] = st[f"ptn{m}_cn_t{b}"] = st[f"ptn{m}_cok_t{b}"] = 0
    blobs = np.array([(b.u, b.v) for b in plain.refused]).reshape(-1, 2)
    found = {r.index: r for r in readings}
    for g in range(first, len(ids) - size + 1, size):
        members = list(range(g, g + size))
        order = [int(x) for x in rng.permutation(members)]
        last, known = order[-1], order[:-1]
        rest = np.delete(uv, members, axis=0)
        third = min(float(np.min(np.hypot(*(rest - uv[m]).T))) for m in members) if len(rest) else math.inf
        t = min(int(np.searchsorted(THIRD_BINS, third, side="right")) - 1, len(THIRD_BINS) - 2)
        unresolved = not all(int(ids[m]) in found and math.dist((found[int(ids[m])].u, found[int(ids[m])].v), uv[m])
                             <= 2.0 for m in members)
        d = np.hypot(*(blobs - uv[known[0]]).T) if len(blobs) else np.zeros(0)
        kn = [(int(ids[m]), (float(uv[m][0] + 0.1 * rng.standard_normal()),
                             float(uv[m][1] + 0.1 * rng.standard_normal()))) for m in known]
        outside = [int(i) for i in ids if int(i) not in {int(ids[m]) for m in members}]
        wrong = [(int(rng.choice(outside)), kn[0][1])] + kn[1:]
        for mg in PARTNER_MARGINS:
            p = f"ptn{mg}_"
            st[p + "n"] += 1
            st[f"{p}n_t{t}"] += 1
            st[p + "cond_n"] += unresolved
            st[f"{p}cn_t{t}"] += unresolved
            if not d.size or d.min() > 4.0:
                st[p + "noblob"] += 1
                continue
            bu, bv = (float(x) for x in blobs[int(np.argmin(d))])
            cfg = PartnerConfig(margin=mg)
            res = decode_partner_view(frames, period, book, bu, bv, kn, cfg)
            if res.ok and res.uv is not None:
                if res.index == int(ids[last]) and math.dist(res.uv, uv[last]) <= 2.0:
                    st[p + "ok"] += 1
                    st[f"{p}ok_t{t}"] += 1
                    st[p + "cond_ok"] += unresolved
                    st[f"{p}cok_t{t}"] += unresolved
                else:
                    st[p + "mislabelled"] += 1
            st[p + "wrong_n"] += 1
            st[p + "wrong_labelled"] += decode_partner_view(frames, period, book, bu, bv, wrong, cfg).ok
    return st


def print_partner(tot: dict[str, float]) -> None:
    """Print the known-partner rows of the summed statistics ``tot`` (keys of :func:`partner_stats`)."""
    for mg in PARTNER_MARGINS:
        p = f"ptn{mg}_"
        n = tot[p + "n"]
        print(f"  known-partner decodes, margin {mg}: {n:.0f}: resolved {tot[p + 'ok']:.0f} "
              f"({tot[p + 'ok'] / max(n, 1):.2%}), mislabelled {tot[p + 'mislabelled']:.0f}, no refused blob at the "
              f"known pixel {tot[p + 'noblob']:.0f}; wrong known partner labelled {tot[p + 'wrong_labelled']:.0f} of "
              f"{tot[p + 'wrong_n']:.0f}")
        print("    resolved by nearest other mote: " + by_bins(tot, p, THIRD_BINS, "ok_t", "n_t"))
        print(f"    among those the blind decoder left unresolved: {tot[p + 'cond_ok']:.0f} of {tot[p + 'cond_n']:.0f} "
              f"({tot[p + 'cond_ok'] / max(tot[p + 'cond_n'], 1):.2%}); by nearest other mote: " + by_bins(tot, p, THIRD_BINS, "cok_t", "cn_t"))


def _add_errors(st: dict, prefix: str, r: DecodedReading, uv: tuple[float, float], pan: float, tilt: float) -> None:
    """Accumulate one reading's squared centroid (px) and angle (rad; pan x cos tilt, tilt) errors."""
    st[f"{prefix}_sq_u"] += (r.u - uv[0]) ** 2
    st[f"{prefix}_sq_v"] += (r.v - uv[1]) ** 2
    st[f"{prefix}_n_px"] += 1
    st[f"{prefix}_sq_x"] += (math.remainder(r.pan - pan, 2 * math.pi) * math.cos(tilt)) ** 2
    st[f"{prefix}_sq_y"] += (r.tilt - tilt) ** 2
