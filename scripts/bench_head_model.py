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

Then the head parameters' data-only information (what observability and ``--head-model auto``'s
score test use), side by side: :func:`~fgloc.solve.self_calibration.head_information` (block
elimination: per node, then the poses) against the dense least squares it replaced
(:func:`dense_head_information` below); they must agree to 1e-9 (relative) or the script stops.

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
from fgloc.solve.self_calibration import (
    HeadModel,
    SelfCalibrationProblem,
    build_self_calibration_problem,
    head_information,
    solve_self_calibrated,
    solve_with_head_model,
)


def dense_head_information(problem: SelfCalibrationProblem) -> np.ndarray:
    """J_h' (I - P_x) J_h from the dense whitened Jacobian of every bearing and the gauge
    (``numpy.linalg.lstsq`` on the pose and node columns): the previous implementation."""
    import gtsam

    problem.prepare(problem.initial)
    heads = set(problem.head_keys.values())
    sub = gtsam.NonlinearFactorGraph()
    for i in range(problem.graph.size()):
        if not set(problem.graph.at(i).keys()) <= heads:
            sub.add(problem.graph.at(i))
    linear = sub.linearize(problem.initial)
    keys = sorted(linear.keys())
    ordering = gtsam.Ordering()
    for key in keys:
        ordering.push_back(key)
    A, _ = linear.jacobian(ordering)
    dims, offset, cols = problem.initial.dims(), 0, {}
    for key in keys:
        cols[key] = np.arange(offset, offset + int(dims[key]))
        offset += int(dims[key])
    h = np.concatenate([cols[k] for k in problem.head_keys.values()])
    x = np.setdiff1d(np.arange(A.shape[1]), h)
    coef, *_ = np.linalg.lstsq(A[:, x], A[:, h], rcond=None)
    R = A[:, h] - A[:, x] @ coef
    out: np.ndarray = R.T @ R
    return out


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
        problem = build_self_calibration_problem(survey, start, active, exclude=exclude, with_prior=False)
        t_block, t_dense = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            info, _ = head_information(problem, problem.initial)
            t_block.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ref = dense_head_information(problem)
            t_dense.append(time.perf_counter() - t0)
            if np.max(np.abs(info - ref)) > 1e-9 * np.max(np.abs(ref)):
                raise SystemExit(f"{size}: block-eliminated head information differs from the dense one")
        tb, td = statistics.median(t_block), statistics.median(t_dense)
        print(f"| {n} x {k} | head information: block elimination / dense least squares | {tb:.3f} | {td:.3f} "
              f"| {td / tb:.1f}x |")


if __name__ == "__main__":
    main()
