"""Monte Carlo of the blink decoder: mislabels, misses and angle error on seeded rendered views.

Each trial renders one view (640 x 480, 65 deg HFOV, head at a random tilt) with
``--motes`` motes at random directions inside it, coded from the book for
``--book`` motes, with 5 % dropped frames, 1 % duplicated frames, 50 Hz mains
flicker on static lights (depth 0.5 and 1.0), ``--glints`` daylight false blobs,
ambient gain noise, head jitter, timestamp jitter, and mote clocks offset (random
start) and drifting (50 ppm). A decode is one true mote in the view. A reading is
*mislabelled* when its centroid is not within 2 px of the true pixel of the mote its
code names. Misses and ambiguous reports are counted, never guessed.

``--sync``: the synchronized book (:func:`fgloc.camera.blink_codes.sync_code_book`);
motes start at a broadcast epoch, each off by up to +-2 ms and drifting at 50 ppm
(sd), and the view is recorded a uniform 0..``--resync`` s after the last (re)start.
``--slide N``: the recording goes on for N more code lengths and is decoded in
sliding windows (:func:`fgloc.camera.blink_decoder.decode_windows`, keys ``sl_*``).
``--groups N``: each view also holds N crowded groups of three
(:func:`fgloc.drivers.blink_frames.close_groups`: each LED ``4 sqrt(U)`` px from an earlier
one of its group, no other mote within 4 px of any) and is decoded with group decoding on
(``PairConfig(max_group=3)``, :mod:`fgloc.camera.blink_groups`); a group decode is
resolved when all three motes are read within 2 px (keys ``grp_*``).
``--pairs N``: each view also holds N crowded pairs (two motes closer than 4 px in the
view's pixels, field pixels for ``--fields``: the field plan's criterion; separation
``4 sqrt(U)`` px, as for uniformly scattered motes, in a random direction; no third mote
within 6 px of the pair's centre) and is decoded with pair decoding on
(:mod:`fgloc.camera.blink_pairs`). A *pair decode* is one such pair; it is resolved when
both its motes are read within 2 px; mislabels are counted over all readings as above.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_montecarlo.py --trials 250 [--fields] [--sync] [--slide 1]
        [--pairs 40 [--time-decode]] [--groups 20] [--partner]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_montecarlo.py --candidates 3|book --frames 18 --motes 20 [--fields]

``--partner`` (with ``--pairs`` or ``--groups``): each crowd's last mote is also decoded by
the known-partner decoder (:mod:`fgloc.camera.blink_partner`), the others known
(:func:`_partner_stats`; margins 3 and 2 on the same views).

``--candidates M``: radio-separation round views (:func:`candidate_trial`): ``--motes`` lit
class motes (none within 4 px of another), each decoded by
:func:`fgloc.camera.blink_candidates.decode_candidates` against the class: itself predicted
``--predict-px`` (sd) from its pixel plus 0..M-1 dark class members predicted within its
``--radius`` (1..M candidates in range), and ``--strays`` lit motes that are no candidate
(they missed the pause) near it, which must be refused; ``--candidates book``: the whole
book, no prediction, no strays (the control). Mislabelled as above (a stray labelled as a
candidate is one); missed is the isolated miss rate (every lit mote is isolated).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from fgloc.camera.blink_candidates import Candidate, CandidateRule, decode_candidates
from fgloc.camera.blink_codes import CodeBook, code_book, sync_code_book
from fgloc.camera.blink_decoder import (  # noqa: E402
    DecodedReading,
    SyncTiming,
    ViewDecode,
    decode_view,
    decode_windows,
)
from fgloc.camera.blink_pairs import PairConfig
from fgloc.camera.blink_partner import PartnerConfig, decode_partner_view
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import (
    BlinkRenderConfig,
    close_groups,
    motes_synchronized,
    motes_with_codes,
    render_view,
)
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
from fgloc.survey.coded_readings import field_intrinsics
from fgloc.survey.field_plans import frames_for


def trial(seed: int, n_motes: int, book_size: int, glints: int, fields: bool = False,
          frames: int | None = None, extend: int = 0, sync: bool = False, resync_s: float = 10.0,
          slide: int = 0, pairs: int = 0, time_decode: bool = False, groups: int = 0,
          partner: bool = False) -> dict[str, float]:
    """One view. ``frames`` recorded (default 3L + 2); with ``extend`` > 0 the recording
    goes on for ``extend`` more frames and the whole stack is decoded again (keys ``ext_*``):
    the retry of a view whose motes were missed, without moving the head. ``slide``:
    ``slide`` more code lengths decoded in sliding windows (keys ``sl_*``). ``sync``: the
    synchronized book and a synchronized start (see the module docstring). ``pairs``: that many
    crowded pairs more, decoded with pair decoding (keys ``pair_*``). ``time_decode``: the
    first window is decoded once more without pair decoding, both timed (keys ``t_off``,
    ``t_on``, seconds). ``partner``: each crowded pair (group) is also decoded by the
    known-partner decoder given one (two) of its motes (keys ``ptn_*``, :func:`_partner_stats`)."""
    rng = np.random.default_rng(seed)
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    if fields:
        intr = field_intrinsics(intr)
    book = sync_code_book(book_size) if sync else code_book(book_size)
    head_pan, head_tilt = rng.uniform(-math.pi, math.pi), rng.uniform(-0.6, 0.2)
    uv = np.column_stack([rng.uniform(15, intr.width - 15, n_motes), rng.uniform(15, intr.height - 15, n_motes)])
    n_single = n_motes
    if pairs:
        uv = np.vstack([uv, _pair_pixels(rng, uv, pairs, intr.width, intr.height)])
        n_motes = len(uv)
    g0 = n_motes
    if groups:
        uv = np.vstack([uv, close_groups(groups, 3, intr.width, intr.height, rng, uv)])
        n_motes = len(uv)
    pans, tilts = pixel_to_pan_tilt(intr, uv, head_pan, head_tilt)
    dist = rng.uniform(3.0, 30.0, n_motes)
    pts = pan_tilt_bearing(pans, tilts) * dist[:, None]
    ids = rng.choice(book_size, size=n_motes, replace=False)
    k0 = frames if frames is not None else frames_for(book.length)
    ext = max(extend, slide * book.length)
    stack, cfg, t_start, timing = _render(rng, intr, head_pan, head_tilt, pts, ids, book, glints, fields, sync,
                                          resync_s, k0 + ext)
    truth = {int(i): uv[k] for k, i in enumerate(ids)}
    dmin = np.sqrt(((uv[:, None, :] - uv[None, :, :]) ** 2).sum(-1)) + np.diag(np.full(n_motes, np.inf))
    isolated = dmin.min(axis=1) >= 4.0  # no other mote within 4 px: the field plan's criterion
    out: dict[str, float] = {"decodes": n_motes, "isolated": int(isolated.sum())}
    def within(periods: int) -> list[tuple[float, np.ndarray]]:  # frames of the first periods (jitter << period)
        return [f for f in stack if f[0] < t_start + (periods - 0.5) / cfg.frame_rate_hz]

    runs = [""] + (["ext_"] if extend else []) + (["sl_"] if slide else [])
    pc = PairConfig(max_group=3) if groups else PairConfig() if pairs else None
    for prefix in runs:
        if prefix == "sl_":
            res = decode_windows(stack, 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, k0, sync=timing,
                                 pairs=pc)
        else:
            t_on = time.perf_counter()
            res = decode_view(within(k0 + (extend if prefix else 0)), 1.0 / cfg.frame_rate_hz, book, intr,
                              head_pan, head_tilt, sync=timing, pairs=pc)
            t_on = time.perf_counter() - t_on
            if time_decode and not prefix:
                t_off = time.perf_counter()
                decode_view(within(k0), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, sync=timing)
                out.update({"t_off": time.perf_counter() - t_off, "t_on": t_on})
        correct = mislabelled = 0
        ex: list[float] = []
        ey: list[float] = []
        found = set()
        for r in res.readings:
            t = truth.get(r.index)
            if t is not None and math.hypot(r.u - t[0], r.v - t[1]) <= 2.0:
                correct += 1
                found.add(r.index)
                k = int(np.flatnonzero(ids == r.index)[0])
                ex.append(math.remainder(r.pan - pans[k], 2 * math.pi) * math.cos(tilts[k]))
                ey.append(r.tilt - tilts[k])
            else:
                mislabelled += 1
        iso_missed = sum(1 for k, i in enumerate(ids) if isolated[k] and int(i) not in found)
        if groups:
            out.update({prefix + k: v for k, v in _group_stats(res.readings, ids, uv, truth, g0, found,
                                                                pans, tilts).items()})
        if pairs:
            out.update({prefix + k: v for k, v in _pair_stats(res.readings, ids, uv, truth, n_single, found,
                                                               isolated, pans, tilts).items()})
        if partner and not prefix:
            plain = decode_view(within(k0), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt)
            first = n_single if pairs else g0
            out.update(_partner_stats(rng, within(k0), 1.0 / cfg.frame_rate_hz, book, plain, res.readings, ids, uv,
                                      first, 2 if pairs else 3))
        out.update({prefix + "correct": correct, prefix + "mislabelled": mislabelled,
                    prefix + "isolated_missed": iso_missed, prefix + "views_missing": float(iso_missed > 0), prefix + "ambiguous": len(res.ambiguous()),
                    prefix + "erased": res.erased, prefix + "samples": res.samples,
                    prefix + "sq_err": float(np.sum(np.square(ex)) + np.sum(np.square(ey))),
                    prefix + "n_err": 2 * len(ex), prefix + "sq_x": float(np.sum(np.square(ex))),
                    prefix + "sq_y": float(np.sum(np.square(ey))), prefix + "n_xy": len(ex)})
    return out


def _render(rng: np.random.Generator, intr: CameraIntrinsics, head_pan: float, head_tilt: float, pts: np.ndarray,
            ids: np.ndarray, book: CodeBook, glints: int, fields: bool, sync: bool, resync_s: float,
            n_frames: int) -> tuple[list[tuple[float, np.ndarray]], BlinkRenderConfig, float, SyncTiming | None]:
    """Render one view of the motes ``ids`` (book indices) at ``pts`` (base frame) with the
    disturbances of the module docstring: (frames, render config, recording start s, sync timing)."""
    pos = {f"n{int(i)}": pts[k] for k, i in enumerate(ids)}
    codes = {f"n{int(i)}": book.bits(int(i)) for i in ids}
    cfg = BlinkRenderConfig(glints=glints, duplicate_rate=0.01)
    if fields:  # twice the rate; each field collects the light of every second row: half the flux
        cfg = replace(cfg, frame_rate_hz=2.0 * cfg.frame_rate_hz, led_flux=0.5 * cfg.led_flux,
                      static_flux=0.5 * cfg.static_flux,
                      glint_flux=(0.5 * cfg.glint_flux[0], 0.5 * cfg.glint_flux[1]))
    period = round(1.0 / cfg.frame_rate_hz, 5)  # what the motes are told (10 us resolution)
    t_start = 0.0
    timing: SyncTiming | None = None
    if sync:
        t_start = float(rng.uniform(0.0, resync_s))  # since the last synchronized (re)start, epoch 0
        motes = motes_synchronized(pos, codes, period, rng)
        timing = SyncTiming(0.0, period, cfg.exposure_s)
    else:
        motes = motes_with_codes(pos, codes, period, rng)
    spp, stt = pixel_to_pan_tilt(intr, rng.uniform(20, 620, (3, 2)) * [1, intr.height / intr.width], head_pan, head_tilt)
    statics = pan_tilt_bearing(spp, stt) * 20.0
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    return render_view(cam, intr, head_pan, head_tilt, motes, n_frames, rng, cfg, statics, t_start), cfg, t_start, timing


def candidate_trial(seed: int, n_lit: int, book_size: int, glints: int, fields: bool, frames: int,
                    near: int | None, strays: int, predict_px: float, radius_px: float,
                    rule: CandidateRule) -> dict[str, float]:
    """One round view decoded against candidates (:mod:`fgloc.camera.blink_candidates`).
    ``n_lit`` class motes (no two within 4 px: a colour class has no conflict) at random
    pixels, each a candidate predicted ``N(0, predict_px)`` px from its true pixel with radius
    ``radius_px``, plus ``U{0..near-1}`` dark decoys per lit mote (other class members
    predicted uniformly within 0.8 x radius of its prediction: 1..``near`` candidates in
    range of each blob); ``strays`` lit motes that are no candidate (they missed the pause)
    4 px to the radius from a lit mote. ``near`` None: the whole book, no prediction, no
    strays (the control). ``frames`` samples recorded; disturbances as :func:`trial`."""
    rng = np.random.default_rng(seed)
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    if fields:
        intr = field_intrinsics(intr)
    book = code_book(book_size)
    head_pan, head_tilt = rng.uniform(-math.pi, math.pi), rng.uniform(-0.6, 0.2)
    strays = strays if near is not None else 0
    uv = np.zeros((0, 2))
    while len(uv) < n_lit:
        p = np.array([rng.uniform(15, intr.width - 15), rng.uniform(15, intr.height - 15)])
        if not len(uv) or np.min(np.hypot(*(uv - p).T)) >= 4.0:
            uv = np.vstack([uv, p])
    while len(uv) < n_lit + strays:
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(4.0, radius_px)
        p = uv[int(rng.integers(n_lit))] + r * np.array([math.cos(a), math.sin(a)])
        if 15 <= p[0] <= intr.width - 15 and 15 <= p[1] <= intr.height - 15 and np.min(np.hypot(*(uv - p).T)) >= 4.0:
            uv = np.vstack([uv, p])
    n = len(uv)
    pans, tilts = pixel_to_pan_tilt(intr, uv, head_pan, head_tilt)
    pts = pan_tilt_bearing(pans, tilts) * rng.uniform(3.0, 30.0, n)[:, None]
    order = rng.permutation(book_size)
    ids = order[:n]
    stack, cfg, t_start, _ = _render(rng, intr, head_pan, head_tilt, pts, ids, book, glints, fields, False, 10.0,
                                     frames)
    if near is None:
        cands = [Candidate(i) for i in range(book_size)]
        in_range = float(book_size * n_lit)
    else:
        cands, spare = [], iter(order[n:].tolist())
        in_range = 0.0
        for k in range(n_lit):
            pu, pv = uv[k] + rng.normal(0.0, predict_px, 2)
            cands.append(Candidate(int(ids[k]), float(pu), float(pv), radius_px))
            for _ in range(int(rng.integers(near))):
                a, r = rng.uniform(0, 2 * math.pi), 0.8 * radius_px * math.sqrt(rng.uniform())
                cands.append(Candidate(next(spare), float(pu + r * math.cos(a)), float(pv + r * math.sin(a)),
                                       radius_px))
        for k in range(n_lit):
            in_range += sum(c.near(*uv[k]) for c in cands)
    res = decode_candidates(stack, 1.0 / cfg.frame_rate_hz, book, cands, intr, head_pan, head_tilt, rule)
    truth = {int(i): uv[k] for k, i in enumerate(ids[:n_lit])}
    # clear: no lit non-candidate within 8 px (outside the decoder's aperture and annulus)
    clear = {int(ids[k]) for k in range(n_lit) if not strays or np.min(np.hypot(*(uv[n_lit:] - uv[k]).T)) > 8.0}
    correct = mislabelled = stray = clear_found = 0
    for rd in res.readings:
        t = truth.get(rd.index)
        if t is not None and math.hypot(rd.u - t[0], rd.v - t[1]) <= 2.0:
            correct += 1
            clear_found += rd.index in clear
        else:
            mislabelled += 1
            stray += any(math.hypot(rd.u - q[0], rd.v - q[1]) <= 2.0 for q in uv[n_lit:])
    return {"decodes": n_lit, "clear": len(clear), "clear_missed": len(clear) - clear_found, "correct": correct, "mislabelled": mislabelled, "stray_labelled": stray,
            "strays": strays, "candidates": len(cands), "in_range": in_range, "erased": res.erased,
            "samples": res.samples, "refused": len(res.refused)}


def _run_candidates(args: argparse.Namespace) -> None:
    """The ``--candidates`` experiment: trials, then one summary line per row."""
    near = None if args.candidates == "book" else int(args.candidates)
    book = code_book(args.book)
    k = args.frames if args.frames is not None else frames_for(book.length)
    rule = CandidateRule(max_unread=args.max_unread, book_margin=args.book_margin)
    tot: dict[str, float] = {}
    t0 = time.perf_counter()
    for s in range(args.trials):
        for key, v in candidate_trial(args.seed + s, args.motes, args.book, args.glints, args.fields, k, near,
                                      args.strays, args.predict_px, args.radius, rule).items():
            tot[key] = tot.get(key, 0.0) + v
    d = tot["decodes"]
    miss = d - tot["correct"] - tot["mislabelled"]
    print(f"{'fields 640 x 240 at 59.94 Hz' if args.fields else 'frames 640 x 480 at 29.97 Hz'}: candidate decoding,"
          f" {args.trials} views x {args.motes} lit class motes (book {args.book}, L = {book.length}), "
          f"{args.glints} glints/view, {time.perf_counter() - t0:.0f} s")
    what = ("whole book, no prediction" if near is None else
            f"1..{near} candidates within {args.radius:g} px of each blob (prediction sd {args.predict_px:g} px), "
            f"{tot['strays'] / args.trials:g} lit non-candidates/view")
    print(f"  candidates: {what}; {tot['candidates'] / args.trials:.1f} per view, "
          f"{tot['in_range'] / d:.2f} in range of each lit mote; rule {rule.max_errors} errors, margin "
          f"{rule.margin}, {rule.max_unread} unread bits, book margin {rule.book_margin}")
    print(f"{k} samples/view, {tot['erased'] / tot['samples']:.1%} erased: decodes {d:.0f}: correct "
          f"{tot['correct']:.0f} ({tot['correct'] / d:.2%}), mislabelled {tot['mislabelled']:.0f} "
          f"(non-candidates labelled {tot['stray_labelled']:.0f} of {tot['strays']:.0f}), "
          f"missed {miss:.0f} ({miss / d:.2%}; all lit motes are isolated)")
    print(f"  lit motes with no lit non-candidate within 8 px {tot['clear']:.0f}: missed {tot['clear_missed']:.0f} "
          f"({tot['clear_missed'] / max(tot['clear'], 1):.2%})")


SEP_BINS = (0.0, 1.0, 2.0, 3.0, 4.0)  #: pair separation bins (px) of the resolved-share table
THIRD_BINS = (4.0, 6.0, 8.0, 12.0, math.inf)  #: bins (px) of the nearest third mote to either LED of a pair


def _pair_pixels(rng: np.random.Generator, others: np.ndarray, n: int, width: int, height: int) -> np.ndarray:
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


def _pair_stats(readings: tuple, ids: np.ndarray, uv: np.ndarray, truth: dict, n_single: int, found: set,
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


FOURTH_BINS = THIRD_BINS  #: bins (px) of the nearest fourth mote to any LED of a group


def _group_stats(readings: tuple, ids: np.ndarray, uv: np.ndarray, truth: dict, g0: int, found: set,
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


def _print_groups(tot: dict[str, float], p: str) -> None:
    n, res = tot[p + "grp_n"], tot[p + "grp_resolved"]
    npx = max(tot[p + "grp_n_px"], 1)
    print(f"  group decodes {n:.0f}: resolved {res:.0f} ({res / max(n, 1):.2%}),"
          f" partly read (1 or 2 of 3) {tot[p + 'grp_partial']:.0f}")
    print("  resolved by nearest fourth mote: " + ", ".join(
        f"{FOURTH_BINS[b]:.0f}-{FOURTH_BINS[b + 1]:.0f} px {tot[f'{p}grp_res_t{b}'] / max(tot[f'{p}grp_n_t{b}'], 1):.1%}"
        f" of {tot[f'{p}grp_n_t{b}']:.0f}" for b in range(len(FOURTH_BINS) - 1)))
    print(f"  centroid error RMS, u / v (px): group LEDs {math.sqrt(tot[p + 'grp_sq_u'] / npx):.3f} / "
          f"{math.sqrt(tot[p + 'grp_sq_v'] / npx):.3f} ({npx:.0f}); angle error RMS, pan (x cos tilt) / tilt: "
          f"{math.degrees(math.sqrt(tot[p + 'grp_sq_x'] / npx)):.5f} / {math.degrees(math.sqrt(tot[p + 'grp_sq_y'] / npx)):.5f} deg")



def _add_errors(st: dict, prefix: str, r: DecodedReading, uv: tuple[float, float], pan: float, tilt: float) -> None:
    """Accumulate one reading's squared centroid (px) and angle (rad; pan x cos tilt, tilt) errors."""
    st[f"{prefix}_sq_u"] += (r.u - uv[0]) ** 2
    st[f"{prefix}_sq_v"] += (r.v - uv[1]) ** 2
    st[f"{prefix}_n_px"] += 1
    st[f"{prefix}_sq_x"] += (math.remainder(r.pan - pan, 2 * math.pi) * math.cos(tilt)) ** 2
    st[f"{prefix}_sq_y"] += (r.tilt - tilt) ** 2


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=250)
    ap.add_argument("--motes", type=int, default=40)
    ap.add_argument("--book", type=int, default=100)
    ap.add_argument("--glints", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fields", action="store_true", help="decode 59.94 Hz fields (640 x 240), not frames")
    ap.add_argument("--frames", type=int, default=None, help="frames per view (default 3L + 2)")
    ap.add_argument("--extend", type=int, default=0, help="also decode after this many more frames")
    ap.add_argument("--sync", action="store_true", help="synchronized book and start (epoch broadcast)")
    ap.add_argument("--resync", type=float, default=10.0, help="seconds between synchronized (re)starts")
    ap.add_argument("--slide", type=int, default=0, help="record this many more code lengths, sliding windows")
    ap.add_argument("--pairs", type=int, default=0, help="crowded pairs per view, decoded with pair decoding on")
    ap.add_argument("--groups", type=int, default=0,
                    help="crowded groups of three per view, decoded with group decoding on (max_group=3)")
    ap.add_argument("--partner", action="store_true",
                    help="with --pairs/--groups: also decode each crowd's last mote by the known-partner decoder "
                    "(fgloc.camera.blink_partner), the others known")
    ap.add_argument("--time-decode", action="store_true",
                    help="also decode each first window without pair decoding; print both medians (s per view)")
    ap.add_argument("--candidates", default="", metavar="M|book",
                    help="round views decoded against candidates (blink_candidates): 1..M candidates in range of "
                    "each lit mote plus the rest of the class, or 'book' (the whole book, the control)")
    ap.add_argument("--strays", type=int, default=2, help="with --candidates: lit non-candidate motes per view")
    ap.add_argument("--predict-px", type=float, default=1.5, help="with --candidates: prediction error sd (px)")
    ap.add_argument("--radius", type=float, default=8.0, help="with --candidates: candidate radius (px)")
    ap.add_argument("--max-unread", type=int, default=CandidateRule().max_unread,
                    help="with --candidates: bit positions allowed without a clean sample")
    ap.add_argument("--book-margin", type=int, default=CandidateRule().book_margin,
                    help="with --candidates: every other book word at least this many mismatches more (0: off)")
    args = ap.parse_args()
    if args.candidates:
        if args.candidates != "book" and not (args.candidates.isdigit() and int(args.candidates) >= 1):
            ap.error(f"--candidates: a count >= 1 or 'book' ({args.candidates})")
        if args.pairs or args.groups or args.sync or args.slide or args.extend:
            ap.error("--candidates: a round view of single class motes (no --pairs/--groups/--sync/--slide/--extend)")
        try:
            CandidateRule(max_unread=args.max_unread, book_margin=args.book_margin)
        except ValueError as exc:
            ap.error(f"--max-unread/--book-margin: {exc}")
        _run_candidates(args)
        return
    if args.partner and not (args.pairs or args.groups) or args.partner and (args.sync or args.slide):
        ap.error("--partner: with --pairs or --groups, rotation-free book, no --slide")
    if args.pairs and args.groups:  # their statistics index the motes of one kind of crowd per view
        ap.error("--pairs and --groups are separate experiments: give one of them")
    tot: dict[str, float] = {}
    times: dict[str, list[float]] = {"t_off": [], "t_on": []}
    t0 = time.perf_counter()
    for k in range(args.trials):
        for key, v in trial(args.seed + k, args.motes, args.book, args.glints, args.fields, args.frames,
                             args.extend, args.sync, args.resync, args.slide, args.pairs, args.time_decode,
                             args.groups, args.partner).items():
            if key in times:
                times[key].append(v)
            else:
                tot[key] = tot.get(key, 0.0) + v
    dt = time.perf_counter() - t0
    d = tot["decodes"]
    book = sync_code_book(args.book) if args.sync else code_book(args.book)
    k0 = args.frames if args.frames is not None else frames_for(book.length)
    print(f"{'fields 640 x 240 at 59.94 Hz' if args.fields else 'frames 640 x 480 at 29.97 Hz'}: "
          f"{args.trials} views x {args.motes} motes ({'synchronized' if args.sync else 'rotation-free'} book "
          f"{args.book}, L = {book.length}), {args.glints} glints/view, "
          f"{dt:.0f} s")
    for prefix, k in [("", k0)] + ([("ext_", k0 + args.extend)] if args.extend else []) + (
            [("sl_", k0 + args.slide * book.length)] if args.slide else []):
        miss = d - tot[prefix + "correct"] - tot[prefix + "mislabelled"]
        print(f"{k} samples/view, {tot[prefix + 'erased'] / tot[prefix + 'samples']:.1%} erased (drops + duplicates): "
              f"decodes {d:.0f}: correct {tot[prefix + 'correct']:.0f} ({tot[prefix + 'correct'] / d:.2%}), "
              f"mislabelled {tot[prefix + 'mislabelled']:.0f}, missed {miss:.0f} ({miss / d:.2%}), "
              f"ambiguous reports {tot[prefix + 'ambiguous']:.0f}")
        print(f"  isolated motes (no other within 4 px) {tot['isolated']:.0f}: missed "
              f"{tot[prefix + 'isolated_missed']:.0f} ({tot[prefix + 'isolated_missed'] / max(tot['isolated'], 1):.2%}); "
              f"views with an isolated miss {tot[prefix + 'views_missing'] / args.trials:.1%}")
        rms = math.sqrt(tot[prefix + "sq_err"] / max(tot[prefix + "n_err"], 1))
        n_xy = max(tot[prefix + "n_xy"], 1)
        print(f"  angle error RMS per axis of correct readings: {math.degrees(rms) * 3600:.1f} arcsec "
              f"({math.degrees(rms):.5f} deg); pan (x cos tilt) {math.degrees(math.sqrt(tot[prefix + 'sq_x'] / n_xy)):.5f}"
              f" deg, tilt {math.degrees(math.sqrt(tot[prefix + 'sq_y'] / n_xy)):.5f} deg")
        if args.pairs:
            _print_pairs(tot, prefix)
        if args.groups:
            _print_groups(tot, prefix)
        if args.partner and not prefix:
            _print_partner(tot)
    if times["t_on"]:
        print(f"decode_view per view, median of {len(times['t_on'])}: without pair decoding "
              f"{1e3 * float(np.median(times['t_off'])):.0f} ms, with {1e3 * float(np.median(times['t_on'])):.0f} ms")


PARTNER_MARGINS = (3, 2)  #: margins (count errors) of the known-partner decodes measured side by side


def _partner_stats(rng: np.random.Generator, frames: list[tuple[float, np.ndarray]], period: float, book: CodeBook,
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


def _print_partner(tot: dict[str, float]) -> None:
    for mg in PARTNER_MARGINS:
        p = f"ptn{mg}_"
        n = tot[p + "n"]
        print(f"  known-partner decodes, margin {mg}: {n:.0f}: resolved {tot[p + 'ok']:.0f} "
              f"({tot[p + 'ok'] / max(n, 1):.2%}), mislabelled {tot[p + 'mislabelled']:.0f}, no refused blob at the "
              f"known pixel {tot[p + 'noblob']:.0f}; wrong known partner labelled {tot[p + 'wrong_labelled']:.0f} of "
              f"{tot[p + 'wrong_n']:.0f}")
        print("    resolved by nearest other mote: " + ", ".join(
            f"{THIRD_BINS[b]:.0f}-{THIRD_BINS[b + 1]:.0f} px {tot[f'{p}ok_t{b}'] / max(tot[f'{p}n_t{b}'], 1):.1%}"
            f" of {tot[f'{p}n_t{b}']:.0f}" for b in range(len(THIRD_BINS) - 1)))
        print(f"    among those the blind decoder left unresolved: {tot[p + 'cond_ok']:.0f} of {tot[p + 'cond_n']:.0f} "
              f"({tot[p + 'cond_ok'] / max(tot[p + 'cond_n'], 1):.2%}); by nearest other mote: " + ", ".join(
            f"{THIRD_BINS[b]:.0f}-{THIRD_BINS[b + 1]:.0f} px {tot[f'{p}cok_t{b}'] / max(tot[f'{p}cn_t{b}'], 1):.1%}"
            f" of {tot[f'{p}cn_t{b}']:.0f}" for b in range(len(THIRD_BINS) - 1)))


def _print_pairs(tot: dict[str, float], p: str) -> None:
    n, res = tot[p + "pair_n"], tot[p + "pair_resolved"]
    npx, nsx = max(tot[p + "pair_n_px"], 1), max(tot[p + "single_n_px"], 1)
    print(f"  pair decodes {n:.0f}: resolved {res:.0f} ({res / max(n, 1):.2%}),"
          f" one of two read {tot[p + 'pair_one']:.0f}")
    print("  resolved by separation: " + ", ".join(
        f"{SEP_BINS[b]:.0f}-{SEP_BINS[b + 1]:.0f} px {tot[f'{p}pair_res_b{b}'] / max(tot[f'{p}pair_n_b{b}'], 1):.1%}"
        f" of {tot[f'{p}pair_n_b{b}']:.0f}" for b in range(len(SEP_BINS) - 1)))
    print("  resolved by nearest third mote: " + ", ".join(
        f"{THIRD_BINS[b]:.0f}-{THIRD_BINS[b + 1]:.0f} px {tot[f'{p}pair_res_t{b}'] / max(tot[f'{p}pair_n_t{b}'], 1):.1%}"
        f" of {tot[f'{p}pair_n_t{b}']:.0f}" for b in range(len(THIRD_BINS) - 1)))
    print(f"  centroid error RMS, u / v (px): pair LEDs {math.sqrt(tot[p + 'pair_sq_u'] / npx):.3f} / "
          f"{math.sqrt(tot[p + 'pair_sq_v'] / npx):.3f} ({npx:.0f}); isolated single LEDs "
          f"{math.sqrt(tot[p + 'single_sq_u'] / nsx):.3f} / {math.sqrt(tot[p + 'single_sq_v'] / nsx):.3f} ({nsx:.0f})")
    print(f"  pair angle error RMS, pan (x cos tilt) / tilt: {math.degrees(math.sqrt(tot[p + 'pair_sq_x'] / npx)):.5f}"
          f" / {math.degrees(math.sqrt(tot[p + 'pair_sq_y'] / npx)):.5f} deg")

if __name__ == "__main__":
    main()
