"""Degenerate input: a clear one-line error or a documented, finite behaviour, never NaN."""

import json
from pathlib import Path

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.model import CameraPose, NodeMode, Survey
from fgloc.files.survey_result import write_survey
from fgloc.init.homography import DegenerateGeometryError
from fgloc.sim.scenes import (
    PAPER_SIGMA,
    PaperScenario,
    RandomScene,
    observe,
    paper_scenario,
    random_scene,
    simulated_survey,
)
from fgloc.solve.joint import SolveError, solve_survey


def survey_of(cameras: list[CameraPose], nodes: np.ndarray, mode=NodeMode.PLANAR, seed=0, sigma=PAPER_SIGMA):
    ids = [f"cam{i}" for i in range(len(cameras))]
    node_ids = [f"n{j:03d}" for j in range(len(nodes))]
    obs = observe(ids, cameras, node_ids, nodes, sigma, np.random.default_rng(seed))
    return simulated_survey(mode, sigma, ids, cameras, node_ids, nodes, obs)


def finite(result) -> bool:
    return all(np.all(np.isfinite(e.position)) and np.all(np.isfinite(e.covariance)) for e in result.nodes.values())


def test_too_few_planar_nodes_is_one_line_on_the_cli(tmp_path: Path, capsys) -> None:
    path = tmp_path / "s.json"
    write_survey(paper_scenario(PaperScenario(n_nodes=3)), path)
    assert main(["solve", str(path), "-o", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "share 4 nodes" in err and "cam0" in err


def test_too_few_3d_nodes() -> None:
    survey = random_scene(RandomScene(n_cameras=2, n_nodes=7, mode=NodeMode.THREE_D, visibility=1.0))
    with pytest.raises(DegenerateGeometryError, match="share 8 nodes"):
        solve_survey(survey)


def test_collinear_nodes_are_refused() -> None:
    base = paper_scenario(PaperScenario(n_nodes=2, seed=1))
    t = np.linspace(0.05, 0.95, 30)
    nodes = np.column_stack([t, 0.2 + 0.6 * t, np.zeros_like(t)])
    survey = survey_of([base.truth.cameras["cam0"], base.truth.cameras["cam1"]], nodes)
    with pytest.raises(DegenerateGeometryError, match="collinear"):
        solve_survey(survey)


def test_coplanar_nodes_in_3d_mode_are_refused() -> None:
    base = paper_scenario(PaperScenario(n_nodes=40, seed=2))
    survey = survey_of([base.truth.cameras["cam0"], base.truth.cameras["cam1"]],
                       base.truth_node_array(), mode=NodeMode.THREE_D)
    with pytest.raises(DegenerateGeometryError, match="coplanar"):
        solve_survey(survey)


def test_disconnected_cameras_are_named() -> None:
    """cam2 shares no node with cam0/cam1: the error names it."""
    base = paper_scenario(PaperScenario(n_nodes=2, seed=3))
    rng = np.random.default_rng(0)
    nodes = np.column_stack([rng.uniform(0, 1, (40, 2)), np.zeros(40)])
    cams = [base.truth.cameras["cam0"], base.truth.cameras["cam1"], CameraPose(np.array([0.5, 2.0, 0.3]), np.eye(3))]
    visible = np.ones((3, 40), dtype=bool)
    visible[2, :] = False
    visible[2, :3] = True
    ids, node_ids = ["cam0", "cam1", "cam2"], [f"n{j:03d}" for j in range(40)]
    from fgloc.core.model import Gauge
    obs = observe(ids, cams, node_ids, nodes, PAPER_SIGMA, rng, visible=visible)
    survey = Survey(NodeMode.PLANAR, Gauge("cam0", "cam1"), PAPER_SIGMA, ids, node_ids, obs)
    with pytest.raises(DegenerateGeometryError, match="cam2"):
        solve_survey(survey)


def test_node_straight_below_a_camera_is_localized() -> None:
    """Pan is undefined at the pole (the reading's pan is arbitrary): the solve stays
    finite and places the node correctly from tilt and the other camera."""
    base = paper_scenario(PaperScenario(n_nodes=30, seed=4, heights=(0.2, 0.15)))
    nodes = base.truth_node_array()
    nodes[0] = [0.0, 0.0, 0.0]  # exactly below cam0
    nodes[1] = [1.0, 1e-4, 0.0]  # almost below cam1
    survey = survey_of([base.truth.cameras["cam0"], base.truth.cameras["cam1"]], nodes, seed=4)
    result = solve_survey(survey)
    assert finite(result)
    for j in (0, 1):
        n = survey.node_ids[j]
        assert n in result.nodes
        assert np.linalg.norm(result.nodes[n].position - nodes[j]) < 0.01


def test_camera_at_a_node_position_gives_finite_result() -> None:
    """3d: a node at a camera's own position has no bearing from it (the simulator reports
    pan = tilt = 0). Either that reading is flagged and the rest stays finite, or the
    solve stops with one line naming the node: never NaN."""
    survey = random_scene(RandomScene(n_cameras=4, n_nodes=40, mode=NodeMode.THREE_D, visibility=1.0, seed=5))
    cams = [survey.truth.cameras[c] for c in survey.camera_ids]
    nodes = survey.truth_node_array()
    nodes[0] = cams[2].position
    s2 = survey_of(cams, nodes, mode=NodeMode.THREE_D, seed=5)
    try:
        result = solve_survey(s2)
    except SolveError as exc:  # documented alternative: a clear error naming the node
        assert "node n000" in str(exc) and "\n" not in str(exc)
        return
    assert finite(result)
    assert any(f.camera == "cam2" and f.node == s2.node_ids[0] for f in result.flagged)


def test_bad_input_json_for_degenerate_gauge(tmp_path: Path, capsys) -> None:
    """Gauge cameras standing on the same vertical give a clear error, not NaN."""
    base = paper_scenario(PaperScenario(n_nodes=30, seed=6))
    cams = [base.truth.cameras["cam0"], CameraPose(np.array([0.0, 0.0, 0.5]), base.truth.cameras["cam1"].rotation)]
    survey = survey_of(cams, base.truth_node_array())
    path = tmp_path / "s.json"
    write_survey(survey, path)
    rc = main(["solve", str(path), "-o", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "vertical" in err
    assert json.loads(path.read_text())["format"] == "fgloc-survey"


# ---- degenerate readings end in an FglocError naming what is degenerate (issue 15) --------


@pytest.mark.parametrize("mode", ["planar", "3d"])
@pytest.mark.parametrize("kind", ["all_equal", "random", "one_node_repeated"])
def test_degenerate_readings_are_fglocerrors(mode, kind) -> None:
    """Whatever the readings, a solve ends in a result or an FglocError, never a bare ValueError."""
    from dataclasses import replace as _replace

    from fgloc.core.errors import FglocError
    from fgloc.core.model import NodeMode
    from fgloc.sim.scenes import RandomScene, random_scene
    from fgloc.solve.joint import solve_survey

    survey = random_scene(RandomScene(n_cameras=3, n_nodes=12, mode=NodeMode(mode), seed=7))
    rng = np.random.default_rng(1)
    if kind == "all_equal":
        obs = [_replace(o, pan=0.3, tilt=-0.4) for o in survey.observations]
    elif kind == "random":
        obs = [_replace(o, pan=float(rng.uniform(-3, 3)), tilt=float(rng.uniform(-1.5, 1.5)))
               for o in survey.observations]
    else:
        obs = [_replace(o, node=survey.node_ids[0]) for o in survey.observations]
    try:
        solve_survey(_replace(survey, observations=obs))
    except FglocError as exc:
        assert str(exc) and "\n" not in str(exc)


def test_ransac_without_consensus_names_what_it_fitted() -> None:
    from fgloc.init.homography import DegenerateGeometryError
    from fgloc.init.ransac import ransac

    with pytest.raises(DegenerateGeometryError, match="homography of cam0 and cam1: no 4 of the 10 agree"):
        ransac(10, 4, lambda idx: 0, lambda m: np.ones(10), threshold=0.1, rng=np.random.default_rng(0),
               what="homography of cam0 and cam1")
    with pytest.raises(DegenerateGeometryError, match="at least 4 needed"):
        ransac(3, 4, lambda idx: 0, lambda m: np.zeros(3), threshold=0.1, rng=np.random.default_rng(0))
