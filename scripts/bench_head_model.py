"""Self-calibrating solve (``--head-model full``): node-eliminated fast path against the reference graph.

Scenes: ``fgloc.sim.bench_scenes`` (the bench's planar scenes; N nodes x K cameras, sigma
0.1 deg) with typical head errors injected (``fgloc.sim.head_errors``). For each scene both
paths run side by side in one process, alternating, ``--repeats`` times; medians are printed:

* ``fit``: :func:`fgloc.solve.self_calibration.solve_self_calibrated` with every head
  parameter of every camera, from the ideal solve's estimate (LM and marginals: the part
  the fast path replaces);
* ``full``: :func:`fgloc.solve.self_calibration.solve_with_head_model` (``HeadModel.FULL``:
  ideal solve, observability, fit, flagging and refit), what ``fgloc solve --head-model full`` runs.

Both paths must reach the same cost (relative 1e-8) or the script stops.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/bench_head_model.py [--sizes 100x2,1000x4] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from fgloc.init.start import InitialEstimate
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.sim.head_errors import inject_head_errors, typical_head_errors
from fgloc.solve.joint import SolverOptions, solve_survey
from fgloc.solve.self_calibration import HeadModel, solve_self_calibrated, solve_with_head_model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="100x2,1000x4", help="comma-separated NODESxCAMERAS")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print("| scene | step | fast path (s) | reference graph (s) | reference / fast |")
    print("|---|---|---:|---:|---:|")
    for size in args.sizes.split(","):
        n, k = (int(x) for x in size.split("x"))
        clean = scene_survey(BenchScene(n, k, seed=args.seed))
        survey = inject_head_errors(clean, typical_head_errors(clean.camera_ids, np.random.default_rng(args.seed)))
        ideal = solve_survey(survey)
        start = InitialEstimate(cameras=dict(ideal.cameras), nodes={i: e.position for i, e in ideal.nodes.items()},
                                unlocalized=dict(ideal.unlocalized))
        exclude = frozenset(f.index for f in ideal.flagged)
        active = {c: tuple(range(7)) for c in survey.camera_ids}
        times: dict[tuple[str, bool], list[float]] = {}
        costs: dict[tuple[str, bool], float] = {}
        for _ in range(args.repeats):
            for fast in (True, False):
                options = replace(SolverOptions(), eliminate_nodes=fast)
                t0 = time.perf_counter()
                fit = solve_self_calibrated(survey, start, active, options, exclude, fast_path=fast)
                times.setdefault(("fit", fast), []).append(time.perf_counter() - t0)
                costs[("fit", fast)] = fit.chi2
                t0 = time.perf_counter()
                result, _ = solve_with_head_model(survey, HeadModel.FULL, options, fast_path=fast)
                times.setdefault(("full", fast), []).append(time.perf_counter() - t0)
                assert result.stats is not None
                costs[("full", fast)] = result.stats.final_error
        for step in ("fit", "full"):
            a, b = costs[(step, True)], costs[(step, False)]
            if abs(a - b) > 1e-8 * abs(b):
                raise SystemExit(f"{size} {step}: fast path cost {a} != reference {b}")
            tf, tr = statistics.median(times[(step, True)]), statistics.median(times[(step, False)])
            print(f"| {n} x {k} | {step} | {tf:.3f} | {tr:.3f} | {tr / tf:.1f}x |")


if __name__ == "__main__":
    main()
