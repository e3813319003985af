"""The benchmark suite's scenes, its noise equivalence and its output (structure and consistency, never timing)."""

import json
import subprocess
import sys

import gtsam
import numpy as np
import pytest

import fgloc  # noqa: F401  (first: importing factors.* before fgloc is circular on main)
from fgloc.core.geometry import pan_tilt_bearing, project_pan_tilt
from fgloc.evaluate.bench_methods import bearing_noise
from fgloc.factors.pan_tilt_factor import pan_tilt_factor
from fgloc.sim.bench_scenes import BenchScene, scene_survey


def test_scene_occlusions_and_coverage() -> None:
    scene = BenchScene(300, 8, seed=3)
    survey = scene_survey(scene)
    t = survey.observation_table
    views = np.bincount(t.node_index, minlength=len(survey.node_ids))
    assert views.min() >= 2
    assert 4.0 < len(t) / len(survey.node_ids) < 6.0  # ~5 views per node with 8 cameras
    truth = survey.truth_node_array()
    for i, cid in enumerate(survey.camera_ids):
        cam = survey.truth.cameras[cid]
        assert 0.05 <= cam.position[2] <= 1.0
        seen = truth[t.node_index[t.camera_index == i]]
        assert np.all(np.linalg.norm(seen[:, :2] - cam.position[:2], axis=1) > scene.blind_radius)


def test_bearing_noise_is_first_order_equivalent_to_pan_tilt_noise() -> None:
    """Truth: for a small displacement of the node, the whitened errors of the C++
    BearingFactor3D with the mapped noise and of the pan-tilt factor agree to first order."""
    rng = np.random.default_rng(0)
    C, L = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L
    sigma = np.deg2rad(0.1)
    for _ in range(20):
        R = gtsam.Rot3.Expmap(rng.normal(size=3) * 0.5)
        c = rng.normal(size=3)
        x = c + R.matrix() @ (pan_tilt_bearing(rng.uniform(-3, 3), rng.uniform(-1.2, 1.2)) * rng.uniform(0.5, 2.0))
        pan, tilt = project_pan_tilt(R.matrix(), c, x[None])
        pan, tilt = float(pan[0]), float(tilt[0])
        u = gtsam.Unit3(pan_tilt_bearing(pan, tilt))
        cpp = gtsam.BearingFactor3D(C(0), L(0), u, bearing_noise(pan, tilt, sigma, u))
        ref = pan_tilt_factor(C(0), L(0), pan, tilt, sigma)
        v = gtsam.Values()
        v.insert(C(0), gtsam.Pose3(R, c))
        direction = rng.normal(size=3)
        for scale, tol in ((3.0, 0.03), (0.03, 3e-4)):  # relative gap shrinks with the step: first order
            step = direction * scale * sigma * np.linalg.norm(x - c)
            if v.exists(L(0)):
                v.erase(L(0))
            v.insert(L(0), x + step)
            e_cpp, e_ref = cpp.error(v), ref.error(v)
            assert abs(e_cpp - e_ref) <= tol * e_ref + 1e-12


@pytest.mark.slow  # ~15 s: six subprocess workers (the suite isolates each for peak memory)
def test_quick_bench_output_is_consistent(tmp_path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, "-m", "fgloc", "bench", "--quick", "--json", str(out)], capture_output=True, text=True, timeout=240
    )
    assert proc.returncode == 0, proc.stderr
    assert "| scene (nodes x cams) |" in proc.stdout
    report = json.loads(out.read_text())
    rows = report["results"]
    by = {(r["n_nodes"], r["n_cameras"], r["method"]): r for r in rows}
    for n, c in [(40, 2), (80, 2), (60, 4)]:
        f = by[(n, c, "fgloc")]
        assert set(f["stage_median_s"]) == {"build", "initialize", "optimize", "marginals", "other"}
        assert f["iterations"] >= 1 and f["peak_rss_mb"] > 0
        cpp = by[(n, c, "gtsam_cpp")]
        # First-order equivalent model: same optimum to a small fraction of a node sigma (~1e-3 here).
        assert cpp["max_position_diff_vs_fgloc"] < 2e-4
        assert abs(cpp["final_cost"] - f["final_cost"]) < 1e-3 * f["final_cost"]
        assert 1 <= cpp["iterations"] <= 10  # the plain pipeline: a handful of iterations from the start
        # The speed-limit row minimizes the same pan-tilt cost: the same optimum.
        npy, ref = by[(n, c, "numpy_schur")], by[(n, c, "fgloc_reference")]
        assert abs(npy["final_cost"] - f["final_cost"]) <= 1e-9 * f["final_cost"]
        assert abs(ref["final_cost"] - f["final_cost"]) <= 1e-9 * f["final_cost"]
        assert npy["max_position_diff_vs_fgloc"] < 1e-7 and f["solve_median_s"] < f["total_median_s"]
    for n in (40, 80):  # scipy runs up to 80 nodes in --quick
        s, f = by[(n, 2, "scipy")], by[(n, 2, "fgloc")]
        assert abs(s["final_cost"] - f["final_cost"]) <= 1e-6 * f["final_cost"]
        assert s["max_position_diff_vs_fgloc"] < 1e-6
    assert not by[(40, 2, "subset_newton")]["available"] or by[(40, 2, "subset_newton")]["final_cost"] is not None
    assert "2 cameras" in report["slopes"] and "optimize" in report["slopes"]["2 cameras"]
    inc = report["incremental"]
    assert [(r["active_nodes"], r["batch_nodes"]) for r in inc] == [(64, 1), (None, 1)]
    assert all(0 < r["update_median_s"] <= r["update_max_s"] for r in inc)
