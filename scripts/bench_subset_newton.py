"""Benchmark the subset-Newton baseline: time per run by subset size, BLAS threads 1 vs default.

Each configuration runs in a fresh process (the BLAS thread count must be set
before numpy loads). Prints a Markdown table of median wall times over
``--repeats`` runs, measured side by side in one invocation.

    python scripts/bench_subset_newton.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
import numpy as np
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.baselines.subset_newton import solve_subset_newton
from fgloc.core.subsets import subsets_for_coverage
out = {}
for k in (5, 10, 20, 50):
    sv = paper_scenario(PaperScenario(seed=0, subset_schedule=(k, subsets_for_coverage(100, k, 5))))
    times = []
    for _ in range(int(sys.argv[1])):
        t = time.perf_counter(); solve_subset_newton(sv); times.append(time.perf_counter() - t)
    out[k] = float(np.median(times))
print(json.dumps(out))
"""


def run(threads: str | None, repeats: int) -> dict[str, float]:
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(var, None)
        if threads is not None:
            env[var] = threads
    res = subprocess.run([sys.executable, "-c", CHILD, str(repeats)], env=env, capture_output=True, text=True, check=True)
    return json.loads(res.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    one = run("1", args.repeats)
    default = run(None, args.repeats)
    print("| k | T | BLAS threads = 1 (s) | BLAS default (s) | default / 1 |")
    print("|---:|---:|---:|---:|---:|")
    for k in one:
        print(f"| {k} | {round(5 * 100 / int(k))} | {one[k]:.3f} | {default[k]:.3f} | {default[k] / one[k]:.2f} |")


if __name__ == "__main__":
    main()
