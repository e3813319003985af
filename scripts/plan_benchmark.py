"""Survey-planning benchmark (docs/planning.md): planned vs naive placement by Monte Carlo, planning time,
repeat planning against "every reading 3x" (the relaxation bound and
its certificate: scripts/repeat_bound.py), and a Dask LocalCluster sweep against the serial one.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/plan_benchmark.py [--quick]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/plan_benchmark.py --placement 8x1000 --trials 20 \
        --objectives mean,mean+swap,logdet      # only those placement rows
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from fgloc.evaluate.sweep import dask_executor, run_sweep
from fgloc.plan.placement import evaluate_placement, plan_placement
from fgloc.plan.repeat import RepeatModel, plan_repeats
from fgloc.plan.repeat_bound import PairSystem, counts_of, plan_bound
from fgloc.plan.site import PlanProblem, corner_placement, grid_sites, sample_polygon
from fgloc.plan.validate import simulate_plan
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.joint import solve_survey

SQUARE = np.array([[0, 0], [100, 0], [100, 100], [0, 100.0]])
SIGMA = math.radians(0.1)
HEIGHTS = (3.0, 8.0)


def placement_rows(n_nodes: int, cams: int, trials: int, objective: str = "mean") -> str:
    """One table row; ``objective`` is mean, worst or logdet, with ``+swap`` for the exchange refinement."""
    nodes = sample_polygon(SQUARE, n_nodes, 1)
    ids, xy, hs = grid_sites((-10, -10, 110, 110), 20, HEIGHTS)
    problem = PlanProblem(nodes, ids, xy, hs, SIGMA)
    t0 = time.perf_counter()
    plan = plan_placement(problem, cams, objective.removesuffix("+swap"), refine=objective.endswith("+swap"))
    seconds = time.perf_counter() - t0
    ch = list(plan.chosen)
    sim, _ = simulate_plan(problem.positions()[ch], problem.rotations()[ch], nodes, problem.visible()[ch], SIGMA, trials)
    best = None
    for h in HEIGHTS:  # the naive placement at its best single height
        naive_xy = corner_placement(SQUARE, cams)
        nprob = PlanProblem(nodes, tuple(f"c{i}" for i in range(cams)), naive_xy, np.full(cams, h), SIGMA)
        nplan = evaluate_placement(nprob, list(range(cams)), "mean")
        if best is None or nplan.predicted.median < best[1].predicted.median:
            best = (nprob, nplan)
    assert best is not None
    nprob, nplan = best
    nch = list(nplan.chosen)
    nsim, _ = simulate_plan(nprob.positions()[nch], nprob.rotations()[nch], nodes, nprob.visible()[nch], SIGMA, trials)
    return (f"| {cams} | {n_nodes} | {objective} | {seconds:.2f} | {plan.predicted.median * 100:.2f} | {sim.median * 100:.2f} | "
            f"{plan.predicted.median / sim.median:.3f} | {nplan.predicted.median * 100:.2f} | {nsim.median * 100:.2f} | "
            f"{sim.median / nsim.median:.3f} | {trials} |")


def timing_row() -> str:
    nodes = sample_polygon(SQUARE, 1000, 2)
    ids, xy, hs = grid_sites((-15, -15, 115, 115), 130 / 6, (5.0,))  # 7 x 7 = 49 sites
    problem = PlanProblem(nodes, ids, xy, hs, SIGMA)
    times = {}
    for objective in ("mean", "worst", "logdet"):
        t0 = time.perf_counter()
        plan_placement(problem, 4, objective)
        times[objective] = time.perf_counter() - t0
    return f"1000 nodes x {len(set(ids))} sites x 4 cameras: " + ", ".join(f"{k} {v:.2f} s" for k, v in times.items())


def repeat_rows(n_nodes: int, cams: int, seed: int) -> str:
    survey = scene_survey(BenchScene(n_nodes, cams, seed=seed))
    result = solve_survey(survey)
    model = RepeatModel(survey, result)
    one_pass = model.n_readings
    target = float(model.node_traces().sum()) / 3.0  # every reading 3x: the information triples
    plan = plan_repeats(survey, result, 2 * one_pass, "mean", stop_trace=target)
    reached = plan.trace_after <= target
    extra = len(plan.readings)
    d = plan_repeats(survey, result, int(0.3 * one_pass), "logdet")
    b = plan_bound(PairSystem.from_model(model), counts_of(model, [(r.camera, r.node) for r in d.readings]), "logdet")
    return (f"| {n_nodes} x {cams} | {one_pass} | {extra if reached else '>' + str(extra)} | "
            f"{(one_pass + extra) / one_pass:.2f} | {100 * b.gain_ratio:.1f} |")


def dask_row(n: int) -> str:
    scenes = [BenchScene(20, 3, seed=s) for s in range(n)]
    t0 = time.perf_counter()
    serial = run_sweep(scenes)
    t_serial = time.perf_counter() - t0
    with dask_executor(n_workers=2) as ex:
        t0 = time.perf_counter()
        dist = run_sweep(scenes, ex)
        t_dask = time.perf_counter() - t0
    same = [replace(t, seconds=0.0) for t in serial] == [replace(t, seconds=0.0) for t in dist]
    return f"{n} scenes: serial {t_serial:.1f} s, 2-worker LocalCluster {t_dask:.1f} s, identical: {same}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--placement", default=None, metavar="CAMSxNODES,...",
                    help="only these placement rows (e.g. 8x1000), nothing else")
    ap.add_argument("--trials", type=int, default=None, help="trials per --placement row (default 10)")
    ap.add_argument("--objectives", default="mean", help="comma-separated, for --placement rows (default mean)")
    args = ap.parse_args()
    header = ("| cameras | nodes | objective | plan s | predicted median cm | simulated median cm | "
              "predicted/simulated | naive predicted cm | naive simulated cm | planned/naive | trials |")
    if args.placement:
        print(header)
        print("|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for row in args.placement.split(","):
            cams, n = (int(v) for v in row.split("x"))
            for objective in args.objectives.split(","):
                print(placement_rows(n, cams, args.trials or 10, objective), flush=True)
        return
    print(timing_row(), flush=True)
    print(header)
    print("|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for cams in (2, 4, 8):
        for n, trials in ((100, 20), (1000, 3 if args.quick else 10)):
            print(placement_rows(n, cams, trials), flush=True)
    print("| survey | readings (one pass) | extra readings to reach the 3x trace | total / one pass | "
          "log-det gain of 0.3 pass, % of the best possible (relaxation) |")
    print("|---|---:|---:|---:|---:|")
    for n, cams, seed in ((100, 4, 1), (300, 4, 2)):
        print(repeat_rows(n, cams, seed), flush=True)
    print(dask_row(200), flush=True)


if __name__ == "__main__":
    main()
