"""The joint NEES of a scene's nodes: joint covariance against the solver's marginals, and a
seeded Monte Carlo in which the honest covariance passes and a wrong one fails."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from fgloc.evaluate.joint_nees import joint_nees, joint_node_covariance
from fgloc.evaluate.score import nees
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey


def test_diagonal_blocks_are_the_solvers_marginals_and_nodes_correlate():
    survey = paper_scenario(PaperScenario(n_nodes=30, seed=7, heights=(0.2, 0.1)))
    result = solve_survey(survey)
    covariance, order = joint_node_covariance(survey, result)
    assert covariance.shape == (2 * len(order), 2 * len(order)) and sorted(order) == sorted(result.nodes)
    for k, node in enumerate(order):
        block = covariance[2 * k:2 * k + 2, 2 * k:2 * k + 2]
        np.testing.assert_allclose(block, result.nodes[node].covariance, rtol=1e-4, atol=1e-14)
    # shared camera errors: off-diagonal blocks are not zero
    std = np.sqrt(np.diag(covariance))
    correlation = covariance / np.outer(std, std)
    off = correlation[np.triu_indices_from(correlation, k=2)]
    assert np.max(np.abs(off)) > 0.3


def test_joint_nees_is_chi_square_over_seeded_scenes():
    """40 scenes of 25 nodes (50 dof each, 2000 in all).

    * Mean: the summed joint NEES is inside its two-sided 95 % chi-square bounds; under the
      covariance scaled by 0.75 or 1.33 it is not.
    * Spread: the scenes' joint NEES vary as chi-square(50) does (variance 100; accepted
      50-200). The nodes' own marginals alone (the correlations dropped) keep the mean but
      vary about ten times more, because a scene's nodes share its camera errors.
    """
    joint, dropped, dof = [], [], 0
    for seed in range(40):
        survey = paper_scenario(PaperScenario(n_nodes=25, seed=8000 + seed, heights=(0.15, 0.1)))
        result = solve_survey(survey)
        value, n = joint_nees(survey, result, survey.truth.nodes)
        joint.append(value)
        dof += n
        errors = np.array([result.nodes[k].position[:2] - survey.truth.nodes[k][:2] for k in result.nodes])
        dropped.append(float(nees(errors, np.array([result.nodes[k].covariance for k in result.nodes])).sum()))
    total = sum(joint)
    lo, hi = chi2.ppf([0.025, 0.975], dof)
    assert lo <= total <= hi, (total / dof, lo / dof, hi / dof)
    assert not lo <= total / 0.75 <= hi and not lo <= total / 1.33 <= hi
    assert 50 <= np.var(joint, ddof=1) <= 200, np.var(joint, ddof=1)
    assert np.var(dropped, ddof=1) > 200, np.var(dropped, ddof=1)


def test_joint_nees_of_the_truth_is_zero():
    survey = paper_scenario(PaperScenario(n_nodes=10, seed=3))
    result = solve_survey(survey)
    value, n = joint_nees(survey, result, {k: v.position for k, v in result.nodes.items()})
    assert n == 20 and value == pytest.approx(0.0, abs=1e-18)
