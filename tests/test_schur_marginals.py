"""Batched Schur-complement node marginals against ``gtsam.Marginals``.

Truth used: GTSAM's own marginal covariances of the same linearized graph
(multifrontal Cholesky, per-key Bayes-tree queries).
"""

import gtsam
import numpy as np

from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.joint import build_problem, initialize
from fgloc.solve.schur_marginals import node_marginals


def _linearized(n: int, cams: int, seed: int):
    survey = scene_survey(BenchScene(n, cams, seed=seed))
    problem = build_problem(survey, initialize(survey))
    values = problem.initial
    problem.prepare(values)
    return problem, values, problem.graph.linearize(values)


def test_schur_marginals_equal_gtsam_marginals() -> None:
    for n, cams, seed in [(50, 2, 0), (80, 5, 1)]:
        problem, values, linear = _linearized(n, cams, seed)
        keys = list(problem.node_keys.values())
        fast = node_marginals(linear, values.dims(), keys)
        assert fast is not None
        ref = gtsam.Marginals(linear, values)
        for k in keys:
            np.testing.assert_allclose(fast[k], ref.marginalCovariance(k), rtol=1e-7, atol=1e-18)


def test_node_to_node_factor_falls_back() -> None:
    """A factor between two nodes breaks the structure: the function must say so, not guess."""
    problem, values, _ = _linearized(30, 2, 2)
    keys = list(problem.node_keys.values())
    problem.graph.add(gtsam.BetweenFactorPoint2(keys[0], keys[1], np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)))
    problem.prepare(values)
    assert node_marginals(problem.graph.linearize(values), values.dims(), keys) is None
