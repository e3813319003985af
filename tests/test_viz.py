"""fgloc.viz: what a person sees, checked by reading the .rrd back (no viewer needed)."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fgloc.viz as viz
from fgloc.cli import main
from fgloc.core.confidence import confidence_scale
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose, FlaggedObservation, NodeEstimate, NodeMode, Result
from fgloc.files.survey_result import write_result, write_survey
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey
from tests.rrd_reading import last_static, load_rrd, unpack_rgba

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def solved():
    """A 30-node paper scenario solved with an iteration recorder."""
    survey = paper_scenario(PaperScenario(n_nodes=30, seed=3))
    recorder = viz.IterationRecorder(survey)
    result = solve_survey(survey, on_iteration=recorder)
    return survey, result, recorder


@pytest.fixture(scope="module")
def flagged_rrd(solved, tmp_path_factory):
    """The solved scenario with one observation marked as an outlier, written to an .rrd."""
    survey, result, recorder = solved
    index = 7
    obs = survey.observations[index]
    flagged = dataclasses.replace(result, flagged=[FlaggedObservation(obs.camera, obs.node, index, 9.0)])
    rng = np.random.default_rng(0)
    positions = np.concatenate([np.asarray(flagged.nodes[n].position) + 1e-3 * rng.normal(size=(4, 3))
                                for n in survey.node_ids])
    node_index = np.repeat(np.arange(len(survey.node_ids)), 4)
    mean = np.array([flagged.nodes[n].position for n in survey.node_ids])
    path = tmp_path_factory.mktemp("rrd") / "scene.rrd"
    viz.write_rrd(path, flagged, survey, recorder=recorder, subsets=(survey.node_ids, positions, node_index, mean))
    return path, flagged, positions, node_index


def test_entity_paths(flagged_rrd, solved) -> None:
    survey = solved[0]
    entities = load_rrd(flagged_rrd[0])
    expected = {
        "world", "world/ground", "world/baseline", "world/nodes/estimate", "world/nodes/covariance",
        "world/nodes/truth", "world/nodes/error", "world/nodes/worst", "world/subset_newton/subsets",
        "world/subset_newton/mean", "world/solve/nodes", "world/solve/cameras", "optimizer/error",
        "report/worst_nodes",
    } | {f"world/cameras/{c}" for c in survey.camera_ids} | {f"world/cameras/{c}/frustum" for c in survey.camera_ids} \
        | {f"world/rays/{c}" for c in survey.camera_ids}
    assert expected <= set(entities)


def test_node_positions_labels_truth_and_error_segments(flagged_rrd, solved) -> None:
    survey, result, _ = solved
    e = load_rrd(flagged_rrd[0])
    est = np.array([result.nodes[n].position for n in survey.node_ids])
    np.testing.assert_allclose(last_static(e, "world/nodes/estimate", "Points3D:positions"), est, atol=1e-6)
    assert list(last_static(e, "world/nodes/estimate", "Points3D:labels")) == survey.node_ids
    truth = survey.truth_node_array()
    np.testing.assert_allclose(last_static(e, "world/nodes/truth", "Points3D:positions"), truth, atol=1e-6)
    seg = last_static(e, "world/nodes/error", "LineStrips3D:strips")
    np.testing.assert_allclose(seg[:, 0], est, atol=1e-6)
    np.testing.assert_allclose(seg[:, 1], truth, atol=1e-6)
    assert unpack_rgba(e["world/nodes/truth"].static["Points3D:colors"][-1])[0].tolist() != \
        unpack_rgba(e["world/nodes/estimate"].static["Points3D:colors"][-1])[0].tolist()


def test_planar_ellipse_half_sizes_match_the_covariance(flagged_rrd, solved) -> None:
    """Half sizes must be k sqrt(eig(C)) with k = sqrt(chi2_2(0.95)) and the ellipse flat in z:
    rebuilt from the stored half sizes and quaternions, R diag((h/k)^2) R^T must equal C."""
    survey, result, _ = solved
    e = load_rrd(flagged_rrd[0])
    hs = last_static(e, "world/nodes/covariance", "Ellipsoids3D:half_sizes")
    q = last_static(e, "world/nodes/covariance", "Ellipsoids3D:quaternions")
    centres = last_static(e, "world/nodes/covariance", "Ellipsoids3D:centers")
    k = confidence_scale(2, 0.95)
    assert k == pytest.approx(2.4477, abs=1e-4)
    for j, n in enumerate(survey.node_ids):
        C = result.nodes[n].covariance
        np.testing.assert_allclose(np.sort(hs[j, :2]), k * np.sqrt(np.linalg.eigvalsh(C)), rtol=1e-5)
        assert hs[j, 2] < 1e-3 * hs[j, :2].max()
        x, y, z, w = q[j]
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        rebuilt = R[:2, :2] @ np.diag((hs[j, :2] / k) ** 2) @ R[:2, :2].T
        np.testing.assert_allclose(rebuilt, C, rtol=1e-4, atol=1e-6 * np.abs(C).max())
        np.testing.assert_allclose(centres[j], result.nodes[n].position, atol=1e-6)


def test_3d_ellipsoids_use_the_3_dof_scale(tmp_path) -> None:
    """3x3 covariances: half sizes k sqrt(eig) with k = sqrt(chi2_3(0.95)) = 2.7955."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(6, 3, 3)) * 1e-2
    covs = A @ A.transpose(0, 2, 1)
    nodes = {f"n{j}": NodeEstimate(rng.normal(size=3), covs[j]) for j in range(6)}
    cams = {"c0": CameraPose(np.zeros(3), np.eye(3)), "c1": CameraPose(np.array([1.0, 0, 0]), np.eye(3))}
    path = viz.write_rrd(tmp_path / "r3.rrd", Result(NodeMode.THREE_D, nodes, cams))
    hs = last_static(load_rrd(path), "world/nodes/covariance", "Ellipsoids3D:half_sizes")
    for j in range(6):
        np.testing.assert_allclose(np.sort(hs[j]), 2.7955 * np.sqrt(np.linalg.eigvalsh(covs[j])), rtol=1e-4)


def test_iteration_steps_and_error_history(flagged_rrd, solved) -> None:
    survey, result, recorder = solved
    e = load_rrd(flagged_rrd[0])
    n_steps = len(result.stats.error_history)
    assert len(recorder.snapshots) == n_steps == result.stats.iterations + 1
    err = e["optimizer/error"].timed["iteration"]["Scalars:scalars"]
    assert [t for t, _ in err] == list(range(n_steps))
    np.testing.assert_allclose([v[0] for _, v in err], result.stats.error_history, rtol=1e-12)
    iterates = e["world/solve/nodes"].timed["iteration"]["Points3D:positions"]
    assert [t for t, _ in iterates] == list(range(n_steps))
    final = np.array([result.nodes[n].position for n in survey.node_ids])
    np.testing.assert_allclose(np.asarray(iterates[-1][1]), final, atol=1e-6)
    assert np.abs(np.asarray(iterates[0][1]) - final).max() > 1e-6  # the first iterate is the initial guess


def test_rays_follow_the_measured_bearings_and_outliers_are_red(flagged_rrd, solved) -> None:
    """Each ray starts at its camera and points along R b(pan, tilt); with 0.1 deg noise the
    estimated node lies within a few milliradians of its rays. Only the flagged ray is red."""
    survey, result, _ = solved
    path, flagged, _, _ = flagged_rrd
    e = load_rrd(path)
    bad = flagged.flagged[0]
    table = survey.observation_table
    for i, cid in enumerate(survey.camera_ids):
        strips = last_static(e, f"world/rays/{cid}", "LineStrips3D:strips")
        colours = unpack_rgba(e[f"world/rays/{cid}"].static["LineStrips3D:colors"][-1])
        obs_idx = np.flatnonzero(table.camera_index == i)
        assert strips.shape == (len(obs_idx), 2, 3)  # one batched call: every observation of the camera
        cam = result.cameras[cid]
        np.testing.assert_allclose(strips[:, 0], np.tile(cam.position, (len(obs_idx), 1)), atol=1e-6)
        d = strips[:, 1] - strips[:, 0]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        expected = pan_tilt_bearing(table.pan[obs_idx], table.tilt[obs_idx]) @ cam.rotation.T
        np.testing.assert_allclose(d, expected, atol=1e-6)
        to_node = np.array([result.nodes[survey.node_ids[j]].position for j in table.node_index[obs_idx]]) - cam.position
        miss = np.linalg.norm(np.cross(to_node, d), axis=1) / np.linalg.norm(to_node, axis=1)
        assert miss.max() < 5e-3
        red = (colours == [255, 0, 0, 255]).all(axis=1)
        assert red.tolist() == [bool(o == bad.index) for o in obs_idx]


def test_subset_cloud_is_coloured_by_node(flagged_rrd, solved) -> None:
    survey = solved[0]
    path, _, positions, node_index = flagged_rrd
    e = load_rrd(path)
    pts = last_static(e, "world/subset_newton/subsets", "Points3D:positions")
    np.testing.assert_allclose(pts, positions, atol=1e-6)
    colours = unpack_rgba(e["world/subset_newton/subsets"].static["Points3D:colors"][-1])
    for j in range(len(survey.node_ids)):
        assert len({tuple(c) for c in colours[node_index == j]}) == 1
    assert len({tuple(c) for c in colours}) == len(survey.node_ids)  # distinct colour per node
    assert list(last_static(e, "world/subset_newton/mean", "Points3D:labels")) == survey.node_ids


def test_camera_transform_and_frustum_along_pan_zero(flagged_rrd, solved) -> None:
    """Transform3D must carry (c, R) (mat3x3 is stored column-major) and the frustum must open along base +x."""
    survey, result, _ = solved
    e = load_rrd(flagged_rrd[0])
    for cid in survey.camera_ids:
        cam = result.cameras[cid]
        np.testing.assert_allclose(last_static(e, f"world/cameras/{cid}", "Transform3D:translation")[0],
                                   cam.position, atol=1e-6)
        R = last_static(e, f"world/cameras/{cid}", "Transform3D:mat3x3")[0].reshape(3, 3).T
        np.testing.assert_allclose(R, cam.rotation, atol=1e-6)
        assert list(last_static(e, f"world/cameras/{cid}", "Points3D:labels")) == [cid]
        frustum = e[f"world/cameras/{cid}/frustum"].static["LineStrips3D:strips"][-1]
        far = np.array(frustum[-1])[:4]  # the closed far rectangle repeats its first corner
        assert (far[:, 0] > 0).all() and np.allclose(far[:, 1:].mean(axis=0), 0.0)


def test_camera_pose_uncertainty_is_drawn_in_the_base_frame(tmp_path) -> None:
    cov = np.diag([1e-6, 2e-6, 3e-6, 4e-6, 1e-6, 9e-6])  # [omega, v]
    cams = {"c0": CameraPose(np.zeros(3), np.eye(3))}
    rec = viz.open_recording(tmp_path / "cam.rrd")
    viz.log_cameras(rec, cams, covariances={"c0": cov})
    viz.close_recording(rec)
    e = load_rrd(tmp_path / "cam.rrd")
    hs = last_static(e, "world/cameras/c0/position_covariance", "Ellipsoids3D:half_sizes")[0]
    np.testing.assert_allclose(np.sort(hs), confidence_scale(3) * np.sqrt([1e-6, 4e-6, 9e-6]), rtol=1e-5)
    assert "rot sigma" in last_static(e, "world/cameras/c0", "Points3D:labels")[0]


def test_live_survey_timeline(tmp_path, solved) -> None:
    survey, result, _ = solved
    rec = viz.open_recording(tmp_path / "live.rrd")
    live = viz.SurveyLogger(rec, survey)
    for step, obs in enumerate(survey.observations[:3]):
        live.log_observation(step, obs, result.cameras[obs.camera])
        live.log_estimates(step, result)
    viz.close_recording(rec)
    e = load_rrd(tmp_path / "live.rrd")
    assert [t for t, _ in e["survey/log"].timed["survey"]["TextLog:text"]] == [0, 1, 2]
    assert [t for t, _ in e["world/nodes/estimate"].timed["survey"]["Points3D:positions"]] == [0, 1, 2]
    assert [t for t, _ in e["world/survey/latest_ray"].timed["survey"]["LineStrips3D:strips"]] == [0, 1, 2]
    assert not e["world/nodes/estimate"].static  # live estimates are temporal, never static


def test_worst_nodes_are_ranked_by_true_error(solved) -> None:
    survey, result, _ = solved
    rows = viz.worst_nodes(result, survey, count=5)
    errors = {n: np.linalg.norm(result.nodes[n].position - survey.truth.nodes[n]) for n in survey.node_ids}
    assert [r.node for r in rows] == sorted(errors, key=errors.get, reverse=True)[:5]
    assert "| node |" in viz.worst_nodes_markdown(rows)


def test_cli_solve_and_view_write_recordings(tmp_path, solved, capsys) -> None:
    survey, result, _ = solved
    write_survey(survey, tmp_path / "survey.json")
    assert main(["solve", str(tmp_path / "survey.json"), "-o", str(tmp_path / "r.json"),
                 "--rerun", str(tmp_path / "s.rrd")]) == 0
    assert len(load_rrd(tmp_path / "s.rrd")["world/solve/nodes"].timed["iteration"]["Points3D:positions"]) > 1
    verify = subprocess.run([str(viz.viewer_binary()), "rrd", "verify", str(tmp_path / "s.rrd")],
                            capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr[-500:]  # complete file with footer, loads in Rerun
    write_result(result, tmp_path / "result.json")
    assert main(["view", str(tmp_path / "result.json"), "--survey", str(tmp_path / "survey.json"),
                 "--save", str(tmp_path / "v.rrd")]) == 0
    assert "world/rays/" + survey.camera_ids[0] in load_rrd(tmp_path / "v.rrd")
    assert "rerun" in capsys.readouterr().out


def test_cli_view_without_display_is_one_clear_line(tmp_path, solved, monkeypatch, capsys) -> None:
    write_result(solved[1], tmp_path / "result.json")
    monkeypatch.setattr(viz, "has_display", lambda: False)
    assert main(["view", str(tmp_path / "result.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "result.json" in err[0] and "--save" in err[0]


def test_only_viz_imports_rerun() -> None:
    """Architecture: rerun is confined to the fgloc/viz/ package (parsed imports, not grep)."""
    offenders = []
    for py in list((REPO / "fgloc").rglob("*.py")) + list((REPO / "factors").rglob("*.py")):
        if py.parent == REPO / "fgloc" / "viz":
            continue
        for node in ast.walk(ast.parse(py.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            if any(n.split(".")[0] in ("rerun", "rerun_cli") for n in names):
                offenders.append(str(py.relative_to(REPO)))
    assert offenders == []


def test_cli_and_solver_do_not_need_rerun() -> None:
    """Importing the CLI and solving must not load rerun (the viewer is optional)."""
    code = ("import sys, fgloc.cli, fgloc.solve.joint, fgloc.evaluate.score; "
            "assert 'rerun' not in sys.modules, 'rerun imported'")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)


def test_viewer_is_started_on_loopback_only(monkeypatch, tmp_path) -> None:
    """`fgloc view` must start the real viewer binary bound to 127.0.0.1 unless --bind says otherwise."""
    calls = []
    monkeypatch.setattr(viz.viewer.subprocess, "call", lambda cmd: calls.append(cmd) or 0)
    assert viz.view_rrd(tmp_path / "x.rrd") == 0
    cmd = calls[0]
    assert Path(cmd[0]) == viz.viewer_binary() and cmd[cmd.index("--bind") + 1] == "127.0.0.1"


def test_planar_subset_solutions_are_accepted_as_2d(tmp_path) -> None:
    """The baseline reports subset solutions as (P, 2) on z = 0: they must land on the plane unchanged."""
    rec = viz.open_recording(tmp_path / "s.rrd")
    viz.log_subset_solutions(rec, ["a", "b"], np.array([[0.1, 0.2], [0.3, 0.4], [0.5, 0.6]]), np.array([0, 0, 1]),
                             np.array([[0.2, 0.3], [np.nan, np.nan]]))
    viz.close_recording(rec)
    e = load_rrd(tmp_path / "s.rrd")
    np.testing.assert_allclose(last_static(e, "world/subset_newton/subsets", "Points3D:positions"),
                               [[0.1, 0.2, 0], [0.3, 0.4, 0], [0.5, 0.6, 0]], atol=1e-7)
    assert list(last_static(e, "world/subset_newton/mean", "Points3D:labels")) == ["a"]  # NaN mean skipped
    with pytest.raises(ValueError):
        viz.log_subset_solutions(rec, ["a"], np.zeros((3, 2)), np.zeros(2, dtype=int))


def test_unwritable_recording_is_one_line_error(tmp_path, solved, capsys) -> None:
    """An .rrd that cannot be created ends `solve --rerun` and `survey --rerun` with one line
    naming the file and exit 2 (rerun itself raises a RuntimeError with a traceback), and
    the survey stops before touching the rig."""
    from fgloc.cli import main

    survey, _, _ = solved
    write_survey(survey, tmp_path / "survey.json")
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    bad = blocker / "x.rrd"
    assert main(["solve", str(tmp_path / "survey.json"), "-o", str(tmp_path / "r.json"), "--rerun", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err and "cannot write the Rerun recording" in err
    rig = Path(__file__).resolve().parent.parent / "examples" / "rig-simulated.json"
    out = tmp_path / "survey-out"
    assert main(["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--quiet", "--rerun", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err
    assert not (out / "journal.jsonl").exists()
