"""``fgloc survey``: run a survey on a rig (or its simulated twin), resumable after a kill."""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from fgloc.core.errors import FglocError

if TYPE_CHECKING:
    from fgloc.survey.runner import LiveEstimate, Progress


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("survey", help="run a survey: light each node, let every camera measure it")
    p.add_argument("--rig", required=True, help="rig.json describing cameras, motes and nodes")
    p.add_argument("-o", "--output", required=True, help="survey directory (journal.jsonl, survey.json)")
    p.add_argument("--simulate", action="store_true", help="run against the simulated twin of the rig")
    p.add_argument("--resume", action="store_true", help="continue the journal in the survey directory")
    p.add_argument("--live-every", type=int, default=1, metavar="N",
                   help="solve and print estimates after every N nodes (default 1)")
    p.add_argument("--no-live", action="store_true", help="no live estimates")
    p.add_argument("--estimator", choices=("batch", "incremental"), default="incremental",
                   help="live estimates from iSAM2 (incremental, default: each reading once, ~1 ms per node "
                        "at any survey size) or by re-solving everything (batch)")
    p.add_argument("--rerun", metavar="FILE.rrd",
                   help="log every live estimate to a Rerun recording on the 'survey' timeline")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


class _ProgressLine:
    """Rewrites one stderr line (a bar) when stderr is a terminal, else prints every 10%."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.last_decile = -1
        self.last_time = 0.0

    def __call__(self, p: Progress) -> None:
        if not self.enabled:
            return
        from fgloc.survey.runner import format_progress

        line = format_progress(p)
        if self.tty:
            now = time.monotonic()
            if now - self.last_time > 0.1 or p.nodes_done == p.nodes_total:
                print("\r" + line, end="\n" if p.nodes_done == p.nodes_total else "", file=sys.stderr, flush=True)
                self.last_time = now
        else:
            decile = (10 * p.nodes_done) // max(p.nodes_total, 1)
            if decile != self.last_decile:
                print(line, file=sys.stderr, flush=True)
                self.last_decile = decile


def run(args: argparse.Namespace) -> int:
    from fgloc.files.rig_config import load_rig
    from fgloc.survey.runner import (
        BatchEstimator,
        IncrementalEstimator,
        format_estimate,
    )
    from fgloc.survey.session import run_survey

    if args.live_every < 1:
        raise FglocError(f"--live-every must be >= 1, got {args.live_every}")
    rig = load_rig(args.rig)
    progress = _ProgressLine(not args.quiet)

    def log(message: str) -> None:
        print(("\n" if progress.tty and progress.enabled else "") + f"fgloc: {message}", file=sys.stderr, flush=True)

    recording = None
    if args.rerun:
        import fgloc.viz as viz  # rerun only when asked

        recording = viz.open_recording(args.rerun)
        logger = viz.SurveyLogger(recording)

    def show(live: LiveEstimate) -> None:
        print(format_estimate(live), flush=True)
        if recording is not None:
            logger.log_estimates(len(live.survey.observations), live.result, live.survey)

    try:
        survey, runner = run_survey(
            rig, args.output, simulate=args.simulate, resume=args.resume,
            estimator=None if args.no_live else (IncrementalEstimator() if args.estimator == "incremental"
                                                 else BatchEstimator()),
            live_every=args.live_every, on_estimate=show, on_progress=progress, log=log,
        )
    finally:
        if recording is not None:
            viz.close_recording(recording)
    s = runner.stats
    print(f"wrote {args.output}/survey.json: {len(survey.node_ids)} nodes, {len(survey.observations)} observations "
          f"({s.nodes_skipped} nodes already done, {s.not_found} not found, {s.led_failed} LED failures, "
          f"{s.head_errors} head errors, {s.reconnects} reconnects)")
    return 0
