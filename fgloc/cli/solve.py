"""``fgloc solve``: solve a survey.json into a result.json."""

from __future__ import annotations

import argparse
import logging
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fgloc.baselines.subset_newton import SubsetNewtonResult
    from fgloc.core.model import Result, Survey


#: Exit status of ``fgloc solve`` when the result was written but is implausible
#: (a camera below the node plane, or readings that do not fit the noise model).
IMPLAUSIBLE_EXIT = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("solve", help="solve a survey (joint factor-graph solve by default)")
    p.add_argument("survey", help="survey.json to read")
    p.add_argument("-o", "--output", required=True, help="result.json to write (atomically)")
    p.add_argument(
        "--method", choices=("joint", "subset-newton"), default="joint",
        help="joint factor-graph solve (default) or the paper's subset-averaging Newton baseline",
    )
    p.add_argument("--subset-size", type=int, default=10, help="subset-newton: nodes per subset (untagged surveys)")
    p.add_argument("--subsets", type=int, default=50, help="subset-newton: number of subsets (untagged surveys)")
    p.add_argument("--seed", type=int, default=0, help="subset-newton: seed of the subset draw (untagged surveys)")
    p.add_argument(
        "--head-model", choices=("ideal", "auto", "full"), default="ideal",
        help="joint: ideal pan-tilt head (default), estimate the head errors the data support (auto), "
        "or all of them (full; refused when the survey cannot determine them); docs/head-calibration.md",
    )
    p.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording (open with `rerun FILE.rrd`)")
    p.set_defaults(run=run)


def describe(result: Result) -> str:
    """One-paragraph summary of a solve for people."""
    s = result.stats
    lines = [f"localized {len(result.nodes)} nodes, {len(result.cameras)} cameras"
             + (f"; {len(result.unlocalized)} unlocalized" if result.unlocalized else "")]
    if s is not None:
        lines.append(
            f"{s.method}: {s.iterations} iterations, error {s.initial_error:.6g} -> {s.final_error:.6g}"
            f" ({'converged' if s.converged else 'NOT converged'})"
        )
        total = sum(s.stage_seconds.values())
        stages = ", ".join(f"{k} {1000 * v:.1f} ms" for k, v in s.stage_seconds.items())
        lines.append(f"time {1000 * total:.1f} ms ({stages})")
    if result.flagged:
        lines.append(f"{len(result.flagged)} observations flagged as implausible (see result file)")
    f = result.fit
    if f is not None:
        if f.dof > 0:
            lines.append(f"fit: chi2 {f.chi2:.6g} for {f.dof} degrees of freedom ({f.readings} readings; "
                         f"ratio {f.chi2 / f.dof:.3g}, expect about 1; p = {f.p_value:.3g})")
        else:
            lines.append(f"fit: {f.readings} readings leave no degrees of freedom to judge the fit")
        lines.extend(f"IMPLAUSIBLE: {problem}" for problem in f.problems)
        lines.extend(f"note: {note}" for note in f.notes)
    return "\n".join(lines)


def subset_cloud(survey: Survey, outcome: SubsetNewtonResult) -> tuple:
    """The baseline's subset solutions as ``(node_ids, positions, node_index, mean)`` for Rerun."""
    import numpy as np

    mean = np.full((len(survey.node_ids), 3), np.nan)
    for j, nid in enumerate(survey.node_ids):
        if nid in outcome.result.nodes:
            mean[j] = outcome.result.nodes[nid].position
    sol = outcome.solutions
    return survey.node_ids, sol.position, sol.node_index, mean


def run(args: argparse.Namespace) -> int:
    from fgloc.files.survey_result import read_survey, write_result
    from fgloc.solve.joint import solve_survey
    from fgloc.solve.plausibility import assess

    survey = read_survey(args.survey)
    recorder = None
    subsets = None
    if args.method == "subset-newton":
        from fgloc.baselines.subset_newton import SubsetNewtonOptions, solve_subset_newton

        outcome = solve_subset_newton(
            survey, SubsetNewtonOptions(subset_size=args.subset_size, n_subsets=args.subsets, seed=args.seed)
        )
        result = outcome.result
        failed = ", ".join(f"{k} {v}" for k, v in outcome.failures.items() if v) or "none"
        print(f"subset-newton: {len(outcome.subsets)} subsets, failed: {failed}")
        subsets = subset_cloud(survey, outcome)
    else:
        if args.rerun:
            from fgloc.viz import IterationRecorder  # rerun is imported only when asked for

            recorder = IterationRecorder(survey)
        result = solve_survey(survey, on_iteration=recorder)
    head_report = None
    if args.method == "joint" and args.head_model != "ideal":
        from fgloc.solve.self_calibration import HeadModel, solve_with_head_model

        result, head_report = solve_with_head_model(survey, HeadModel(args.head_model))
    # The fit is judged against the ideal head model's residuals: only for the plain joint solve.
    result.fit = assess(survey, result, least_squares=args.method == "joint" and head_report is None)
    write_result(result, args.output, {"head_calibration": head_report.to_json()} if head_report else None)
    print(describe(result))
    if head_report is not None:
        print(head_report.summary())
    print(f"wrote {args.output}")
    status = 0 if result.fit.plausible else IMPLAUSIBLE_EXIT
    if args.rerun:
        from fgloc.viz import camera_covariances_or_none, write_rrd

        write_rrd(args.rerun, result, survey, recorder=recorder, subsets=subsets,
                  camera_covariances=camera_covariances_or_none(survey, result) if subsets is None else None,
                  head_calibration=head_report.to_json() if head_report is not None else None)
        print(f"wrote {args.rerun} (open it with `rerun {args.rerun}`)")
    if status:
        logging.getLogger(__name__).warning(f"{args.output}: the solution is implausible (see IMPLAUSIBLE above)")
    return status
