"""``fgloc simulate``: write a simulated survey of the paper's scenario."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from fgloc.core.errors import FglocError

if TYPE_CHECKING:
    from fgloc.sim.scenes import PaperScenario


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a survey of the paper's scenario (with truth)")
    p.add_argument("-o", "--output", required=True, help="survey.json to write")
    p.add_argument("--nodes", type=int, default=100, help="number of nodes (default 100)")
    p.add_argument("--sigma-deg", type=float, default=0.1, help="pan and tilt noise in degrees (default 0.1)")
    p.add_argument(
        "--heights", type=float, nargs=2, default=(0.1, 0.1), metavar=("H0", "H1"),
        help="camera heights in baseline units (default 0.1 0.1)",
    )
    p.add_argument("--roll-pitch-deg", type=float, default=3.0, help="max random base roll/pitch in degrees")
    p.add_argument("--repeats", type=int, default=1, help="readings per camera and node (default 1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--subset-schedule", type=int, nargs=2, default=None, metavar=("K", "T"),
        help="re-measure per subset: T random subsets of K nodes, each read afresh (--repeats times) "
        "and tagged with its subset index (for fgloc solve --method subset-newton)",
    )
    p.add_argument(
        "--head-errors", metavar="SPEC", default=None,
        help="non-ideal heads: 'typical' (tilt index 0.3 deg, collimation/trunnion 0.2 deg, scales 0.5 %%, "
        "lever arm 0.0005, random signs), 'sampled' (drawn from the population those sizes are the 1-sigma of) "
        "or name=value,... (degrees, percent, baseline units); "
        "see docs/head-calibration.md",
    )
    p.add_argument(
        "--pan-range-deg", type=float, default=None, metavar="DEG",
        help="the heads turn only +-DEG (e.g. 170 for an EVI-D70, 100 for an EVI-D100): readings whose true "
        "mechanical pan lies beyond are left out (default: unlimited)",
    )
    p.set_defaults(run=run)


def scenario_from_args(args: argparse.Namespace) -> PaperScenario:
    import numpy as np

    from fgloc.cli._args import finite, integer
    from fgloc.sim.scenes import PaperScenario, paper_scenario

    finite("--sigma-deg", args.sigma_deg, above=0.0, at_most=90.0)
    for h in args.heights:
        finite("--heights", h, above=0.0)
    finite("--roll-pitch-deg", args.roll_pitch_deg, at_least=0.0, at_most=90.0)
    integer("--nodes", args.nodes, at_least=1)
    integer("--repeats", args.repeats, at_least=1)
    integer("--seed", args.seed, at_least=0)
    try:
        config = PaperScenario(
            n_nodes=args.nodes,
            sigma=float(np.deg2rad(args.sigma_deg)),
            heights=(args.heights[0], args.heights[1]),
            max_roll_pitch_deg=args.roll_pitch_deg,
            repeats=args.repeats,
            seed=args.seed,
            subset_schedule=None if args.subset_schedule is None else tuple(args.subset_schedule),
        )
        paper_scenario(PaperScenario(n_nodes=1, sigma=config.sigma, heights=config.heights, repeats=config.repeats))
        if config.subset_schedule is not None:
            k, t = config.subset_schedule
            if not 1 <= k <= config.n_nodes or t < 1:
                raise ValueError(f"--subset-schedule needs 1 <= K <= {config.n_nodes} and T >= 1, got {k} {t}")
    except ValueError as exc:
        raise FglocError(f"simulate: {exc}") from None
    return config


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fgloc.cli._args import finite
    from fgloc.files.survey_result import write_survey
    from fgloc.sim.head_errors import inject_head_errors, parse_head_errors
    from fgloc.sim.scenes import paper_scenario

    pan_range = None
    if args.pan_range_deg is not None:
        pan_range = float(np.deg2rad(finite("--pan-range-deg", args.pan_range_deg, above=0.0, at_most=180.0)))
    survey = paper_scenario(scenario_from_args(args))
    n_readings = len(survey.observations)
    heads = {} if args.head_errors is None else parse_head_errors(
        args.head_errors, survey.camera_ids, np.random.default_rng(args.seed + 1))
    if heads or pan_range is not None:
        survey = inject_head_errors(survey, heads, pan_range)
    if pan_range is not None:
        print(f"--pan-range-deg {args.pan_range_deg:g}: left out {n_readings - len(survey.observations)} "
              f"of {n_readings} readings beyond the pan range")
    write_survey(survey, args.output)
    print(f"wrote {args.output}: {len(survey.node_ids)} nodes, {len(survey.camera_ids)} cameras, "
          f"{len(survey.observations)} observations")
    return 0
