#!/usr/bin/env python3
"""Run a survey live (or against the simulated twin) and watch the estimates converge.

An example to start from, written only against fgloc's public API:

    python scripts/live_survey.py --rig examples/rig-simulated.json -o my-survey --simulate
    python scripts/live_survey.py --rig rig.json -o my-survey --resume      # after a crash

Everything is journaled to my-survey/journal.jsonl as it happens; kill it at any
moment and rerun with --resume. The per-node callbacks below are where to hook
your own display; ``--rerun FILE.rrd`` logs every live estimate on the ``survey``
timeline with ``fgloc.viz.SurveyLogger`` (open the file with ``rerun FILE.rrd``).
"""

from __future__ import annotations

import argparse
import logging
import sys

from fgloc.core.errors import FglocError
from fgloc.files.rig_config import load_rig
from fgloc.survey.live import BatchEstimator, IncrementalEstimator, LiveEstimate, format_estimate
from fgloc.survey.runner import Progress, format_progress
from fgloc.survey.session import run_survey


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rig", required=True)
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--simulate", action="store_true")
    p.add_argument("--resume", action="store_true")
    p.add_argument("--every", type=int, default=5, help="show estimates after every N nodes (default 5)")
    p.add_argument("--batch", action="store_true",
                   help="re-solve everything for each estimate instead of updating iSAM2 with the new readings")
    p.add_argument("--rerun", metavar="FILE.rrd", help="log live estimates to a Rerun recording (fgloc.viz)")
    args = p.parse_args(argv)
    # fgloc logs what goes wrong (LED and camera failures, failed live estimates) on the "fgloc" logger.
    logging.basicConfig(level=logging.WARNING, format="live_survey: %(message)s", stream=sys.stderr)

    hooks = []
    recording = None
    if args.rerun:
        try:
            import fgloc.viz as viz
        except ImportError:
            print("live_survey: --rerun needs fgloc.viz, not in this build", file=sys.stderr)
            return 2
        recording = viz.open_recording(args.rerun)
        logger = viz.SurveyLogger(recording)
        hooks.append(lambda live: logger.log_estimates(len(live.survey.observations), live.result, live.survey))

    def on_estimate(live: LiveEstimate) -> None:
        print(format_estimate(live, limit=3), flush=True)
        for hook in hooks:
            hook(live)

    def on_progress(progress: Progress) -> None:
        print(format_progress(progress), file=sys.stderr, flush=True)

    try:
        rig = load_rig(args.rig)
        survey, runner = run_survey(rig, args.output, simulate=args.simulate, resume=args.resume,
                                    estimator=BatchEstimator() if args.batch else IncrementalEstimator(), live_every=args.every,
                                    on_estimate=on_estimate, on_progress=on_progress)
    except FglocError as exc:
        print(f"live_survey: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if recording is not None:
            viz.close_recording(recording)
    print(f"survey complete: {len(survey.observations)} observations of {len(survey.node_ids)} nodes "
          f"-> {args.output}/survey.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
