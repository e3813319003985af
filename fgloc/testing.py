"""Test helpers shipped with fgloc (like ``symforce.test_util``): scenes and checks that the
test suite and the stress scripts share.

This module sits at the top of the layers, beside :mod:`fgloc.cli`: it may import any
part of fgloc, and nothing in fgloc imports it.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.utils.numerical_derivative import numericalDerivative31, numericalDerivative32, numericalDerivative33

from fgloc.core.geometry import FloatArray
from fgloc.core.model import NodeMode, Survey
from fgloc.factors.pan_tilt_head_factor import HeadFactorSet
from fgloc.init.start import InitialEstimate
from fgloc.sim.scenes import RandomScene, random_scene
from fgloc.solve.joint import build_problem, solve, solve_survey

__all__ = ["assert_head_factor_jacobians", "reaches_global_optimum", "stress_scene"]


def stress_scene(index: int, mode: NodeMode) -> Survey:
    """The index-th stress scene (deterministic): 2-8 cameras, 20-400 nodes, random visibility.

    ``scripts/stress_scenes.py`` runs scenes 0..N-1; the tests run a seeded sample."""
    rng = np.random.default_rng(index)
    return random_scene(
        RandomScene(
            n_cameras=int(rng.integers(2, 9)),
            n_nodes=int(rng.integers(20, 401)),
            mode=mode,
            visibility=float(rng.uniform(0.5, 1.0)),
            seed=index,
        )
    )


def reaches_global_optimum(survey: Survey, rel_tol: float = 1e-6) -> tuple[bool, float, float]:
    """Solve ``survey`` from fgloc's own start and from the truth: (ok, our final error, the truth's).

    ``ok`` when our final cost is no higher than the cost of the solve started at the
    true scene (within ``rel_tol``): a start in another basin would end higher."""
    ours = solve_survey(survey)
    truth = survey.truth
    assert truth is not None, "reaches_global_optimum needs a simulated survey (with truth)"
    assert ours.stats is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes={n: truth.nodes[n] for n in ours.nodes})
    ref = solve(build_problem(survey, start))
    assert ref.stats is not None
    ok = ours.stats.final_error <= ref.stats.final_error * (1 + rel_tol) + 1e-6
    return ok, ours.stats.final_error, ref.stats.final_error


def assert_head_factor_jacobians(
    heads: HeadFactorSet, keys: tuple[int, int, int], pose: gtsam.Pose3, node: FloatArray, head_values: FloatArray,
    sigma: float,
) -> tuple[FloatArray, FloatArray]:
    """Assert that the first head-model factor's analytic Jacobians equal GTSAM's numerical
    derivatives (step 1e-6, tolerance 1e-6), computed without and then with the set's prepared
    cache. ``keys`` are its (camera pose, node, head vector) keys, ``sigma`` its isotropic noise.
    Returns the analytic unwhitened Jacobian (columns: pose 6, node 2 or 3, head vector) and the
    numerical one of the head vector."""
    factor = heads.factors[0]

    def values_of(p: gtsam.Pose3, x: FloatArray, h: FloatArray) -> gtsam.Values:
        v = gtsam.Values()
        v.insert(keys[0], p)
        v.insert(keys[1], x)
        v.insert(keys[2], h)
        return v

    def f(p: gtsam.Pose3, x: FloatArray, h: FloatArray) -> FloatArray:
        return np.asarray(factor.unwhitenedError(values_of(p, x, h)))

    values = values_of(pose, node, head_values)
    num = [d(f, pose, node, head_values, 1e-6) for d in (numericalDerivative31, numericalDerivative32,
                                                          numericalDerivative33)]
    dp = len(node)
    A = np.zeros((2, 0))
    for use_cache in (False, True):
        if use_cache:
            heads.prepare(values)
        A = np.asarray(factor.linearize(values).jacobian()[0]) * sigma
        np.testing.assert_allclose(A[:, :6], num[0], atol=1e-6)
        np.testing.assert_allclose(A[:, 6:6 + dp], num[1], atol=1e-6)
        np.testing.assert_allclose(A[:, 6 + dp:], num[2], atol=1e-6)
    return A, np.asarray(num[2])
