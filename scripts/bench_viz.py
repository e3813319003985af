"""Benchmark of fgloc.viz: time and size of .rrd recordings (acceptance of issue 5).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/bench_viz.py

1. The paper's scenario (100 nodes, 2 cameras): joint solve with the iteration
   recorder, plus a subset-Newton baseline stand-in (50 subset solutions per node,
   scattered around the estimate; the real baseline gives arrays of the same shape).
   "beyond the solve" = writing the .rrd, measured cold (first write in this process,
   including `import rerun`) and warm (median of 5).
2. A 10,000-node result (synthetic estimates around the truth of a simulated
   survey, 20,000 rays, 10 recorded iterations): logging time, median of 3.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from fgloc.core.model import NodeEstimate, Result  # noqa: E402
from fgloc.sim.scenes import PaperScenario, paper_scenario  # noqa: E402
from fgloc.solve.joint import solve_survey  # noqa: E402


def subsets_stand_in(survey, result, per_node: int = 50):
    rng = np.random.default_rng(0)
    ids = [n for n in survey.node_ids if n in result.nodes]
    est = np.array([result.nodes[n].position for n in ids])
    positions = np.repeat(est, per_node, axis=0) + 3e-3 * rng.normal(size=(len(ids) * per_node, 3)) * [1, 1, 0]
    return ids, positions, np.repeat(np.arange(len(ids)), per_node), est


def main() -> int:
    tmp = Path(tempfile.mkdtemp(prefix="fgloc-bench-viz-"))
    rows: list[tuple[str, str, str]] = []

    survey = paper_scenario(PaperScenario(seed=0))
    solve_survey(survey)  # warm-up
    plain_times = []
    for _ in range(3):
        t0 = time.perf_counter()
        solve_survey(survey)
        plain_times.append(time.perf_counter() - t0)
    t_plain = statistics.median(plain_times)

    t0 = time.perf_counter()
    import fgloc.viz as viz  # cold: imports rerun

    t_import = time.perf_counter() - t0
    recorded_times = []
    for _ in range(3):
        recorder = viz.IterationRecorder(survey)
        t0 = time.perf_counter()
        result = solve_survey(survey, on_iteration=recorder)
        recorded_times.append(time.perf_counter() - t0)
    t_recorded = statistics.median(recorded_times)
    from fgloc.solve.camera_uncertainty import camera_covariances

    t0 = time.perf_counter()
    cam_cov = camera_covariances(survey, result)
    t_camcov = time.perf_counter() - t0
    subsets = subsets_stand_in(survey, result)
    t0 = time.perf_counter()
    path = viz.write_rrd(tmp / "paper.rrd", result, survey, recorder=recorder, subsets=subsets,
                         camera_covariances=cam_cov)
    t_cold = time.perf_counter() - t0
    warm = []
    for i in range(5):
        t0 = time.perf_counter()
        viz.write_rrd(tmp / f"paper{i}.rrd", result, survey, recorder=recorder, subsets=subsets,
                      camera_covariances=cam_cov)
        warm.append(time.perf_counter() - t0)
    size = path.stat().st_size
    rows += [
        ("paper: solve without recorder", f"{1000 * t_plain:.0f} ms", "median of 3, warm"),
        ("paper: solve with recorder", f"{1000 * t_recorded:.0f} ms",
         f"median of 3; {len(recorder.snapshots)} iterations recorded"),
        ("paper: camera pose covariances", f"{1000 * t_camcov:.0f} ms", "re-linearize + Marginals"),
        ("paper: import fgloc.viz (rerun)", f"{1000 * t_import:.0f} ms", "once per process"),
        ("paper: write .rrd, cold", f"{1000 * t_cold:.0f} ms", "first write incl. Rerun warm-up"),
        ("paper: write .rrd, warm", f"{1000 * statistics.median(warm):.0f} ms", "median of 5"),
        ("paper: .rrd size", f"{size / 1e6:.2f} MB", f"{len(subsets[1])} subset points"),
        ("paper: beyond the solve (import + recorder + camera cov + cold write)",
         f"{1000 * (t_import + max(t_recorded - t_plain, 0.0) + t_camcov + t_cold):.0f} ms", "acceptance < 1000 ms"),
    ]

    big = paper_scenario(PaperScenario(n_nodes=10_000, seed=1))
    rng = np.random.default_rng(2)
    truth = big.truth_node_array()
    nodes = {}
    for j, n in enumerate(big.node_ids):
        A = rng.normal(size=(2, 2)) * 2e-3
        nodes[n] = NodeEstimate(truth[j] + np.r_[2e-3 * rng.normal(size=2), 0.0], A @ A.T + 1e-8 * np.eye(2))
    big_result = Result(big.mode, nodes, dict(big.truth.cameras))
    big_rec = viz.IterationRecorder(big)
    for k in range(10):
        big_rec.snapshots.append(viz.IterationSnapshot(k, 10.0 ** (3 - k / 5),
                                                       np.array([c.position for c in big.truth.cameras.values()]),
                                                       truth + 1e-3 * (10 - k)))
    times = []
    for i in range(3):
        t0 = time.perf_counter()
        p = viz.write_rrd(tmp / f"big{i}.rrd", big_result, big, recorder=big_rec)
        times.append(time.perf_counter() - t0)
    rows += [
        ("10k nodes: write .rrd (nodes, ellipses, truth, 20k rays, 10 iterations)",
         f"{1000 * statistics.median(times):.0f} ms", "median of 3; acceptance < 3000 ms"),
        ("10k nodes: .rrd size", f"{p.stat().st_size / 1e6:.2f} MB", ""),
    ]

    width = max(len(r[0]) for r in rows)
    print(f"{'what':<{width}}  {'value':>10}  note")
    for what, value, note in rows:
        print(f"{what:<{width}}  {value:>10}  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
