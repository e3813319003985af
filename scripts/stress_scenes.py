"""Stress the joint solve on random scenes and check it reaches the global optimum.

Each scene: 2-8 cameras at heights 0.05-1.0 of the field, random yaw, some
hanging upside down, 20-400 nodes, random occlusions, sigma 0.1 degree. The
solve from fgloc's own closed-form start must end at the cost of a solve started
from the truth (a local minimum would end higher).

    python scripts/stress_scenes.py --mode planar --scenes 200
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from fgloc.core.model import NodeMode, Survey  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.scenes import RandomScene, random_scene  # noqa: E402
from fgloc.solve.joint import build_problem, solve, solve_survey  # noqa: E402


def scene(index: int, mode: NodeMode, outlier_share: float = 0.0) -> Survey:
    """The index-th stress scene (deterministic)."""
    rng = np.random.default_rng(index)
    return random_scene(
        RandomScene(
            n_cameras=int(rng.integers(2, 9)),
            n_nodes=int(rng.integers(20, 401)),
            mode=mode,
            visibility=float(rng.uniform(0.5, 1.0)),
            seed=index,
        )
    )


def reaches_global_optimum(survey: Survey, rel_tol: float = 1e-6) -> tuple[bool, float, float]:
    """(ok, our final error, final error from the truth)."""
    ours = solve_survey(survey)
    truth = survey.truth
    start = InitialEstimate(cameras=dict(truth.cameras), nodes={n: truth.nodes[n] for n in ours.nodes})
    ref = solve(build_problem(survey, start))
    ok = ours.stats.final_error <= ref.stats.final_error * (1 + rel_tol) + 1e-6
    return ok, ours.stats.final_error, ref.stats.final_error


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=["planar", "3d"], default="planar")
    parser.add_argument("--scenes", type=int, default=200)
    args = parser.parse_args()
    mode = NodeMode(args.mode)
    failures = 0
    t0 = time.perf_counter()
    for k in range(args.scenes):
        ok, ours, ref = reaches_global_optimum(scene(k, mode))
        if not ok:
            failures += 1
            print(f"scene {k}: final error {ours:.6g} > {ref:.6g} from truth")
    print(f"{args.scenes - failures} of {args.scenes} {mode.value} scenes reached the global optimum "
          f"({time.perf_counter() - t0:.1f} s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
