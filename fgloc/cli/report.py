"""``fgloc report``: rerun the paper's simulated experiment and write a reproduction report."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report", help="reproduce the paper's experiment: subset-Newton baseline vs joint solve vs CRLB"
    )
    p.add_argument("-o", "--output", required=True, help="directory for report.md and the PNG figures")
    p.add_argument("--quick", action="store_true", help="small settings (seconds), as used by the tests")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds (default 6, or 1 with --quick)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from fgloc.cli._output import StepBar
    from fgloc.core.errors import FglocError
    from fgloc.evaluate.report import ReportConfig, run_experiment, write_report
    from fgloc.evaluate.report_figures import require_matplotlib

    require_matplotlib()
    config = ReportConfig.quick() if args.quick else ReportConfig()
    if args.seeds is not None:
        if args.seeds < 1:
            raise FglocError(f"report: --seeds must be >= 1, got {args.seeds}")
        config = replace(config, seeds=tuple(range(args.seeds)))
    with StepBar(args.progress, "report", unit="run") as bar:
        data = run_experiment(config, progress=bar)
    path = write_report(data, Path(args.output))
    print(f"wrote {path} ({len(data.runs)} runs in {data.seconds:.1f} s)")
    return 0
