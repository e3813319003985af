"""Bounds of the per-node ANEES under correlated nodes: exact against closed forms, calibrated
on seeded correlated scenes where the independent-node bounds are not, and still able to
reject an overconfident covariance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import block_diag
from scipy.stats import chi2

from fgloc.evaluate.anees_bounds import (
    anees_bounds,
    anees_bounds_of_eigenvalues,
    generalized_chi2_quantiles,
    node_nees_eigenvalues,
)
from fgloc.evaluate.joint_nees import joint_node_covariance
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey


def random_marginals(rng: np.random.Generator, n: int, dim: int) -> list[np.ndarray]:
    """``n`` random positive-definite ``dim x dim`` node covariances of unequal axes."""
    out = []
    for _ in range(n):
        a = rng.normal(size=(dim, dim))
        out.append(a @ a.T + 0.2 * np.eye(dim))
    return out


def shared_offset_scene(rng: np.random.Generator, n: int, offset_variance: float) -> np.ndarray:
    """(2n, 2n) joint covariance of ``n`` planar nodes: each its own random marginal plus an
    offset common to the scene's nodes (variance ``offset_variance`` per axis), the way a
    scene's camera-pose error moves all its nodes together."""
    return block_diag(*random_marginals(rng, n, 2)) + offset_variance * np.kron(np.ones((n, n)), np.eye(2))


def per_node_anees(rng: np.random.Generator, covariances: list[np.ndarray], draws: int,
                   scale: float = 1.0) -> np.ndarray:
    """``draws`` per-node ANEES (planar) of errors drawn from each scene's covariance and
    scored against the marginals of ``scale`` times it."""
    total = np.zeros(draws)
    nodes = 0
    for c in covariances:
        n = c.shape[0] // 2
        errors = (rng.standard_normal((draws, 2 * n)) @ np.linalg.cholesky(c).T).reshape(draws, n, 2)
        information = np.linalg.inv(scale * c.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :])
        total += np.einsum("kni,nij,knj->k", errors, information, errors)
        nodes += n
    return total / nodes


@pytest.mark.parametrize(("dim", "scene_sizes"), [(2, (1,)), (2, (3, 4)), (2, (100, 97, 99, 98, 100)), (3, (2, 30))])
def test_block_diagonal_covariances_give_the_independent_chi_square_bounds(dim, scene_sizes):
    """One node alone (2 eigenvalues: the grid's tail by QAWF), a few, and the 494 nodes of
    the 100-mote benchmark's five scenes; planar and 3d."""
    rng = np.random.default_rng(3)
    covariances = [block_diag(*random_marginals(rng, n, dim)) for n in scene_sizes]
    for c in covariances:
        np.testing.assert_allclose(node_nees_eigenvalues(c, dim), 1.0, rtol=1e-10)
    nodes = sum(scene_sizes)
    independent = chi2.ppf([0.025, 0.975], dim * nodes) / nodes
    np.testing.assert_allclose(anees_bounds(covariances, dim), independent, rtol=1e-9)
    np.testing.assert_allclose(anees_bounds(covariances, dim, 0.9),
                               chi2.ppf([0.05, 0.95], dim * nodes) / nodes, rtol=1e-9)


def test_quantiles_match_the_closed_form_of_paired_weights():
    """Weights in equal pairs make ``Q`` a sum of exponentials with distinct means ``2 a_j``,
    whose survival function is ``sum_j prod_{i != j} a_j / (a_j - a_i) exp(-x / (2 a_j))``: the
    quantiles land on their probabilities to 1e-9, one weight a hundred times the others."""
    a = np.array([100.0, 3.0, 1.0, 0.5])

    def survival(x: float) -> float:
        return float(sum(np.prod([aj / (aj - ai) for ai in a if ai != aj]) * np.exp(-x / (2 * aj)) for aj in a))

    probabilities = [0.025, 0.5, 0.975]
    quantiles = generalized_chi2_quantiles(np.repeat(a, 2), probabilities)
    assert np.all(np.diff(quantiles) > 0)
    for p, x in zip(probabilities, quantiles):
        assert 1.0 - survival(x) == pytest.approx(p, abs=1e-9)


def test_correlated_scenes_are_calibrated_where_the_independent_bounds_are_not():
    """8 scenes of 20 nodes sharing a per-scene offset, 20,000 seeded draws of their errors:
    the per-node ANEES leaves the new 95 % bounds in 5 % of draws (accepted 4.2-5.8 %, +-5
    binomial sd), the independent-node bounds in more than 15 %; the new bounds are wider."""
    rng = np.random.default_rng(20)
    covariances = [shared_offset_scene(rng, 20, 0.3) for _ in range(8)]
    lo, hi = anees_bounds(covariances, 2)
    independent_lo, independent_hi = chi2.ppf([0.025, 0.975], 2 * 160) / 160
    assert lo < independent_lo and hi > independent_hi
    anees = per_node_anees(rng, covariances, 20_000)
    outside = float(np.mean((anees < lo) | (anees > hi)))
    outside_independent = float(np.mean((anees < independent_lo) | (anees > independent_hi)))
    assert 0.042 <= outside <= 0.058, outside
    assert outside_independent > 0.15, outside_independent
    # each tail holds its own 2.5 %, though the distribution is skewed
    assert 0.018 <= float(np.mean(anees < lo)) <= 0.032 and 0.018 <= float(np.mean(anees > hi)) <= 0.032


def test_an_overconfident_covariance_leaves_the_new_bounds():
    """Errors drawn from ``C``, scored against the marginals of ``0.75 C`` (the eigenvalues,
    hence the bounds, do not change with the scale): outside in most of 5,000 draws."""
    rng = np.random.default_rng(21)
    covariances = [shared_offset_scene(rng, 20, 0.3) for _ in range(8)]
    lo, hi = anees_bounds([0.75 * c for c in covariances], 2)
    anees = per_node_anees(rng, covariances, 5_000, scale=0.75)
    assert float(np.mean((anees < lo) | (anees > hi))) > 0.6


def test_bounds_pool_the_scenes_eigenvalues():
    """Two scenes' bounds from their covariances equal those from their eigenvalues pooled,
    and lie inside the span of each scene's own (pooling narrows them)."""
    rng = np.random.default_rng(5)
    covariances = [shared_offset_scene(rng, 10, 0.5), shared_offset_scene(rng, 15, 0.2)]
    eigenvalues = [node_nees_eigenvalues(c, 2) for c in covariances]
    assert anees_bounds(covariances, 2) == pytest.approx(anees_bounds_of_eigenvalues(eigenvalues, 2), rel=1e-12)
    lo, hi = anees_bounds(covariances, 2)
    for e in eigenvalues:
        own_lo, own_hi = anees_bounds_of_eigenvalues([e], 2)
        assert own_lo < lo and hi < own_hi


def test_the_solvers_joint_covariance_gives_eigenvalues_of_mean_one_and_wider_bounds():
    """A seeded 15-node scene through the solver: the eigenvalues are positive, sum to 2N (mean
    1), and the shared camera errors spread them (the largest above 2), so the bounds are wider
    than the independent ones."""
    survey = paper_scenario(PaperScenario(n_nodes=15, seed=9, heights=(0.2, 0.1)))
    covariance, order = joint_node_covariance(survey, solve_survey(survey))
    eigenvalues = node_nees_eigenvalues(covariance, 2)
    assert eigenvalues.shape == (2 * len(order),) and eigenvalues.min() > 0
    assert eigenvalues.mean() == pytest.approx(1.0, rel=1e-9)
    assert eigenvalues.max() > 2.0
    lo, hi = anees_bounds([covariance], 2)
    independent_lo, independent_hi = chi2.ppf([0.025, 0.975], 2 * len(order)) / len(order)
    assert lo < independent_lo and hi > independent_hi


def test_rejects_malformed_input():
    with pytest.raises(ValueError):
        node_nees_eigenvalues(np.eye(5), 2)
    with pytest.raises(ValueError):
        generalized_chi2_quantiles(np.zeros(4), [0.5])
    with pytest.raises(ValueError):
        generalized_chi2_quantiles(np.ones(4), [1.0])
    with pytest.raises(ValueError):
        anees_bounds_of_eigenvalues([np.ones(3)], 2)
