"""Extra camera-side variables in the node-eliminated fast path: view offsets and head vectors.

Truths: the reference graph (one factor per reading, view offsets as ``Vector2`` keys in
:func:`fgloc.solve.joint.build_problem`, head vectors in
:func:`fgloc.solve.self_calibration.build_self_calibration_problem`; their factors are
checked against numerical differentiation in test_view_offsets.py and test_head_model.py)
and central differences of the eliminated cost.
"""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np
import pytest

import fgloc  # noqa: F401  (first: importing factors.* before fgloc is circular on main)
from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing
from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS
from fgloc.core.model import NodeMode, Survey
from fgloc.factors.view_offset import rotate_by_view
from fgloc.sim.scenes import RandomScene, random_scene
from fgloc.solve.eliminated import (
    HeadSpec,
    build_eliminated,
    camera_covariance,
    collect_eliminated,
    optimize_eliminated,
    solve_survey_eliminated,
)
from fgloc.solve.joint import SolverOptions, auto_gauge_sigma, build_problem, initialize, solve_problem, solve_survey
from fgloc.solve.levenberg_marquardt import LMParams
from fgloc.solve.self_calibration import build_self_calibration_problem, optimize

TIGHT = LMParams(relative_error_tol=1e-14, absolute_error_tol=0.0)
HEAD_SIGMA = math.radians(0.1)


def _viewed(survey: Survey, views_per_camera: int, seed: int) -> Survey:
    """``survey`` with its readings grouped into views (pan sectors per camera), each view's head
    error applied as the head would (a rotation at the view's head pan); sigma = hypot(head, the
    reading's own), and every third reading with its own tilt sigma (``sigma_axes``, 2.5x pan's)."""
    rng = np.random.default_rng(seed)
    t = survey.observation_table
    out = []
    errors: dict[str, np.ndarray] = {}
    for k, o in enumerate(survey.observations):
        sector = int(np.floor((o.pan + math.pi) / (2 * math.pi) * views_per_camera)) % views_per_camera
        vid = f"{o.camera}/v{sector}"
        head_pan = -math.pi + (sector + 0.5) * 2 * math.pi / views_per_camera
        if vid not in errors:
            errors[vid] = rng.normal(0.0, HEAD_SIGMA, 2)
        q = pan_tilt_bearing(np.array([o.pan]), np.array([o.tilt]))
        qp, _, _ = rotate_by_view(q, errors[vid][None], np.array([head_pan]))
        pan, tilt = bearing_pan_tilt(qp)
        axes = (math.hypot(HEAD_SIGMA, t.sigma[k]), math.hypot(HEAD_SIGMA, 2.5 * t.sigma[k])) if k % 3 == 0 else None
        out.append(replace(o, pan=float(pan[0]), tilt=float(tilt[0]), sigma=math.hypot(HEAD_SIGMA, t.sigma[k]),
                           view=vid, view_sigma=HEAD_SIGMA, view_pan=head_pan, sigma_axes=axes))
    viewed = replace(survey, observations=out)
    for cached in ("observation_table", "view_ids"):
        viewed.__dict__.pop(cached, None)
    return viewed


def _scene(name: str, sigma_deg: float = 0.01) -> Survey:
    """Random scenes; readings of sigma 0.01 deg (a decoder's), or 0.1 deg for the head model."""
    sigma = math.radians(sigma_deg)
    if name == "planar":
        return random_scene(RandomScene(n_cameras=3, n_nodes=60, sigma=sigma, seed=11))
    if name == "planar repeats":
        return random_scene(RandomScene(n_cameras=4, n_nodes=50, repeats=2, visibility=0.7, sigma=sigma, seed=12))
    if name == "3d":
        return random_scene(RandomScene(n_cameras=4, n_nodes=60, mode=NodeMode.THREE_D, sigma=sigma, seed=13))
    raise ValueError(name)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("name", ["planar", "planar repeats", "3d"])
def test_view_offsets_same_optimum_and_marginals_as_the_reference_graph(name: str) -> None:
    survey = _viewed(_scene(name), 6, seed=1)
    init = initialize(survey)
    options = SolverOptions(lm=TIGHT, gauge_sigma=auto_gauge_sigma(survey, init))
    ref = build_problem(survey, init, options)
    assert len(ref.view_keys) >= 12
    ref_solution = solve_problem(ref, options)
    fast = build_eliminated(survey, init, options)
    assert fast.view_keys == ref.view_keys
    outcome = optimize_eliminated(fast, options)
    result = collect_eliminated(fast, outcome, options)
    ref_cost = ref_solution.result.stats.final_error
    assert abs(result.stats.final_error - ref_cost) <= 1e-9 * ref_cost
    values = ref_solution.values
    ref.prepare(values)
    marginals = gtsam.Marginals(ref.graph.linearize(values), values)
    for nid, key in ref.node_keys.items():
        np.testing.assert_allclose(result.nodes[nid].position, ref_solution.result.nodes[nid].position, atol=1e-7)
        assert _rel(result.nodes[nid].covariance, marginals.marginalCovariance(key)) <= 1e-8
    sigma = camera_covariance(fast, outcome.values)
    k = len(fast.camera_keys)
    for a, key in enumerate(fast.view_keys.values()):
        np.testing.assert_allclose(np.asarray(outcome.values.atVector(key)), np.asarray(values.atVector(key)),
                                   atol=1e-9)
        block = sigma[6 * k + 2 * a: 6 * k + 2 * a + 2, 6 * k + 2 * a: 6 * k + 2 * a + 2]
        assert _rel(block, marginals.marginalCovariance(key)) <= 1e-8


def test_solve_survey_with_views_takes_the_fast_path_to_the_reference_result() -> None:
    survey = _viewed(_scene("planar"), 5, seed=2)
    fast = solve_survey_eliminated(survey)  # raises EliminationFailed instead of falling back
    ref = solve_survey(survey, SolverOptions(eliminate_nodes=False))
    assert abs(fast.stats.final_error - ref.stats.final_error) <= 1e-9 * ref.stats.final_error
    for nid, est in ref.nodes.items():
        assert _rel(fast.nodes[nid].covariance, est.covariance) <= 1e-6


def _reduced_gradient_check(problem, values: gtsam.Values) -> None:  # type: ignore[no-untyped-def]
    readings = problem.readings
    system = readings.reduced(values)
    h = 1e-7
    numeric = []
    for key, dim in zip(readings.keys, readings.dims):
        for i in range(dim):
            costs = []
            for sign in (1.0, -1.0):
                moved = gtsam.Values(values)
                delta = np.zeros(dim)
                delta[i] = sign * h
                if dim == 6 and key in problem.camera_keys.values():
                    moved.update(key, values.atPose3(key).retract(delta))
                else:
                    moved.update(key, np.asarray(values.atVector(key)) + delta)
                costs.append(readings.cost(moved))
            numeric.append((costs[0] - costs[1]) / (2 * h))
    scale = np.linalg.norm(system.gradient)
    assert len(numeric) == len(system.gradient)
    assert np.max(np.abs(np.array(numeric) - system.gradient)) <= 1e-4 * scale


@pytest.mark.parametrize("name", ["planar", "3d"])
def test_reduced_gradient_with_view_offsets_is_the_derivative_of_the_eliminated_cost(name: str) -> None:
    survey = _viewed(_scene(name), 4, seed=3)
    problem = build_eliminated(survey, initialize(survey))
    values = gtsam.Values(problem.initial)
    rng = np.random.default_rng(4)
    for key in problem.view_keys.values():
        values.update(key, rng.normal(0.0, HEAD_SIGMA, 2))
    _reduced_gradient_check(problem, values)


ALL = tuple(range(7))


@pytest.mark.parametrize("name", ["planar", "3d"])
def test_head_vectors_same_optimum_and_marginals_as_the_reference_graph(name: str) -> None:
    survey = _scene(name, 0.1)
    init = initialize(survey)
    options = SolverOptions(lm=TIGHT, gauge_sigma=auto_gauge_sigma(survey, init))
    active = {c: ALL for c in survey.camera_ids}
    active[survey.camera_ids[-1]] = (0, 1, 3)  # a camera with a partial model
    ref = build_self_calibration_problem(survey, init, active, None, options, frozenset(), DEFAULT_PRIOR_SIGMAS)
    ref_out = optimize(ref, options)
    fast = build_eliminated(survey, init, options, heads=HeadSpec(active, None, DEFAULT_PRIOR_SIGMAS))
    assert fast.head_keys == ref.head_keys
    outcome = optimize_eliminated(fast, options)
    result = collect_eliminated(fast, outcome, options)
    ref_cost = ref_out.error_history[-1]
    assert abs(result.stats.final_error - ref_cost) <= 1e-9 * ref_cost
    # Marginals at the same point (the fast optimum with its nodes; the weakly determined head
    # parameters leave the two optima ~1e-8 apart, enough to move marginals by ~1e-8).
    values = fast.node_values(outcome.values)
    for key in ref_out.values.keys():
        if ref_out.values.dims()[key] in (2, 3) and key not in fast.head_keys.values():
            np.testing.assert_allclose(np.asarray(values.atVector(key)), np.asarray(ref_out.values.atVector(key)),
                                       atol=1e-7)
    ref.prepare(values)
    marginals = gtsam.Marginals(ref.graph.linearize(values), values)
    for nid, key in ref.node_keys.items():
        assert _rel(result.nodes[nid].covariance, marginals.marginalCovariance(key)) <= 1e-8
    sigma = camera_covariance(fast, outcome.values)
    offset = 6 * len(fast.camera_keys)
    for cid, key in fast.head_keys.items():
        n = len(active[cid])
        np.testing.assert_allclose(np.asarray(outcome.values.atVector(key)), np.asarray(ref_out.values.atVector(key)),
                                   atol=1e-6 * np.max(DEFAULT_PRIOR_SIGMAS))
        assert _rel(sigma[offset:offset + n, offset:offset + n], marginals.marginalCovariance(key)) <= 1e-8
        offset += n


def test_reduced_gradient_with_head_vectors_is_the_derivative_of_the_eliminated_cost() -> None:
    survey = _scene("3d", 0.1)
    active = {c: ALL for c in survey.camera_ids}
    problem = build_eliminated(survey, initialize(survey), heads=HeadSpec(active, None, DEFAULT_PRIOR_SIGMAS))
    values = gtsam.Values(problem.initial)
    rng = np.random.default_rng(5)
    # Pan scale held at zero: it scales the *wrapped* pan (core.head_model), so a nonzero value makes
    # the cost jump where a node crosses pan +-180 deg, and central differences there mean nothing.
    for key in problem.head_keys.values():
        values.update(key, rng.normal(0.0, 1.0, 7) * np.array([3e-3, 3e-3, 3e-3, 0.0, 5e-3, 1e-3, 1e-3]))
    _reduced_gradient_check(problem, values)


@pytest.mark.parametrize("name", ["planar", "3d"])
def test_pan_and_tilt_sigmas_same_optimum_and_marginals_without_views(name: str) -> None:
    # readings with their own tilt sigma (Observation.sigma_axes) on the plain fast path (no camera-side extras)
    base = _scene(name, 0.1)
    obs = [replace(o, sigma_axes=(base.sigma, 3.0 * base.sigma)) if k % 2 else o
           for k, o in enumerate(base.observations)]
    survey = replace(base, observations=obs)
    init = initialize(survey)
    options = SolverOptions(lm=TIGHT, gauge_sigma=auto_gauge_sigma(survey, init))
    ref = build_problem(survey, init, options)
    ref_solution = solve_problem(ref, options)
    fast = build_eliminated(survey, init, options)
    assert fast.readings.side is None
    outcome = optimize_eliminated(fast, options)
    result = collect_eliminated(fast, outcome, options)
    ref_cost = ref_solution.result.stats.final_error
    assert abs(result.stats.final_error - ref_cost) <= 1e-9 * ref_cost
    for nid, est in ref_solution.result.nodes.items():
        np.testing.assert_allclose(result.nodes[nid].position, est.position, atol=1e-7)
        assert _rel(result.nodes[nid].covariance, est.covariance) <= 1e-8
