"""``fgloc survey``: run a survey on a rig (or its simulated twin), resumable after a kill."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from fgloc.core.errors import FglocError

if TYPE_CHECKING:
    from tqdm import tqdm

    from fgloc.survey.live import LiveEstimate
    from fgloc.survey.runner import Progress


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
    p.add_argument("--identify", choices=("sequential", "coded"), default=None,
                   help="identify motes one lit LED at a time (sequential) or many per view by blink codes "
                        "(coded); overrides rig.json's identification (default there: sequential)")
    p.add_argument("--coded", action="append", default=[], metavar="KEY=VALUE",
                   help="a coded-survey lever, overriding rig.json's \"coded\" (repeatable): retry=continue|burst, "
                        "separate=zoom|radio, fallback=predicted|blobs, video=frames|fields, probe=on|off, pairs=on|off "
                        "(default first; --resume runs with the levers the journal recorded; docs/blink-codes.md)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (as fgloc -q survey, which also hides warnings)")
    p.set_defaults(run=run)


class _SurveyBar:
    """Survey progress as a tqdm bar on stderr: nodes done/total, observations, failures, time left.

    Created on the first report (a resumed survey starts at its nodes already done, so the
    rate and the time left count only this run's nodes)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.bar: tqdm | None = None

    def __call__(self, p: Progress) -> None:
        from fgloc.cli._output import progress_bar

        if self.bar is None:
            self.bar = progress_bar(self.enabled, total=p.nodes_total, initial=p.nodes_done, desc="survey",
                                    unit="node", leave=True)
        field = "" if p.field_s is None else f", field {p.field_s:.1f} s"
        self.bar.set_postfix_str(f"{p.observations} obs, {p.failures} failed{field}", refresh=False)
        self.bar.update(p.nodes_done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from fgloc.files.rig_config import load_rig
    from fgloc.survey.live import BatchEstimator, IncrementalEstimator, format_estimate
    from fgloc.survey.session import run_survey

    if args.live_every < 1:
        raise FglocError(f"--live-every must be >= 1, got {args.live_every}")
    levers = {}
    for item in args.coded:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            raise FglocError(f"--coded: expected KEY=VALUE, got {item!r}")
        levers[key.strip()] = value.strip()
    rig = load_rig(args.rig)
    progress = _SurveyBar(args.progress and not args.quiet)

    recording = None
    if args.rerun:
        import fgloc.viz as viz  # rerun only when asked

        recording = viz.open_recording(args.rerun)
        logger = viz.SurveyLogger(recording)

    def show(live: LiveEstimate) -> None:
        tqdm.write(format_estimate(live))  # above the bar, on stdout
        if recording is not None:
            logger.log_estimates(len(live.survey.observations), live.result, live.survey)

    try:
        survey, runner = run_survey(
            rig, args.output, simulate=args.simulate, resume=args.resume,
            estimator=None if args.no_live else (IncrementalEstimator() if args.estimator == "incremental"
                                                 else BatchEstimator()),
            live_every=args.live_every, on_estimate=show, on_progress=progress, identification=args.identify,
            coded_levers=levers,
        )
    finally:
        progress.close()
        if recording is not None:
            viz.close_recording(recording)
    s = runner.stats
    print(f"wrote {args.output}/survey.json: {len(survey.node_ids)} nodes, {len(survey.observations)} observations "
          f"({s.nodes_skipped} nodes already done, {s.not_found} not found, {s.led_failed} LED failures, "
          f"{s.head_errors} head errors, {s.reconnects} reconnects)")
    if runner.field_time is not None:
        print(f"predicted field time: {runner.field_time.describe()}")
    return 0
