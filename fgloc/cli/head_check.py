"""``fgloc head-check``: re-read a few known motes with a rig and flag head drift (docs/survey.md)."""

from __future__ import annotations

import argparse

from fgloc.core.errors import FglocError

#: exit status when a camera's drift is flagged (2 stays "bad input")
DRIFT_EXIT = 4


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("head-check", help="re-read known motes with the rig and flag head drift against a result")
    p.add_argument("--rig", required=True, help="rig.json of the surveyed rig")
    p.add_argument("--result", required=True,
                   help="result.json of the survey (with its head_calibration block from --head-model auto|full)")
    p.add_argument("--motes", required=True, help="comma-separated ids of localized motes to re-read, e.g. n001,n007")
    p.add_argument("-o", "--output", required=True,
                   help="check directory (journal.jsonl, survey.json, head_check.json)")
    p.add_argument("--repeats", type=int, default=None, metavar="N",
                   help="readings per mote and camera (default: the rig's repeats)")
    p.add_argument("--alpha", type=float, default=1e-3,
                   help="bound on the drift test's false-alarm probability over the whole check (SPRT; default 0.001)")
    p.add_argument("--with-calibration-uncertainty", action="store_true",
                   help="add the calibration's marginal uncertainty to the test (conservative; docs/survey.md)")
    p.add_argument("--rerun", metavar="FILE.rrd",
                   help="also write a Rerun recording of the drift check and the calibrations (docs/head-calibration.md)")
    p.add_argument("--simulate", action="store_true", help="check the rig's simulated twin")
    p.add_argument("--resume", action="store_true", help="continue the check's journal in the directory")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fgloc.files.rig_config import load_rig
    from fgloc.survey.head_check import REPORT_NAME, run_head_check

    if not 0.0 < args.alpha < 1.0:
        raise FglocError(f"--alpha: must lie in (0, 1), got {args.alpha!r}")
    motes = [m.strip() for m in args.motes.split(",") if m.strip()]
    rig = load_rig(args.rig)
    report = run_head_check(rig, args.result, motes, args.output, simulate=args.simulate, resume=args.resume,
                            repeats=args.repeats, alpha=args.alpha,
                            calibration_uncertainty=args.with_calibration_uncertainty)
    print(report.summary())
    print(f"wrote {args.output}/{REPORT_NAME}")
    if args.rerun:
        from fgloc.survey.head_check import read_head_block
        from fgloc.viz import write_head_check_rrd  # rerun is imported only when asked for

        write_head_check_rrd(args.rerun, report.to_json(), read_head_block(args.result))
        print(f"wrote {args.rerun} (open it with `rerun {args.rerun}`)")
    return DRIFT_EXIT if report.drifted else 0
