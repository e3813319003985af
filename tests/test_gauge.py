"""The gauge prior fixes the frame without biasing the solution."""

import gtsam
import numpy as np
import pytest

from fgloc.core.model import CameraPose
from fgloc.factors.baseline_prior import BaselinePrior, ground_point_factor
from fgloc.init.start import InitialEstimate
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import SolverOptions, build_problem, initialize, solve


@pytest.fixture(scope="module")
def survey():
    return paper_scenario(PaperScenario(n_nodes=60, seed=21, heights=(0.12, 0.3)))


def test_solution_independent_of_gauge_sigma(survey) -> None:
    """Bearings cannot resist a gauge motion, so the prior's strength must not move the optimum."""
    init = initialize(survey)
    results = [solve(build_problem(survey, init, SolverOptions(gauge_sigma=s)), SolverOptions(gauge_sigma=s))
               for s in (1e-5, 1e-6, 1e-7)]
    for r in results[1:]:
        for n in survey.node_ids:
            np.testing.assert_allclose(r.nodes[n].position, results[0].nodes[n].position, atol=1e-9)
    # Covariances converge as sigma -> 0 (the gauge leaks only O(sigma^2)).
    # Covariances agree up to the gauge leak, O(sigma^2) = 1e-12 at sigma = 1e-6.
    for n in survey.node_ids:
        np.testing.assert_allclose(results[1].nodes[n].covariance, results[2].nodes[n].covariance, rtol=0, atol=1e-11)


def test_solution_independent_of_how_the_gauge_is_held(survey) -> None:
    """Pin the two cameras' ground points at arbitrary other places, solve, and map back by the
    plane similarity: the result must equal the direct solve (the prior carries no information)."""
    init = initialize(survey)
    direct = solve(build_problem(survey, init))
    a, b = np.array([0.3, -0.2]), np.array([2.3, 1.0])
    d = b - a
    scale, ang = np.linalg.norm(d), np.arctan2(d[1], d[0])
    c, s_ = np.cos(ang), np.sin(ang)
    rot3 = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    shift = np.array([a[0], a[1], 0.0])
    moved = InitialEstimate(
        cameras={k: CameraPose(shift + scale * rot3 @ v.position, rot3 @ v.rotation) for k, v in init.cameras.items()},
        nodes={k: shift + scale * rot3 @ p for k, p in init.nodes.items()},
    )
    problem = build_problem(survey, moved)
    g = gtsam.NonlinearFactorGraph()
    for i in range(problem.graph.size() - 2):  # drop the spec gauge (its two factors come last)
        g.add(problem.graph.at(i))
    g.add(ground_point_factor(problem.camera_keys["cam0"], tuple(a)))
    g.add(ground_point_factor(problem.camera_keys["cam1"], tuple(b)))
    problem.graph = g
    other = solve(problem)
    rot = np.array([[np.cos(ang), np.sin(ang)], [-np.sin(ang), np.cos(ang)]])  # undo rotation
    for n in survey.node_ids:
        mapped = rot @ (other.nodes[n].position[:2] - a) / scale
        np.testing.assert_allclose(mapped, direct.nodes[n].position[:2], atol=1e-8)
    assert other.stats.final_error == pytest.approx(direct.stats.final_error, rel=1e-9)


def test_without_gauge_the_marginals_are_indeterminate(survey) -> None:
    """Dropping the gauge leaves a rank-deficient system: GTSAM must refuse (so the prior is needed)."""
    init = initialize(survey)
    problem = build_problem(survey, init)
    g = gtsam.NonlinearFactorGraph()
    for i in range(problem.graph.size() - 2):
        g.add(problem.graph.at(i))
    problem.prepare(problem.initial)
    with pytest.raises(RuntimeError, match="Indeterminate"):
        gtsam.Marginals(g.linearize(problem.initial), problem.initial)


def test_gauge_factors_jacobians_numerical() -> None:
    from gtsam.utils.numerical_derivative import numericalDerivative11, numericalDerivative21, numericalDerivative22

    from fgloc.core.model import NodeMode

    rng = np.random.default_rng(0)
    p0 = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    p1 = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3))
    for mode in (NodeMode.PLANAR, NodeMode.THREE_D):
        for f in BaselinePrior(mode, 0, 1, sigma=1.0).factors():
            keys = list(f.keys())
            def err(*poses):
                v = gtsam.Values()
                for k, p in zip(keys, poses):
                    v.insert(k, p)
                return f.unwhitenedError(v)
            v = gtsam.Values()
            v.insert(0, p0)
            v.insert(1, p1)
            A, _ = f.linearize(v).jacobian()
            if len(keys) == 1:
                num = numericalDerivative11(err, p0 if keys[0] == 0 else p1, 1e-6)
            else:
                num = np.hstack([numericalDerivative21(err, p0, p1, 1e-6), numericalDerivative22(err, p0, p1, 1e-6)])
            np.testing.assert_allclose(A, num, atol=1e-6)
