"""``fgloc bench``: the benchmark suite (see :mod:`fgloc.evaluate.bench`)."""

from __future__ import annotations

import argparse

from fgloc.evaluate import bench


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmark the solver against GTSAM's C++ factors and scipy")
    bench.build_parser(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    return bench.run(args)
