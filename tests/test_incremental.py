"""IncrementalLocalizer (iSAM2) against the batch solve of the same readings.

Truth used: :func:`fgloc.solve.joint.solve_survey` on the complete survey
(itself checked against the reference factors in test_fast_solve.py). After
``refine()`` both minimize the same cost from a converged start, so positions
and marginal covariances must agree to numerical tolerance; before it the
iSAM2 estimate carries only the linearization error of node placement.
"""

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.incremental import IncrementalLocalizer, IncrementalParams
from fgloc.solve.joint import SolverOptions, solve_survey


def _feed_node_by_node(survey, loc, order=None):
    by_node = {}
    for o in survey.observations:
        by_node.setdefault(o.node, []).append(o)
    for nid in order or survey.node_ids:
        loc.add_observations(by_node[nid])


def _compare(result, batch):
    pos = max(
        np.abs(result.nodes[k].position - batch.nodes[k].position).max() / np.sqrt(np.trace(batch.nodes[k].covariance))
        for k in batch.nodes
    )
    cov = max(
        np.abs(result.nodes[k].covariance - batch.nodes[k].covariance).max() / np.abs(batch.nodes[k].covariance).max()
        for k in batch.nodes
    )
    return pos, cov


def _held_factors(loc) -> int:
    graph = loc._isam.getFactorsUnsafe()
    return sum(1 for i in range(graph.size()) if graph.at(i) is not None)


@pytest.mark.parametrize("active_nodes", [None, 8, 64])
def test_incremental_agrees_with_batch_after_all_readings(active_nodes) -> None:
    """None keeps all 120 nodes in iSAM2; 8 and 64 marginalize old nodes in rounds."""
    survey = scene_survey(BenchScene(120, 4, seed=1))
    loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma, IncrementalParams(active_nodes=active_nodes))
    _feed_node_by_node(survey, loc)
    batch = solve_survey(survey, SolverOptions(gauge_sigma=loc.gauge_sigma))
    live = loc.estimate()
    assert set(live.nodes) == set(batch.nodes)
    pos, cov = _compare(live, batch)
    assert pos < 0.5 and cov < 0.2  # live: linearization error only, a fraction of a sigma
    if active_nodes is None:
        # Every reading is in iSAM2 exactly once (plus the two gauge factors).
        assert _held_factors(loc) == len(survey.observations) + 2
    else:
        # iSAM2 holds only the newest nodes: their readings, the gauge pair and one summary.
        assert loc.active_node_count <= active_nodes
        held = sum(1 for o in survey.observations if o.node in loc._active)
        assert _held_factors(loc) == held + 2 + 1
    loc.refine()
    pos, cov = _compare(loc.estimate(), batch)
    assert pos < 1e-5 and cov < 1e-5


def test_late_reading_of_a_marginalized_node_brings_it_back() -> None:
    """Each node's second and later readings arrive 20 nodes after its first, when an
    8-node window has long marginalized it: the node becomes a variable again with its
    old conditional, and nothing is lost or counted twice (covariances would shrink)."""
    survey = scene_survey(BenchScene(90, 3, seed=5))
    by_node: dict[str, list] = {}
    for o in survey.observations:
        by_node.setdefault(o.node, []).append(o)
    loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma, IncrementalParams(active_nodes=8))
    ids = survey.node_ids
    for k in range(len(ids) + 20):
        if k < len(ids):
            loc.add_observations(by_node[ids[k]][:1])
        if k >= 20:
            loc.add_observations(by_node[ids[k - 20]][1:])
    assert loc.revived_nodes > 20
    batch = solve_survey(survey, SolverOptions(gauge_sigma=loc.gauge_sigma))
    live = loc.estimate()
    assert set(live.nodes) == set(batch.nodes)
    pos, cov = _compare(live, batch)
    assert pos < 0.5 and cov < 0.2
    loc.refine()
    pos, cov = _compare(loc.estimate(), batch)
    assert pos < 1e-5 and cov < 1e-5


def test_estimate_before_bootstrap_is_a_clear_error() -> None:
    survey = scene_survey(BenchScene(20, 2, seed=2))
    loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma)
    loc.add_observations(survey.observations[:3])
    assert not loc.bootstrapped
    with pytest.raises(FglocError, match="not enough readings"):
        loc.estimate()


def test_late_camera_joins_and_result_matches_batch() -> None:
    """Readings of cam2 arrive after everything else: it waits, then a re-bootstrap adds it."""
    survey = scene_survey(BenchScene(60, 3, seed=4))
    loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma)
    first = [o for o in survey.observations if o.camera != "cam2"]
    late = [o for o in survey.observations if o.camera == "cam2"]
    for o in first:
        loc.add_observations([o])
    assert "cam2" not in loc.estimate(covariances=False).cameras
    for o in late:
        loc.add_observations([o])
    assert "cam2" in loc.estimate(covariances=False).cameras
    loc.refine()
    pos, cov = _compare(loc.estimate(), solve_survey(survey, SolverOptions(gauge_sigma=loc.gauge_sigma)))
    assert pos < 1e-5 and cov < 1e-5


def test_unknown_camera_is_rejected() -> None:
    survey = scene_survey(BenchScene(20, 2, seed=2))
    loc = IncrementalLocalizer(["cam0", "cam1"], survey.gauge, survey.sigma)
    bad = survey.observations[0].__class__("camX", "n000", 0.0, 0.0)
    with pytest.raises(FglocError, match="camX"):
        loc.add_observations([bad])


@pytest.mark.slow  # ~3 s
def test_live_covariances_are_honest_over_monte_carlo() -> None:
    """Statistical truth: 40 seeded scenes of the paper's scenario (100 nodes, 2 cameras,
    heights 0.05-0.5), fed node by node through a 16-node window (so ~85 % of the nodes
    are stored conditionals), no refine. The live covariance must be honest: ANEES in
    [1.8, 2.2] (chi-square, 2 dof) and 93-97 % of nodes inside their 95 % ellipse. The
    camera term matters: the conditional covariance alone (cameras taken as exact) gives
    ANEES ~3.4 on the same data, and that is asserted to fail the band."""
    from fgloc.evaluate.score import CHI2_95, nees
    from fgloc.sim.scenes import PaperScenario, paper_scenario

    rng = np.random.default_rng(2024)
    nees_all, conditional_only = [], []
    for seed in range(40):
        heights = tuple(rng.uniform(0.05, 0.5, size=2))
        survey = paper_scenario(PaperScenario(seed=5000 + seed, heights=heights))
        loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma, IncrementalParams(active_nodes=16))
        _feed_node_by_node(survey, loc)
        live = loc.estimate()
        assert set(live.nodes) == set(survey.node_ids)
        err = np.array([live.nodes[n].position[:2] - survey.truth.nodes[n][:2] for n in survey.node_ids])
        cov = np.array([live.nodes[n].covariance for n in survey.node_ids])
        nees_all.extend(nees(err, cov))
        stored = loc._marginalized.node_ids()
        err_stored = np.array([live.nodes[n].position[:2] - survey.truth.nodes[n][:2] for n in stored])
        c6 = 6 * len(survey.camera_ids)
        conditional_only.extend(nees(err_stored, loc._marginalized.covariances(np.zeros((c6, c6)))))
    nees_all = np.array(nees_all)
    assert 1.8 <= nees_all.mean() <= 2.2, nees_all.mean()
    assert 0.93 <= np.mean(nees_all <= CHI2_95[2]) <= 0.97
    assert np.mean(conditional_only) > 2.6


def test_stress_script_scenes_stay_close_to_batch(capsys) -> None:
    """scripts/stress_incremental.py on 3 random scenes (random node order, late readings that
    bring marginalized nodes back, random windows): every scene within 0.5 sigma and 20 %."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "scripts" / "stress_incremental.py"
    spec = importlib.util.spec_from_file_location("stress_incremental", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--scenes", "3", "--seed", "1"]) == 0
    assert "3 of 3 scenes within" in capsys.readouterr().out
