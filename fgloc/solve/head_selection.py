"""Model selection of the head: the Bayes score test of the ideal head against the head population.

The question ``--head-model auto`` asks is whether the readings show head errors of the kind
the prior describes (a zero-mean Gaussian population, one sigma per parameter,
:data:`fgloc.core.head_model.DEFAULT_PRIOR_SIGMAS`). Linearized, with the poses and nodes
eliminated, the readings see a head vector ``h`` through their whitened residuals
``r = J h + e`` (``e`` standard normal). Against the alternative ``h ~ N(0, P)`` the most
powerful test of ``h = 0`` (Neyman-Pearson: the likelihood ratio of the two marginal
distributions of ``r``) rejects for large

    ``S = r' J (P^-1 + F)^-1 J' r``,  ``F = J'J`` the head's data-only information,

which is what the extended fit already holds: ``S = chi2_data(ideal) - chi2_data(extended)
- chi2_prior(extended)`` at the extended MAP estimate (``h_hat = (P^-1 + F)^-1 J' r``).
Under the ideal head ``S = sum_i mu_i z_i^2`` with ``z_i`` standard normal and
``mu_i = lambda_i / (1 + lambda_i)``, ``lambda_i`` the eigenvalues of ``P^(1/2) F P^(1/2)``
(the prior-whitened information). Directions the readings hardly see (``lambda`` near 0)
weigh almost nothing, where the plain likelihood-ratio test (``chi2(ideal) - chi2(extended)``
against chi-square with k dof) spends a whole degree of freedom on each; with one strongly
seen direction and thirteen faint ones that dilution is what kept the ideal head in most
surveys whose heads had errors (docs/head-calibration.md, "Model selection").

The null distribution is a weighted sum of chi-square(1) variables; its tail is computed by
seeded Monte Carlo (:func:`weighted_chi2_sf`), deterministic for a given survey.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray

#: Level of the Bayes score test (P(reject | ideal head)). Chosen on the paper scene's Monte
#: Carlo (docs/head-calibration.md): at 1 % the ideal head is kept on >= 99 % of clean
#: surveys (their accuracy within 1.03x of the ideal solve), while surveys with heads from
#: the population are solved within 1.1x of the extended model's Cramer-Rao bound.
SCORE_ALPHA = 0.01
#: Draws of the null distribution's Monte Carlo: the p-value's standard error at 1 % is 0.0002.
NULL_DRAWS = 200_000


@dataclass(frozen=True)
class ScoreTest:
    """The Bayes score test's outcome: ``statistic`` S, the level-``alpha`` ``threshold``
    (the null's 1 - alpha quantile), the ``p_value`` P(S_null >= S), and the null's
    ``weights`` mu_i (in [0, 1), largest first)."""

    statistic: float
    threshold: float
    p_value: float
    weights: FloatArray
    alpha: float

    @property
    def rejects_ideal(self) -> bool:
        return self.p_value < self.alpha


def null_weights(whitened_information: FloatArray) -> FloatArray:
    """``mu_i = lambda_i / (1 + lambda_i)`` for the eigenvalues of the prior-whitened data-only
    information of the head parameters (symmetric, positive semidefinite), largest first."""
    info = np.asarray(whitened_information, dtype=float)
    lam = np.clip(np.linalg.eigvalsh(0.5 * (info + info.T)), 0.0, None)
    return np.sort(lam / (1.0 + lam))[::-1]


def _null_draws(weights: FloatArray, draws: int, seed: int, chunk: int = 20_000) -> FloatArray:
    """``draws`` seeded samples of sum_i w_i z_i^2, drawn in chunks of rows so that memory stays
    ~chunk x len(weights) doubles (a Generator's consecutive draws continue one stream: the
    samples equal those of one (draws, k) draw)."""
    rng = np.random.default_rng(seed)
    w = np.asarray(weights, dtype=float)
    out = np.empty(draws)
    for start in range(0, draws, chunk):
        z = rng.standard_normal((min(chunk, draws - start), len(w)))
        out[start:start + len(z)] = (z * z) @ w
    return out


def weighted_chi2_sf(x: float, weights: FloatArray, draws: int = NULL_DRAWS, seed: int = 0) -> float:
    """P(sum_i w_i z_i^2 >= x), z_i independent standard normal (seeded Monte Carlo)."""
    if len(weights) == 0:
        return 0.0 if x > 0.0 else 1.0
    return float(np.mean(_null_draws(weights, draws, seed) >= x))


def bayes_score_test(chi2_ideal: float, chi2_extended: float, prior_chi2: float,
                     whitened_information: FloatArray, alpha: float = SCORE_ALPHA,
                     draws: int = NULL_DRAWS, seed: int = 0) -> ScoreTest:
    """Test the ideal head on one set of readings.

    ``chi2_ideal`` and ``chi2_extended`` are the bearings' chi-square (no prior) at the ideal
    and at the extended MAP solution of the same readings, ``prior_chi2`` the head prior's
    chi-square ``sum (h_hat / sigma)^2`` at the latter, ``whitened_information`` the data-only
    information of the estimated head parameters in prior-sigma units (poses and nodes
    eliminated).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
    weights = null_weights(whitened_information)
    statistic = float(chi2_ideal - chi2_extended - prior_chi2)
    null = _null_draws(weights, draws, seed) if len(weights) else np.zeros(1)
    p_value = float(np.mean(null >= statistic))
    threshold = float(np.quantile(null, 1.0 - alpha))
    if not math.isfinite(statistic):
        p_value = 0.0
    return ScoreTest(statistic, threshold, p_value, weights, alpha)
