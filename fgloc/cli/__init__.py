"""The ``fgloc`` command line: one module per command, registered in ``COMMANDS``.

Every user-facing failure is an :class:`fgloc.core.model.FglocError` (or an OS error
on a named file) and ends as one line on stderr with exit status 2 (bad input)
or 1 (I/O), never a traceback.
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

from fgloc.cli import bench, calibrate, demo, motes, ptz, report, score, simulate, solve, survey, view  # noqa: E402
from fgloc.core.errors import FglocError  # noqa: E402

COMMANDS: list[ModuleType] = [simulate, solve, score, demo, view, report, survey, calibrate, ptz, motes, bench]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fgloc",
        description="Localize sensor nodes and pan-tilt cameras from pan-tilt bearings.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except FglocError as exc:
        print(f"fgloc: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"fgloc: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("fgloc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
