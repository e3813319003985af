"""``fgloc demo``: the main job. Simulate the paper's scenario, solve it, score it, write it out."""

from __future__ import annotations

import argparse
from pathlib import Path

from fgloc.cli.solve import describe
from fgloc.files import write_result, write_survey
from fgloc.joint_solver import solve_survey
from fgloc.scoring import format_score_table, score
from fgloc.simulate import PaperScenario, paper_scenario


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate the paper's scenario, solve, score and write the files")
    p.add_argument("-o", "--out-dir", default="out", help="directory for the files (default out/)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out_dir)
    survey = paper_scenario(PaperScenario(seed=args.seed))
    write_survey(survey, out / "survey.json")
    print(f"simulated the paper's scenario: {len(survey.node_ids)} nodes, 2 cameras, sigma 0.1 deg, seed {args.seed}")
    from fgloc.viz import IterationRecorder, camera_covariances_or_none, write_rrd  # keeps `import fgloc.cli` free of rerun

    recorder = IterationRecorder(survey)
    result = solve_survey(survey, on_iteration=recorder)
    write_result(result, out / "result.json")
    write_rrd(out / "fgloc.rrd", result, survey, recorder=recorder,
              camera_covariances=camera_covariances_or_none(survey, result))
    print(describe(result))
    print()
    print(format_score_table(score(survey, result)))
    print()
    print(f"wrote {out / 'survey.json'}, {out / 'result.json'} and {out / 'fgloc.rrd'}")
    print(f"see it: rerun {out / 'fgloc.rrd'}   (or .venv/bin/rerun {out / 'fgloc.rrd'})")
    return 0
