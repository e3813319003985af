"""The Bayes score test of the ideal head (fgloc.solve.head_selection), checked on the
linear-Gaussian model it is derived from: exact level under the ideal head, more power
than the plain likelihood-ratio test against heads from the prior's population."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.solve.head_selection import bayes_score_test, null_weights, weighted_chi2_sf
from fgloc.solve.self_calibration import chi2_quantile


def test_weighted_chi2_with_unit_weights_is_chi_square() -> None:
    for k in (1, 3, 14):
        q = chi2_quantile(0.95, k)
        assert weighted_chi2_sf(q, np.ones(k)) == pytest.approx(0.05, abs=0.002)


def test_chunked_null_draws_equal_one_draw() -> None:
    from fgloc.solve.head_selection import _null_draws

    w = np.array([0.9, 0.3, 0.01])
    z = np.random.default_rng(7).standard_normal((50_001, 3))
    np.testing.assert_allclose(_null_draws(w, 50_001, 7, chunk=20_000), (z * z) @ w, rtol=1e-12)


def test_null_weights_are_lambda_over_one_plus_lambda() -> None:
    a = np.random.default_rng(1).standard_normal((5, 3))
    info = a.T @ a
    lam = np.linalg.eigvalsh(info)
    np.testing.assert_allclose(null_weights(info), np.sort(lam / (1 + lam))[::-1], rtol=1e-12)


def _linear_fit(J: np.ndarray, r: np.ndarray) -> tuple[float, float, float]:
    """chi2 of the ideal head, of the MAP head under a unit prior, and the prior's chi2."""
    F = J.T @ J
    h = np.linalg.solve(np.eye(J.shape[1]) + F, J.T @ r)
    return float(r @ r), float(np.sum((r - J @ h) ** 2)), float(h @ h)


def _design(rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """Whitened head Jacobian: one direction seen strongly (lambda ~ 20), six faintly (~0.3)."""
    q, _ = np.linalg.qr(rng.standard_normal((n, 7)))
    return q * np.sqrt(np.array([20.0, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3]))


def test_statistic_is_the_marginal_likelihood_ratio_quadratic_form() -> None:
    rng = np.random.default_rng(2)
    J = _design(rng)
    r = rng.standard_normal(J.shape[0])
    test = bayes_score_test(*_linear_fit(J, r), J.T @ J, draws=20_000)
    F = J.T @ J
    expected = r @ J @ np.linalg.solve(np.eye(7) + F, J.T @ r)
    assert test.statistic == pytest.approx(expected, rel=1e-9)


def test_level_under_the_ideal_head_and_power_against_the_population() -> None:
    rng = np.random.default_rng(3)
    J = _design(rng)
    F = J.T @ J
    alpha, runs = 0.05, 1500
    threshold = bayes_score_test(0.0, 0.0, 0.0, F, alpha=alpha).threshold  # depends on F only

    def score(fit: tuple[float, float, float]) -> float:
        return fit[0] - fit[1] - fit[2]

    lr_thr = chi2_quantile(1 - alpha, 7)
    rejected_null = rejected_alt = lr_alt = unit_null = 0
    for _ in range(runs):
        e = rng.standard_normal(J.shape[0])
        s0 = score(_linear_fit(J, e))
        rejected_null += s0 > threshold
        unit_null += s0 > lr_thr
        h = rng.standard_normal(7)  # a head from the prior's population (unit sigmas)
        r = J @ h + e
        rejected_alt += score(_linear_fit(J, r)) > threshold
        lr = r @ J @ np.linalg.solve(F, J.T @ r)  # plain LR: chi2(ideal) - chi2(unregularized), chi2(7)
        lr_alt += lr > lr_thr
    # Level: binomial sd at 5 % over 1500 runs is 0.56 %; the chi2(7) threshold (unit weights)
    # rejects far less often than its nominal 5 %.
    assert 0.035 < rejected_null / runs < 0.065
    assert unit_null / runs < 0.01
    assert rejected_alt > lr_alt + 0.03 * runs, (rejected_alt, lr_alt)
    last = bayes_score_test(*_linear_fit(J, r), F, alpha=alpha)
    assert last.rejects_ideal == (last.statistic > last.threshold)
