#!/usr/bin/env python3
"""Benchmark suite; same as ``fgloc bench``. Usage: scripts/bench.py [--quick] [--json out.json]."""

import sys

from fgloc.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
