"""IncrementalLocalizer (iSAM2) against the batch solve of the same readings.

Truth used: :func:`fgloc.joint_solver.solve_survey` on the complete survey
(itself checked against the reference factors in test_fast_solve.py). After
``refine()`` both minimize the same cost from a converged start, so positions
and marginal covariances must agree to numerical tolerance; before it the
iSAM2 estimate carries only the linearization error of node placement.
"""

import numpy as np
import pytest

from fgloc.bench_scenes import BenchScene, scene_survey
from fgloc.incremental import IncrementalLocalizer
from fgloc.joint_solver import SolverOptions, solve_survey
from fgloc.model import FglocError


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


def test_incremental_agrees_with_batch_after_all_readings() -> None:
    survey = scene_survey(BenchScene(120, 4, seed=1))
    loc = IncrementalLocalizer(survey.camera_ids, survey.gauge, survey.sigma)
    _feed_node_by_node(survey, loc)
    batch = solve_survey(survey, SolverOptions(gauge_sigma=loc.gauge_sigma))
    live = loc.estimate()
    assert set(live.nodes) == set(batch.nodes)
    pos, cov = _compare(live, batch)
    assert pos < 0.5 and cov < 0.2  # live: linearization error only, a fraction of a sigma
    loc.refine()
    pos, cov = _compare(loc.estimate(), batch)
    assert pos < 1e-5 and cov < 1e-5
    # Every reading is in iSAM2 exactly once (plus the two gauge factors).
    assert loc._isam.getFactorsUnsafe().size() == len(survey.observations) + 2


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
