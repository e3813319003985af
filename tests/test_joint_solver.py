"""The joint solve against known truth, the Cramér–Rao bound and covariance honesty."""

import numpy as np
import pytest

from fgloc.core.model import CameraPose
from fgloc.evaluate.crlb import cramer_rao_bound
from fgloc.evaluate.score import CHI2_95, nees, score
from fgloc.init.start import InitialEstimate
from fgloc.sim.scenes import PAPER_SIGMA, PaperScenario, paper_scenario
from fgloc.solve.joint import build_problem, solve, solve_survey


def test_noise_free_survey_recovers_truth_exactly() -> None:
    """Truth: readings without noise (the noise model still says 0.1 degree), so the optimum is the true scene."""
    survey = paper_scenario(PaperScenario(n_nodes=40, sigma=1e-15, heights=(0.07, 0.3), seed=11))
    survey.sigma = PAPER_SIGMA
    result = solve_survey(survey)
    assert result.stats.converged
    for n in survey.node_ids:
        np.testing.assert_allclose(result.nodes[n].position, survey.truth.nodes[n], atol=1e-9)
    for c in survey.camera_ids:
        np.testing.assert_allclose(result.cameras[c].position, survey.truth.cameras[c].position, atol=1e-9)
        np.testing.assert_allclose(result.cameras[c].rotation, survey.truth.cameras[c].rotation, atol=1e-9)


@pytest.mark.parametrize("seed", [3, 17])
def test_reaches_the_optimum_found_from_the_truth(seed: int) -> None:
    """Global optimum: starting from our closed form must end at the same cost as starting at the truth."""
    survey = paper_scenario(PaperScenario(seed=seed, heights=(0.05, 0.45)))
    ours = solve_survey(survey)
    truth = survey.truth
    start = InitialEstimate(cameras=dict(truth.cameras), nodes=dict(truth.nodes))
    from_truth = solve(build_problem(survey, start))
    assert ours.stats.final_error == pytest.approx(from_truth.stats.final_error, rel=1e-7)
    for n in survey.node_ids:
        np.testing.assert_allclose(ours.nodes[n].position, from_truth.nodes[n].position, atol=1e-8)


def test_final_error_matches_chi_square_expectation() -> None:
    """At the optimum 2*error ~ chi-square with (2M - P) degrees of freedom (P = unknowns - gauge)."""
    survey = paper_scenario(PaperScenario(n_nodes=100, seed=8))
    result = solve_survey(survey)
    dof = 2 * len(survey.observations) - (2 * 100 + 12 - 4)
    assert abs(2 * result.stats.final_error - dof) < 4 * np.sqrt(2 * dof)


def test_repeated_readings_shrink_the_covariance() -> None:
    """Each repeat is an independent factor: R repeats divide the covariance by about R."""
    one = solve_survey(paper_scenario(PaperScenario(n_nodes=30, seed=2, repeats=1)))
    four = solve_survey(paper_scenario(PaperScenario(n_nodes=30, seed=2, repeats=4)))
    ratio = np.median([np.trace(one.nodes[n].covariance) / np.trace(four.nodes[n].covariance) for n in one.nodes])
    assert 3.6 < ratio < 4.4


@pytest.mark.slow
def test_monte_carlo_efficiency_and_consistency() -> None:
    """Statistical truth over 50 seeded scenes of the paper's scenario (heights 0.05-0.5, random bases).

    * The ML estimate is efficient: RMS node error within 10% of the Cramér–Rao bound
      (a wrong Jacobian converges elsewhere or inflates the error).
    * The marginal covariance is honest: ANEES in [1.8, 2.2] (chi-square, 2 dof) and
      93-97% of nodes inside their 95% ellipse (a covariance off by a factor 1.5 fails both).
    """
    rng = np.random.default_rng(2024)
    sq_err, bound, nees_all = [], [], []
    for seed in range(50):
        heights = tuple(rng.uniform(0.05, 0.5, size=2))
        survey = paper_scenario(PaperScenario(seed=5000 + seed, heights=heights))
        result = solve_survey(survey)
        assert result.stats.converged, f"seed {seed} did not converge"
        crb = cramer_rao_bound(survey)
        err = np.array([result.nodes[n].position[:2] - survey.truth.nodes[n][:2] for n in survey.node_ids])
        cov = np.array([result.nodes[n].covariance for n in survey.node_ids])
        sq_err.extend((err**2).sum(1))
        bound.extend(np.trace(crb[n]) for n in survey.node_ids)
        nees_all.extend(nees(err, cov))
    ratio = np.sqrt(np.mean(sq_err)) / np.sqrt(np.mean(bound))
    assert 0.9 <= ratio <= 1.1, ratio
    nees_all = np.array(nees_all)
    assert 1.8 <= nees_all.mean() <= 2.2, nees_all.mean()
    inside = np.mean(nees_all <= CHI2_95[2])
    assert 0.93 <= inside <= 0.97, inside


def test_score_of_truth_is_zero_and_wrong_covariance_is_caught() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=50, seed=4))
    result = solve_survey(survey)
    s = score(survey, result)
    assert s.n_nodes == 50 and s.median_m == pytest.approx(100 * s.median)
    # Inflate every covariance 4x: ANEES must drop to about a quarter.
    for est in result.nodes.values():
        object.__setattr__(est, "covariance", est.covariance * 4)
    assert score(survey, result).anees == pytest.approx(s.anees / 4, rel=1e-9)


def test_camera_poses_in_gauge_frame() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=60, seed=9, heights=(0.2, 0.1)))
    result = solve_survey(survey)
    cams: dict[str, CameraPose] = result.cameras
    np.testing.assert_allclose(cams["cam0"].position[:2], [0, 0], atol=1e-6)
    np.testing.assert_allclose(cams["cam1"].position[:2], [1, 0], atol=1e-6)
    assert abs(cams["cam0"].position[2] - 0.2) < 0.01 and abs(cams["cam1"].position[2] - 0.1) < 0.01
