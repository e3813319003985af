#!/usr/bin/env python3
"""Time and peak memory of ``fgloc solve`` as the number of readings grows (issue 15, item 8).

The paper's scenario (2 cameras, ``--nodes`` nodes) is simulated with ``R`` repeats per
camera and node, i.e. ``2 x nodes x R`` readings, written to survey.json, and solved by
``fgloc solve`` in a child process; its wall time and peak resident memory (the child's
``ru_maxrss``) are printed per size. Memory must grow linearly in the readings: before
the fix, 40000 readings of one node built a (40000, 40000, 2) distance table (23.8 GiB)
in the consensus re-placement of flagged surveys.

    python scripts/bench_million.py                       # 10k, 100k and 1M readings
    python scripts/bench_million.py --repeats 100 1000    # chosen sizes

Measured (2 cores, OPENBLAS_NUM_THREADS=1, node-eliminated solve): 10k readings 0.6 s / 98 MiB,
100k 1.2 s / 214 MiB, 1M 19.0 s / 1562 MiB (docs/scaling.md).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, default=50)
    parser.add_argument("--repeats", type=int, nargs="+", default=[100, 1000, 10000])
    args = parser.parse_args()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    fgloc = [sys.executable, "-m", "fgloc"]
    print("| readings | solve wall s | peak RSS MiB |\n|---:|---:|---:|")
    with tempfile.TemporaryDirectory(prefix="fgloc-million-") as tmp:
        for r in args.repeats:
            survey, result = Path(tmp) / f"s{r}.json", Path(tmp) / f"r{r}.json"
            subprocess.run([*fgloc, "simulate", "-o", str(survey), "--nodes", str(args.nodes), "--repeats", str(r)],
                           check=True, stdout=subprocess.DEVNULL, env=env)
            # Each size in its own process tree, so that ru_maxrss is this solve's peak.
            code = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
                    f"subprocess.run({[*fgloc, 'solve', str(survey), '-o', str(result)]!r}, check=True, "
                    "stdout=subprocess.DEVNULL); "
                    "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
            out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env)
            wall, rss_kib = out.stdout.split()
            print(f"| {2 * args.nodes * r:,} | {float(wall):.1f} | {int(rss_kib) / 1024:.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
