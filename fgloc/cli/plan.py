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

from fgloc.core.errors import FglocError


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
    plan = plan_repeats(survey, read_result(args.result), args.budget, args.objective)
    if args.json:
        print(json.dumps({"objective": plan.objective, "before": plan.before, "after": plan.after,
                          "readings": [{"camera": r.camera, "node": r.node, "gain": r.gain} for r in plan.readings]},
                         indent=1))
        return 0
    print(f"{plan.objective}: {plan.before:.6g} -> {plan.after:.6g} with {len(plan.readings)} more readings "
          f"(survey has {plan.n_readings_now}); summed node trace {plan.trace_before:.3e} -> {plan.trace_after:.3e}")
    for r in plan.readings:
        print(f"{r.camera}\t{r.node}\t{r.gain:.4g}")
    return 0
