"""The nodes-eliminated fast path against the reference graph (one pan-tilt factor per reading).

Truths: the reference graph (its per-reading factors are checked against numerical
differentiation in test_pan_tilt_factor.py), central differences of the eliminated
cost, and GTSAM's own M-estimators.
"""

from dataclasses import replace

import gtsam
import numpy as np
import pytest

import fgloc  # noqa: F401  (first: importing factors.* before fgloc is circular on main)
from fgloc.core.model import NodeMode, Survey
from fgloc.factors.eliminated_readings import Kernel, factor_rows, loss_and_weight
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.sim.scenes import RandomScene, random_scene
from fgloc.solve.eliminated import (
    build_eliminated,
    camera_covariance,
    collect_eliminated,
    estimate_eliminated,
    optimize_eliminated,
)
from fgloc.solve.joint import (
    RobustKernel,
    SolverOptions,
    auto_gauge_sigma,
    build_problem,
    initialize,
    solve_problem,
    solve_survey,
)
from fgloc.solve.levenberg_marquardt import LMParams

TIGHT = LMParams(relative_error_tol=1e-14, absolute_error_tol=0.0)


def _with_outliers(survey: Survey, every: int, degrees: float = 4.0) -> Survey:
    obs = [replace(o, pan=o.pan + np.deg2rad(degrees)) if i % every == 0 else o for i, o in enumerate(survey.observations)]
    return replace(survey, observations=obs)


def _scene(name: str) -> Survey:
    if name == "planar 2 cams":
        return scene_survey(BenchScene(60, 2, seed=1))
    if name == "planar 8 cams":
        return scene_survey(BenchScene(80, 8, seed=2))
    if name == "planar repeats":
        return random_scene(RandomScene(n_cameras=4, n_nodes=50, repeats=3, visibility=0.7, seed=3))
    if name == "3d 3 cams":
        return random_scene(RandomScene(n_cameras=3, n_nodes=50, mode=NodeMode.THREE_D, seed=4))
    if name == "3d 8 cams repeats":
        return random_scene(RandomScene(n_cameras=8, n_nodes=60, mode=NodeMode.THREE_D, repeats=2, visibility=0.6, seed=5))
    if name == "planar outliers":
        return _with_outliers(random_scene(RandomScene(n_cameras=4, n_nodes=60, seed=6)), 17)
    if name == "3d outliers":
        return _with_outliers(random_scene(RandomScene(n_cameras=5, n_nodes=60, mode=NodeMode.THREE_D, seed=7)), 19)
    raise ValueError(name)


CASES = [
    ("planar 2 cams", RobustKernel.NONE),
    ("planar 8 cams", RobustKernel.NONE),
    ("planar repeats", RobustKernel.NONE),
    ("3d 3 cams", RobustKernel.NONE),
    ("3d 8 cams repeats", RobustKernel.NONE),
    ("planar outliers", RobustKernel.HUBER),
    ("planar outliers", RobustKernel.CAUCHY),
    ("3d outliers", RobustKernel.CAUCHY),
]


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize(("name", "kernel"), CASES)
def test_same_optimum_and_marginals_as_the_reference_graph(name: str, kernel: RobustKernel) -> None:
    survey = _scene(name)
    init = initialize(survey)
    # One gauge sigma for every graph built here (auto_gauge_sigma depends on the start).
    options = SolverOptions(robust=kernel, lm=TIGHT, gauge_sigma=auto_gauge_sigma(survey, init))
    ref = build_problem(survey, init, options)
    ref_solution = solve_problem(ref, options)
    fast = build_eliminated(survey, init, options)
    outcome = optimize_eliminated(fast, options)
    result = collect_eliminated(fast, outcome, options)
    if kernel is not RobustKernel.NONE:
        # A robust cost has several minima and GTSAM-linearized (IRLS) LM creeps towards one:
        # from the same start the fast path must do at least as well, and the reference graph,
        # polished from the fast optimum, must find nothing lower (same minimum, same marginals).
        assert result.stats.final_error <= ref_solution.result.stats.final_error * (1 + 1e-9)
        ref = build_problem(survey, estimate_eliminated(fast, outcome.values), options)
        ref_solution = solve_problem(ref, options)
    ref_cost = ref_solution.result.stats.final_error
    assert abs(result.stats.final_error - ref_cost) <= 1e-9 * ref_cost
    # The fast path's reported cost is the reference graph's error at its estimate.
    full = fast.node_values(outcome.values)
    ref.prepare(full)
    assert np.isclose(float(ref.graph.error(full)), result.stats.final_error, rtol=1e-12)
    dim = survey.mode.position_dim
    for nid, est in ref_solution.result.nodes.items():
        np.testing.assert_allclose(result.nodes[nid].position, est.position, atol=1e-7)
    # Marginals: the reference graph's (gtsam.Marginals) at the Gaussian reference optimum; with a
    # robust kernel at the fast optimum itself (the IRLS weights make them sensitive to where the
    # reference LM stopped creeping).
    point = ref_solution.values if kernel is RobustKernel.NONE else full
    ref.prepare(point)
    marginals = gtsam.Marginals(ref.graph.linearize(point), point)
    for nid, key in ref.node_keys.items():
        assert result.nodes[nid].covariance.shape == (dim, dim)
        assert _rel(result.nodes[nid].covariance, marginals.marginalCovariance(key)) <= 1e-8
    sigma_cc = camera_covariance(fast, outcome.values)
    for a, key in enumerate(fast.camera_keys.values()):
        block = sigma_cc[6 * a : 6 * a + 6, 6 * a : 6 * a + 6]
        assert _rel(block, marginals.marginalCovariance(key)) <= 1e-8


def test_solve_survey_flags_the_same_readings_as_the_reference() -> None:
    survey = _with_outliers(scene_survey(BenchScene(80, 4, seed=8)), 23, degrees=3.0)
    fast = solve_survey(survey)
    ref = solve_survey(survey, SolverOptions(eliminate_nodes=False))
    assert fast.flagged and {f.index for f in fast.flagged} == {f.index for f in ref.flagged}
    assert fast.unlocalized == ref.unlocalized
    assert abs(fast.stats.final_error - ref.stats.final_error) <= 1e-9 * ref.stats.final_error
    for nid, est in ref.nodes.items():
        np.testing.assert_allclose(fast.nodes[nid].position, est.position, atol=1e-7)
        assert _rel(fast.nodes[nid].covariance, est.covariance) <= 1e-6


@pytest.mark.parametrize("name", ["planar 8 cams", "3d 3 cams", "planar outliers"])
def test_reduced_gradient_is_the_derivative_of_the_eliminated_cost(name: str) -> None:
    """Central differences of f(c) = min_x cost(c, x) in each camera's tangent (right perturbation)."""
    survey = _scene(name)
    kernel = RobustKernel.CAUCHY if "outliers" in name else RobustKernel.NONE
    problem = build_eliminated(survey, initialize(survey), SolverOptions(robust=kernel))
    readings, values = problem.readings, problem.initial
    system = readings.reduced(values)
    keys = list(problem.camera_keys.values())
    h = 1e-6
    numeric = np.zeros(6 * len(keys))
    for a, key in enumerate(keys):
        for i in range(6):
            costs = []
            for sign in (1.0, -1.0):
                moved = gtsam.Values(values)
                xi = np.zeros(6)
                xi[i] = sign * h
                moved.update(key, values.atPose3(key).retract(xi))
                costs.append(readings.cost(moved))
            numeric[6 * a + i] = (costs[0] - costs[1]) / (2 * h)
    scale = np.linalg.norm(system.gradient)
    assert np.max(np.abs(numeric - system.gradient)) <= 1e-4 * scale


@pytest.mark.parametrize("name", ["planar repeats", "3d 8 cams repeats", "planar outliers"])
def test_reduced_hessian_is_the_schur_complement_of_the_reference_linearization(name: str) -> None:
    survey = _scene(name)
    kernel = RobustKernel.HUBER if "outliers" in name else RobustKernel.NONE
    options = SolverOptions(robust=kernel)
    problem = build_eliminated(survey, initialize(survey), options)
    system = problem.readings.reduced(problem.initial)
    # The reference graph's readings at the same cameras and the eliminated nodes.
    at = estimate_eliminated(problem, problem.initial)
    ref = build_problem(survey, at, options)
    ref.prepare(ref.initial)
    pan_tilt = gtsam.NonlinearFactorGraph()
    for i in range(len(ref.pan_tilt)):
        pan_tilt.add(ref.graph.at(i))
    J, e = pan_tilt.linearize(ref.initial).jacobian()  # columns in sorted key order: cameras (c) before nodes (l)
    n_cam = 6 * len(problem.camera_keys)
    H = J.T @ J
    g = -J.T @ e
    hcc, hcn, hnn = H[:n_cam, :n_cam], H[:n_cam, n_cam:], H[n_cam:, n_cam:]
    schur = hcc - hcn @ np.linalg.solve(hnn, hcn.T)
    reduced_g = g[:n_cam] - hcn @ np.linalg.solve(hnn, g[n_cam:])
    assert _rel(system.hessian, schur) <= 1e-9
    np.testing.assert_allclose(system.gradient, reduced_g, atol=1e-7 * np.linalg.norm(reduced_g) + 1e-9)
    # The factor's rows reproduce the system: R^T R = S, R^T e = g, 0.5 |rows|^2 = f at zero step.
    root, e_red = factor_rows(system.hessian, system.gradient)
    assert _rel(root.T @ root, system.hessian) <= 1e-12
    np.testing.assert_allclose(root.T @ e_red, system.gradient, atol=1e-9 * np.linalg.norm(system.gradient) + 1e-6)
    linear = problem.graph.at(0).linearize(problem.initial)
    assert np.isclose(linear.error(gtsam.VectorValues.Zero(problem.initial.zeroVectors())), system.cost, rtol=1e-12)
    assert np.isclose(problem.graph.at(0).error(problem.initial), system.cost, rtol=1e-12)


@pytest.mark.parametrize("kernel", [Kernel.HUBER, Kernel.CAUCHY, Kernel.GAUSSIAN])
def test_loss_and_weight_are_gtsams(kernel: Kernel) -> None:
    s = np.array([0.0, 0.3, 1.0, 2.9, 3.1, 7.0, 40.0])
    loss, weight = loss_and_weight(s**2, kernel, 3.0)
    if kernel is Kernel.GAUSSIAN:
        np.testing.assert_allclose(loss, 0.5 * s**2)
        return
    model = {Kernel.HUBER: gtsam.noiseModel.mEstimator.Huber, Kernel.CAUCHY: gtsam.noiseModel.mEstimator.Cauchy}[kernel].Create(3.0)
    np.testing.assert_allclose(loss, [model.loss(float(v)) for v in s], rtol=1e-12)
    np.testing.assert_allclose(weight[1:], [model.weight(float(v)) for v in s[1:]], rtol=1e-12)


def test_iteration_callback_sees_cameras_and_nodes() -> None:
    survey = scene_survey(BenchScene(40, 3, seed=9))
    seen: list[tuple[int, int]] = []

    def record(k: int, values: gtsam.Values, error: float) -> None:
        seen.append((k, values.size()))

    solve_survey(survey, on_iteration=record)
    assert seen[0][0] == 0 and all(size == 3 + 40 for _, size in seen)
