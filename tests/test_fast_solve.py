"""The fast solve path against the readable reference.

Truths used: the reference per-reading factor built on
``fgloc.factors.pan_tilt_factor.pan_tilt_error`` (itself checked against numerical
differentiation in test_pan_tilt_factor.py), and a tight reference solve
(GTSAM's per-reading factors, small LM steps, 1e-14 tolerance) for the optimum
and the marginal covariances.
"""

import gtsam
import numpy as np

import fgloc  # noqa: F401  (first: importing factors.* before fgloc is circular on main)
from fgloc.factors.pan_tilt_factor import planar_pan_tilt_factor
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.joint import SolverOptions, build_problem, initialize, solve_problem, solve_survey
from fgloc.solve.levenberg_marquardt import LMParams, levenberg_marquardt


def _reference_graph(problem):
    """The same graph with one reference factor per reading (no vectorized cache)."""
    graph = gtsam.NonlinearFactorGraph()
    ft = problem.pan_tilt
    for i in range(len(ft)):
        sigma = ft.factors[i].noiseModel().sigmas()[0]
        graph.add(planar_pan_tilt_factor(int(ft.camera_keys[i]), int(ft.node_keys[i]), ft.pan[i], ft.tilt[i], sigma))
    for i in range(len(ft), problem.graph.size()):
        graph.add(problem.graph.at(i))
    return graph


def test_prepared_linearization_equals_reference_factors() -> None:
    survey = scene_survey(BenchScene(30, 4, seed=3))
    problem = build_problem(survey, initialize(survey))
    values = problem.initial
    problem.prepare(values)
    fast_A, fast_b = problem.graph.linearize(values).jacobian()
    ref_A, ref_b = _reference_graph(problem).linearize(values).jacobian()
    np.testing.assert_allclose(fast_A, ref_A, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(fast_b, ref_b, rtol=1e-12, atol=1e-9)
    assert np.isclose(problem.graph.error(values), _reference_graph(problem).error(values), rtol=1e-13)


def test_fast_solve_reaches_tight_reference_optimum_and_covariances() -> None:
    survey = scene_survey(BenchScene(60, 3, seed=5))
    fast = solve_survey(survey)
    problem = build_problem(survey, initialize(survey))
    ref_graph = _reference_graph(problem)
    tight = LMParams(initial_lambda=1e-3, relative_error_tol=1e-15, absolute_error_tol=0.0)
    ref = levenberg_marquardt(ref_graph, problem.initial, problem.elimination_ordering(), tight)
    assert fast.stats is not None
    assert fast.stats.final_error <= ref.error_history[-1] * (1 + 1e-9)
    marginals = gtsam.Marginals(ref_graph, ref.values)
    for nid, key in problem.node_keys.items():
        np.testing.assert_allclose(fast.nodes[nid].position[:2], ref.values.atPoint2(key), atol=1e-9)
        np.testing.assert_allclose(fast.nodes[nid].covariance, marginals.marginalCovariance(key), rtol=1e-6, atol=1e-14)


def test_small_initial_lambda_takes_fewer_iterations_to_the_same_cost() -> None:
    """Regression guard for the lambda schedule: the default must not lose to Nielsen's 1/3 rule."""
    survey = scene_survey(BenchScene(100, 2, seed=0))
    problem = build_problem(survey, initialize(survey))
    new = solve_problem(problem, SolverOptions(compute_marginals=False)).result
    problem2 = build_problem(survey, initialize(survey))
    old = solve_problem(problem2, SolverOptions(lm=LMParams(min_lambda_factor=1.0 / 3.0), compute_marginals=False)).result
    assert new.stats.iterations <= old.stats.iterations
    assert np.isclose(new.stats.final_error, old.stats.final_error, rtol=1e-9)


def test_vectorized_error_equals_graph_error_with_extra_and_robust_factors() -> None:
    """Truth: GTSAM's own ``graph.error`` (per-factor callbacks and C++ factors)."""
    survey = scene_survey(BenchScene(40, 3, seed=7))
    problem = build_problem(survey, initialize(survey))
    values = problem.initial
    assert np.isclose(problem.error(values), problem.graph.error(values), rtol=1e-12)
    keys = list(problem.node_keys.values())
    problem.add_factor(gtsam.PriorFactorPoint2(keys[0], np.array([0.3, 0.4]), gtsam.noiseModel.Isotropic.Sigma(2, 0.01)))
    assert np.isclose(problem.error(values), problem.graph.error(values), rtol=1e-12)
    # Robust noise: the set cannot sum the loss itself and must defer to GTSAM.
    from fgloc.factors.pan_tilt_batch import PanTiltFactorSet

    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), gtsam.noiseModel.Isotropic.Sigma(2, 0.01))
    ft = problem.pan_tilt
    rset = PanTiltFactorSet(ft.camera_keys, ft.node_keys, ft.pan, ft.tilt, [robust] * len(ft), planar=True)
    assert rset.error(values) is None
