"""Repeat planning against its convex relaxation (docs/planning.md, "Re-measurement: how good is greedy").

For bench scenes (``BenchScene(n, cameras, seed=1)``, solved by ``solve_survey``, linearized at the
estimate), with B = floor(0.3 x the readings of one pass):

* goal (b): the greedy plan of B readings (objectives ``mean`` and ``logdet``) against the certified
  relaxation bound: gap in % of the bound and share of the best possible gain;
* goal (a): the summed node trace of "every reading measured 3x" (T3) against the certified lower
  bound on the trace of every plan of B extra readings (bound > T3: proven infeasible), the smallest
  budget the relaxation certifies is needed, and the budget greedy needs.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/repeat_bound.py [--scenes 100x2,100x4,1000x2,1000x4]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fgloc.plan.repeat import RepeatModel, plan_repeats
from fgloc.plan.repeat_bound import PairSystem, counts_of, evaluate, plan_bound, repeat_feasibility
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.joint import solve_survey


def scene_rows(n: int, cams: int, seed: int) -> tuple[list[str], str]:
    survey = scene_survey(BenchScene(n, cams, seed=seed))
    result = solve_survey(survey)
    model = RepeatModel(survey, result)
    system = PairSystem.from_model(model)
    n1 = model.n_readings
    budget = int(np.floor(0.3 * n1))
    label = f"{n} x {cams}"
    rows = []
    t0 = time.perf_counter()
    feas = repeat_feasibility(survey, result, greedy=False)
    t_cert = time.perf_counter() - t0
    t0 = time.perf_counter()
    to_target = plan_repeats(survey, result, 2 * n1, "mean", stop_trace=feas.target)
    t_greedy3 = time.perf_counter() - t0
    greedy_budget = len(to_target.readings) if to_target.trace_after <= feas.target else None
    for objective in ("mean", "logdet"):
        t0 = time.perf_counter()
        if objective == "mean":  # the first B picks of the run to the target are the greedy plan of B
            picks = to_target.readings[:budget]
            t_greedy = t_greedy3 * len(picks) / max(len(to_target.readings), 1)
        else:
            picks = plan_repeats(survey, result, budget, objective).readings
            t_greedy = time.perf_counter() - t0
        counts = counts_of(model, [(r.camera, r.node) for r in picks])
        t0 = time.perf_counter()
        b = plan_bound(system, counts, objective)
        t_bound = time.perf_counter() - t0
        unit = "nats" if objective == "logdet" else "%"
        gap = f"{b.gap:.3f} nats" if unit == "nats" else f"{b.gap_percent:.2f} %"
        rows.append(f"| {label} | {n1} | {len(model.pairs)} | {objective} | {budget} | {b.before:.6g} | "
                    f"{b.achieved:.6g} | {b.bound:.6g} | {gap} | {100 * b.gain_ratio:.1f} | {b.iterations} | "
                    f"{t_greedy:.1f} | {t_bound:.2f} |")
    g = "not reached" if greedy_budget is None else f"{greedy_budget} ({feas.ratio(greedy_budget):.3f})"
    free = f"{feas.free_bound:.4e}" + (" > T3" if feas.free_bound > feas.target else "")
    feas_row = (f"| {label} | {n1} | {budget} | {feas.trace_one_pass:.4e} | {feas.target:.4e} | {feas.bound:.4e} | "
                f"{feas.status} | {free} | {feas.certified_min_budget} ({feas.ratio(feas.certified_min_budget):.3f}) | "
                f"{feas.relaxed_reach_budget} | {g} | {t_cert:.1f} | {t_greedy3:.1f} |")
    assert float(evaluate(system, np.zeros(system.n_pairs), "mean", False).value) == feas.trace_one_pass
    return rows, feas_row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default="100x2,100x4,1000x2,1000x4", help="NODESxCAMERAS,... (BenchScene, seed 1)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    bound_rows, feas_rows = [], []
    for item in args.scenes.split(","):
        n, cams = (int(v) for v in item.split("x"))
        rows, feas = scene_rows(n, cams, args.seed)
        bound_rows += rows
        feas_rows.append(feas)
        print("\n".join(rows), flush=True)
        print(feas, flush=True)
    print()
    print("| survey | readings (one pass) | pairs | objective | B = 0.3 pass | before | greedy | relaxation bound | "
          "gap (of bound) | % of best possible gain | SPG iterations | greedy s | bound s |")
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(bound_rows))
    print()
    print("| survey | readings (one pass) | B | trace one pass | T3 (every reading 3x) | certified min trace, B extra | "
          "status | certified min trace, 1.3 passes allocated freely | certified min extra (total/pass) | "
          "relaxation reaches T3 at | greedy reaches T3 at (total/pass) | certificate s | greedy s |")
    print("|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|")
    print("\n".join(feas_rows))


if __name__ == "__main__":
    main()
