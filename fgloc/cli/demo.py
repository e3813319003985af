"""``fgloc demo``: the main job. Simulate the paper's scenario, solve it jointly and with the
paper's subset-averaging baseline on the same readings, compare both with the Cramér–Rao
bound, and write the survey, both results and a Rerun recording."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

SUBSET_SIZE, SUBSETS = 10, 50

if TYPE_CHECKING:
    import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate the paper's scenario, solve, compare with the paper's method, write files")
    p.add_argument("-o", "--out-dir", default="out", help="directory for the files (default out/)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--no-rerun", action="store_true", help="do not write the Rerun recording")
    p.set_defaults(run=run)


def bound_error_draws(covariances: list[np.ndarray], replicates: int = 200, seed: int = 0) -> np.ndarray:
    """Error norms an efficient estimator would show: (replicates, nodes) Gaussian draws from the bound."""
    import numpy as np

    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(np.array(covariances))
    z = rng.standard_normal((replicates, len(covariances), chol.shape[-1]))
    return np.linalg.norm(np.einsum("nij,rnj->rni", chol, z), axis=-1)


def comparison_table(rows: list[tuple[str, np.ndarray, float | None, float | None]]) -> str:
    """Markdown table of per-node errors in metres at the paper's 100 m baseline.

    A 2-D ``err`` (replicates, nodes) is summarized per replicate and averaged.
    """
    import numpy as np

    from fgloc.evaluate.score import PAPER_BASELINE_METRES

    lines = [
        "| method | median m | 95% m | max m | RMS m | ANEES | time s |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, err, anees, seconds in rows:
        e = np.atleast_2d(err * PAPER_BASELINE_METRES)
        stats = [np.median(e, axis=1), np.percentile(e, 95, axis=1), e.max(axis=1), np.sqrt(np.mean(e**2, axis=1))]
        med, p95, mx, rms = (float(np.mean(v)) for v in stats)
        lines.append(
            f"| {name} | {med:.3f} | {p95:.3f} | {mx:.3f} | {rms:.3f} | "
            f"{'' if anees is None else f'{anees:.2f}'} | {'' if seconds is None else f'{seconds:.3f}'} |"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fgloc.baselines.subset_newton import SubsetNewtonOptions, solve_subset_newton
    from fgloc.cli.solve import describe, subset_cloud
    from fgloc.evaluate.crlb import cramer_rao_bound
    from fgloc.evaluate.score import PAPER_BASELINE_METRES, format_score_table, score
    from fgloc.files.survey_result import write_result, write_survey
    from fgloc.sim.scenes import PaperScenario, paper_scenario
    from fgloc.solve.joint import solve_survey

    out = Path(args.out_dir)
    survey = paper_scenario(PaperScenario(seed=args.seed))
    write_survey(survey, out / "survey.json")
    print(f"simulated the paper's scenario: {len(survey.node_ids)} nodes, 2 cameras at heights 0.1 "
          f"(10 m on a 100 m baseline), sigma 0.1 deg, seed {args.seed} -> {out / 'survey.json'}")

    recorder = None
    if not args.no_rerun:
        from fgloc.viz import IterationRecorder  # keeps `import fgloc.cli` free of rerun

        recorder = IterationRecorder(survey)
    t0 = time.perf_counter()
    joint = solve_survey(survey, on_iteration=recorder)
    joint_s = time.perf_counter() - t0
    write_result(joint, out / "result.json")
    print()
    print(describe(joint))
    print()
    print(format_score_table(score(survey, joint)))

    t0 = time.perf_counter()
    baseline = solve_subset_newton(survey, SubsetNewtonOptions(subset_size=SUBSET_SIZE, n_subsets=SUBSETS, seed=args.seed))
    baseline_s = time.perf_counter() - t0
    write_result(baseline.result, out / "result-subset-newton.json")
    failed = sum(baseline.failures.values())

    bound = cramer_rao_bound(survey)
    assert survey.truth is not None  # a simulated scenario
    truth = survey.truth.nodes
    ids = [n for n in survey.node_ids if n in baseline.result.nodes]
    joint_err = np.array([np.linalg.norm(joint.nodes[n].position - truth[n]) for n in survey.node_ids])
    base_err = np.array([np.linalg.norm(baseline.result.nodes[n].position - truth[n]) for n in ids])
    crlb_err = bound_error_draws([bound[n] for n in survey.node_ids], seed=args.seed)
    print()
    print(f"Compared on the same {len(survey.observations)} readings, metres at a {PAPER_BASELINE_METRES:g} m baseline:")
    print(comparison_table([
        ("joint factor graph (fgloc)", joint_err, score(survey, joint).anees, joint_s),
        (f"paper's subset Newton, k={SUBSET_SIZE}, T={SUBSETS} ({failed} subsets failed, "
         f"{len(ids)} nodes covered)", base_err, None, baseline_s),
        ("Cramér–Rao bound (what an efficient estimator shows on average)", crlb_err, None, None),
    ]))

    files = [out / "survey.json", out / "result.json", out / "result-subset-newton.json"]
    if recorder is not None:
        from fgloc.viz import camera_covariances_or_none, write_rrd

        write_rrd(out / "fgloc.rrd", joint, survey, recorder=recorder, subsets=subset_cloud(survey, baseline),
                  camera_covariances=camera_covariances_or_none(survey, joint))
        files.append(out / "fgloc.rrd")
    print()
    print("wrote " + ", ".join(str(f) for f in files))
    if recorder is not None:
        print(f"see it: .venv/bin/rerun {out / 'fgloc.rrd'}   (a viewer window; `fgloc view --help` for more)")
    return 0
