"""``fgloc plan``: survey planning by the Cramér–Rao bound (docs/planning.md).

``fgloc plan place SITES.json --cameras K -o DIR``: where to put the cameras (plan.json,
rig.json, plan.png), optionally checked by Monte Carlo (``--validate N``, on Dask with
``--dask local`` or ``--dask tcp://HOST:8786``). ``fgloc plan repeat SURVEY RESULT --budget N``:
which readings to take next.
"""

from __future__ import annotations

import argparse
import json
import os
from typing import TYPE_CHECKING

from fgloc.core.errors import FglocError

if TYPE_CHECKING:
    from fgloc.core.model import Result, Survey
    from fgloc.plan.repeat import RepeatPlan


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan a survey: camera placement, re-measurements")
    ps = p.add_subparsers(dest="plan_command", required=True, metavar="WHAT")
    pl = ps.add_parser("place", help="choose camera sites and heights")
    pl.add_argument("sites", help="site file (JSON): field, candidate sites/grid, visibility, sigma_deg")
    pl.add_argument("--cameras", type=int, required=True, help="number of cameras (>= 2)")
    pl.add_argument("--objective", default="mean", help="mean | worst | logdet (default mean)")
    pl.add_argument("--sigma-deg", type=float, default=None, help="bearing noise in degrees (default: the file's)")
    pl.add_argument("-o", "--out", required=True, help="output directory (plan.json, rig.json, plan.png)")
    pl.add_argument("--swap", action="store_true",
                    help="refine greedy by exchanges (each chosen site against every free one) while the objective improves")
    pl.add_argument("--bound", action="store_true", help="also compute the convex-relaxation log-det bound")
    pl.add_argument("--validate", type=int, default=0, metavar="N", help="check the prediction on N simulated surveys")
    pl.add_argument("--dask", default=None, metavar="ADDRESS",
                    help="run the validation on Dask: 'local' (a 2-worker LocalCluster) or a scheduler address")
    pl.add_argument("--no-picture", action="store_true", help="skip plan.png")
    pl.set_defaults(run=run_place)
    pr = ps.add_parser("repeat", help="the next readings worth taking")
    pr.add_argument("survey", help="survey.json")
    pr.add_argument("result", help="result.json (its solve)")
    pr.add_argument("--budget", type=int, required=True, help="number of readings to plan")
    pr.add_argument("--objective", default="mean", help="mean | worst | logdet (default mean)")
    pr.add_argument("--json", action="store_true", help="print machine-readable JSON")
    pr.add_argument("--bound", action="store_true",
                    help="also bound the plan by the convex relaxation (mean, logdet) and certify whether "
                         "1.3x the readings of one pass can reach the trace of every reading measured 3x")
    pr.set_defaults(run=run_repeat)


def run_place(args: argparse.Namespace) -> int:
    from fgloc.plan.io import read_site_file, write_plan
    from fgloc.plan.placement import OBJECTIVES, plan_placement

    if args.objective not in OBJECTIVES:
        raise FglocError(f"--objective: expected one of {', '.join(OBJECTIVES)} ({args.objective!r})")
    if args.cameras < 2:
        raise FglocError(f"--cameras: must be >= 2 ({args.cameras})")
    if args.sigma_deg is not None and not args.sigma_deg > 0:
        raise FglocError(f"--sigma-deg: must be > 0 ({args.sigma_deg})")
    if args.validate < 0:
        raise FglocError(f"--validate: must be >= 0 ({args.validate})")
    problem, polygon = read_site_file(args.sites, args.sigma_deg)
    plan = plan_placement(problem, args.cameras, args.objective, refine=args.swap)
    os.makedirs(args.out, exist_ok=True)
    write_plan(plan, args.out)
    if not args.no_picture:
        from fgloc.plan.picture import plan_picture

        plan_picture(plan, os.path.join(args.out, "plan.png"), polygon)
    pe = plan.predicted
    print(f"cameras (gauge pair first): {', '.join(problem.label(c) for c in plan.chosen)}")
    print(f"predicted node error: median {pe.median:.4f} m, 95% {pe.p95:.4f} m, worst {pe.worst:.4f} m")
    if args.bound:
        from fgloc.plan.fisher import candidate_info
        from fgloc.plan.placement import default_prior_m
        from fgloc.plan.relaxation import placement_bound

        info = candidate_info(problem.jacobians(), problem.nodes_xy, default_prior_m(problem))
        b = placement_bound(info, problem.site_ids, list(plan.chosen))
        print(f"relaxation bound: log det within {b.gap_nats:.2f} nats of the best possible "
              f"({100 * b.gain_ratio:.1f}% of the largest possible gain)")
    if args.validate:
        from contextlib import nullcontext

        from fgloc.evaluate.sweep import dask_executor
        from fgloc.plan.validate import simulate_plan

        ch = list(plan.chosen)
        ctx = nullcontext(None) if args.dask is None else dask_executor(None if args.dask == "local" else args.dask)
        with ctx as executor:
            sim, _ = simulate_plan(problem.positions()[ch], problem.rotations()[ch], problem.nodes_xy,
                                   problem.visible()[ch], problem.sigma, args.validate, executor=executor,
                                   progress=args.progress)
        print(f"simulated ({sim.trials} surveys): median {sim.median:.4f} m, 95% {sim.p95:.4f} m, "
              f"worst {sim.worst:.4f} m (predicted/simulated median {pe.median / sim.median:.3f})")
    return 0


def run_repeat(args: argparse.Namespace) -> int:
    from fgloc.files.survey_result import read_result, read_survey
    from fgloc.plan.repeat import plan_repeats

    if args.budget < 1:
        raise FglocError(f"--budget: must be >= 1 ({args.budget})")
    if args.objective not in ("mean", "worst", "logdet"):
        raise FglocError(f"--objective: expected one of mean, worst, logdet ({args.objective!r})")
    survey = read_survey(args.survey)
    result = read_result(args.result)
    plan = plan_repeats(survey, result, args.budget, args.objective)
    bound, feasibility = _repeat_bound(survey, result, plan) if args.bound else (None, {})
    if args.json:
        doc = {"objective": plan.objective, "before": plan.before, "after": plan.after,
               "readings": [{"camera": r.camera, "node": r.node, "gain": r.gain} for r in plan.readings]}
        if args.bound:
            doc["bound"] = bound
            doc["feasibility"] = feasibility
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{plan.objective}: {plan.before:.6g} -> {plan.after:.6g} with {len(plan.readings)} more readings "
          f"(survey has {plan.n_readings_now}); summed node trace {plan.trace_before:.3e} -> {plan.trace_after:.3e}")
    for r in plan.readings:
        print(f"{r.camera}\t{r.node}\t{r.gain:.4g}")
    if args.bound:
        _print_bound(bound, feasibility)
    return 0


def _repeat_bound(survey: Survey, result: Result, plan: RepeatPlan) -> tuple[dict | None, dict]:
    """The relaxation bound of ``plan`` (None for ``worst``) and the feasibility certificate, as JSON."""
    from fgloc.plan.repeat import RepeatModel
    from fgloc.plan.repeat_bound import BOUND_OBJECTIVES, PairSystem, counts_of, plan_bound, repeat_feasibility

    bound = None
    if plan.objective in BOUND_OBJECTIVES:
        model = RepeatModel(survey, result)
        counts = counts_of(model, [(r.camera, r.node) for r in plan.readings])
        b = plan_bound(PairSystem.from_model(model), counts, plan.objective)
        bound = {"objective": b.objective, "budget": b.budget, "before": b.before, "achieved": b.achieved,
                 "bound": b.bound, "relaxed": b.relaxed, "gap": b.gap, "gap_percent": b.gap_percent,
                 "gain_ratio": b.gain_ratio, "iterations": b.iterations}
    f = repeat_feasibility(survey, result)
    feasibility = {"status": f.status, "n_readings": f.n_readings, "budget": f.budget,
                   "trace_one_pass": f.trace_one_pass, "target": f.target, "bound": f.bound,
                   "free_bound": f.free_bound, "certified_min_budget": f.certified_min_budget,
                   "certified_min_ratio": f.ratio(f.certified_min_budget),
                   "relaxed_reach_budget": f.relaxed_reach_budget, "greedy_budget": f.greedy_budget,
                   "greedy_ratio": f.ratio(f.greedy_budget)}
    return bound, feasibility


def _print_bound(bound: dict | None, f: dict) -> None:
    if bound is None:
        print("relaxation bound: not supported for objective worst (max of node traces is not smooth)")
    else:
        unit = "nats" if bound["objective"] == "logdet" else "baseline units^2"
        print(f"relaxation bound ({bound['objective']}): no plan of {bound['budget']} readings gets below "
              f"{bound['bound']:.6g}; this plan {bound['achieved']:.6g}, gap {bound['gap']:.3g} {unit} "
              f"({bound['gap_percent']:.2f}% of the bound), {100 * bound['gain_ratio']:.1f}% of the best possible gain")
    greedy = ("not reached" if f["greedy_budget"] is None
              else f"{f['greedy_budget']} extra ({f['greedy_ratio']:.2f}x one pass)")
    print(f"every reading 3x: target summed trace {f['target']:.4e} (one pass {f['trace_one_pass']:.4e}); "
          f"with {f['budget']} extra readings (1.3x one pass) no plan gets below {f['bound']:.4e}: {f['status']}")
    print(f"  needs >= {f['certified_min_budget']} extra readings ({f['certified_min_ratio']:.2f}x one pass, certified); "
          f"greedy: {greedy}")
    if f["free_bound"] > f["target"]:
        print(f"  not even {f['n_readings'] + f['budget']} readings allocated freely over the pairs (first pass not kept) "
              f"get below {f['free_bound']:.4e}")
