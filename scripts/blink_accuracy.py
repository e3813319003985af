"""Localization accuracy of a coded survey against the sequential survey on the same scenes.

Each trial is one seeded paper scene (two cameras 0.1 above (0, 0) and (1, 0), nodes
uniform in the unit square, head sigma 0.1 deg). The sequential readings are the
simulator's (one independent head error per reading); the coded readings come from
:func:`fgloc.survey.coded_readings.coded_observations` (one head error per view shared by
its motes, the decoder's centroid error measured by scripts/blink_montecarlo.py,
refinement at the lowest separating zoom, misses and unresolved motes left out; each
reading names its view, so the solver estimates one head offset per view, unless
``--no-views``). Both are solved by ``fgloc.solve_survey``; RMS and ANEES are taken over the nodes both
localized. ANEES bounds: two-sided 95 % chi-square bounds for the mean of K NEES
values with 2 dof each (K = node-trials; nodes of one scene are correlated through the
cameras, so these bounds are tight).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_accuracy.py --trials 200 \
        [--fields] [--decoder-pan DEG --decoder-tilt DEG] [--fx-error 0.005] [--miss-rate Q]
        [--pair-rate P --pair-pan DEG --pair-tilt DEG] [--group-rate P --group-pan DEG --group-tilt DEG]

``--pair-rate``: crowded groups of exactly two motes are read in the wide views as pairs
with that probability, with the pair decoder's centroid error (``--pair-pan``,
``--pair-tilt``; measured by scripts/blink_montecarlo.py --pairs), and not refined.
``--group-rate``: the same for crowded groups of exactly three and the group decoder
(``--group-pan``, ``--group-tilt``; scripts/blink_montecarlo.py --groups).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy.stats import chi2

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.coded_readings import CodedNoise, accuracy_trial
from fgloc.survey.field_plans import pair_rate_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--nodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--decoder-pan", type=float, default=0.0098, help="deg, decoder angle error RMS (pan x cos tilt)")
    ap.add_argument("--decoder-tilt", type=float, default=0.0098, help="deg, decoder angle error RMS (tilt)")
    ap.add_argument("--fx-error", type=float, default=0.0, help="relative focal-length calibration error")
    ap.add_argument("--miss-rate", type=float, default=0.0, help="decoder miss rate per recording")
    ap.add_argument("--fields", action="store_true", help="decode single fields (half vertical resolution)")
    ap.add_argument("--pair-rate", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="pair decoding: share of crowded groups of exactly two read as a pair in the wide view, or "
                    "per bound on the distance to the nearest third mote (px), as field_time.py --pair-decode")
    ap.add_argument("--pair-pan", type=float, default=None, help="deg, pair-decoded centroid error RMS (pan x cos tilt)")
    ap.add_argument("--pair-tilt", type=float, default=None, help="deg, pair-decoded centroid error RMS (tilt)")
    ap.add_argument("--group-rate", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="group decoding: share of crowded groups of exactly three read as a group in the wide view, "
                    "or per bound on the distance to the nearest fourth mote (px), as field_time.py --group-decode")
    ap.add_argument("--group-pan", type=float, default=None, help="deg, group-decoded centroid error RMS (pan x cos tilt)")
    ap.add_argument("--group-tilt", type=float, default=None, help="deg, group-decoded centroid error RMS (tilt)")
    ap.add_argument("--independent-head", action="store_true",
                    help="diagnostic: an independent head error per reading instead of one per view")
    ap.add_argument("--no-views", action="store_true",
                    help="readings do not name their views: the solver takes them as independent (total sigma)")
    args = ap.parse_args()
    try:
        table = pair_rate_table(args.pair_rate) if args.pair_rate else ((math.inf, 0.0),)
    except ValueError as exc:
        ap.error(f"--pair-rate: {exc} ({args.pair_rate})")
    try:
        gtable = pair_rate_table(args.group_rate) if args.group_rate else ((math.inf, 0.0),)
    except ValueError as exc:
        ap.error(f"--group-rate: {exc} ({args.group_rate})")
    noise = CodedNoise(decoder_sigma_pan=math.radians(args.decoder_pan),
                       decoder_sigma_tilt=math.radians(args.decoder_tilt), fx_error=args.fx_error,
                       miss_rate=args.miss_rate, field_rows=args.fields,
                       shared_head=not args.independent_head, views=not args.no_views,
                       pair_rate=table[0][1] if len(table) == 1 else table,
                       pair_sigma_pan=None if args.pair_pan is None else math.radians(args.pair_pan),
                       pair_sigma_tilt=None if args.pair_tilt is None else math.radians(args.pair_tilt),
                       group_rate=gtable[0][1] if len(gtable) == 1 else gtable,
                       group_sigma_pan=None if args.group_pan is None else math.radians(args.group_pan),
                       group_sigma_tilt=None if args.group_tilt is None else math.radians(args.group_tilt))
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    sq = {"seq": [], "coded": []}  # type: dict[str, list[np.ndarray]]
    ne = {"seq": [], "coded": []}  # type: dict[str, list[np.ndarray]]
    views = refined = unresolved = missed = dropped = 0
    t0 = time.perf_counter()
    for k in range(args.trials):
        a = accuracy_trial(args.seed + k, args.nodes, intr, noise)
        sq["seq"].append(a.sq_seq)
        sq["coded"].append(a.sq_coded)
        ne["seq"].append(a.nees_seq)
        ne["coded"].append(a.nees_coded)
        views += sum(a.readings.views.values())
        refined += sum(a.readings.refined.values())
        unresolved += sum(a.readings.unresolved.values())
        missed += sum(a.readings.missed.values())
        dropped += a.dropped
    dt = time.perf_counter() - t0
    n = sum(len(x) for x in sq["seq"])
    lo, hi = chi2.ppf(0.025, 2 * n) / n, chi2.ppf(0.975, 2 * n) / n
    print(f"{args.trials} scenes x {args.nodes} nodes, decoder {args.decoder_pan} / {args.decoder_tilt} deg, "
          f"fx error {args.fx_error}, miss rate {args.miss_rate}, {'fields' if args.fields else 'frames'}, "
          f"head error {'per reading' if args.independent_head else 'per view'}"
          f"{', views not named' if args.no_views else ''}"
          f"{f', pair decoding at {args.pair_rate} ({args.pair_pan} / {args.pair_tilt} deg)' if args.pair_rate else ''}"
          f"{f', group decoding at {args.group_rate} ({args.group_pan} / {args.group_tilt} deg)' if args.group_rate else ''}, "
          f"{dt:.0f} s")
    print(f"per scene: {views / args.trials:.1f} views (both cameras), {refined / args.trials:.1f} refined readings, "
          f"{unresolved / args.trials:.2f} unresolved, {missed / args.trials:.2f} missed, "
          f"{dropped / args.trials:.2f} nodes unlocalized by the coded solve; {n} node-trials compared")
    rms = {k: math.sqrt(float(np.mean(np.concatenate(v)))) for k, v in sq.items()}
    anees = {k: float(np.mean(np.concatenate(v))) for k, v in ne.items()}
    print("| survey | RMS error (baseline units) | RMS / sequential | ANEES | 95 % bounds |")
    print("|---|---|---|---|---|")
    for k in ("seq", "coded"):
        ok = "inside" if lo <= anees[k] <= hi else "OUTSIDE"
        print(f"| {k} | {rms[k]:.5f} | {rms[k] / rms['seq']:.3f} | {anees[k]:.3f} | [{lo:.3f}, {hi:.3f}] {ok} |")


if __name__ == "__main__":
    main()
