#!/usr/bin/env python3
"""Benchmark suite; same as ``fgloc bench``. Usage: scripts/bench.py [--quick] [--json out.json]."""

import sys

from fgloc.evaluate.bench import build_parser, run

if __name__ == "__main__":
    sys.exit(run(build_parser().parse_args()))
