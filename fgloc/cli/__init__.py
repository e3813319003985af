"""The ``fgloc`` command line: one module per command, registered in ``COMMANDS``.

Every user-facing failure is an :class:`fgloc.core.model.FglocError` (or an OS error
on a named file) and ends as one line on stderr with exit status 2 (bad input)
or 1 (I/O), never a traceback.

``-v`` / ``-vv`` / ``-q`` (before the command) set what the library's log records show
on stderr: WARNING by default, INFO, DEBUG, or ERROR only; ``-q`` also turns off the
progress bars (which are drawn only when stderr is a terminal anyway).
"""

from __future__ import annotations

import argparse
import os
import sys
from types import ModuleType

# Small dense solves are far faster single-threaded on these machines
# (shared/reference/measured-pitfalls.md); must be set before numpy loads.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from fgloc.cli import (  # noqa: E402
    _output,
    bench,
    calibrate,
    demo,
    head_check,
    motes,
    plan,
    ptz,
    report,
    score,
    simulate,
    solve,
    survey,
    view,
)
from fgloc.core.errors import FglocError  # noqa: E402
from fgloc.core.redact import redact_urls  # noqa: E402

COMMANDS: list[ModuleType] = [simulate, solve, score, demo, view, report, survey, calibrate, ptz, motes, bench, plan,
                               head_check]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fgloc",
        description="Localize sensor nodes and pan-tilt cameras from pan-tilt bearings.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, dest="log_verbose",
                        help="show more log lines on stderr: -v info, -vv debug")
    parser.add_argument("-q", "--quiet", action="store_true", dest="log_quiet",
                        help="only errors on stderr, no progress bars")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.progress = not args.log_quiet  # bars also need a terminal on stderr (tqdm's disable=None)
    with _output.logging_to_stderr(_output.level_for(args.log_verbose, args.log_quiet)):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the chosen command; every expected failure ends as one line on stderr."""
    try:
        return int(args.run(args) or 0)
    except FglocError as exc:
        print(f"fgloc: error: {redact_urls(str(exc))}", file=sys.stderr)  # never a URL's password
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(redact_urls(f"fgloc: error: {where}{exc.strerror or exc}"), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("fgloc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
