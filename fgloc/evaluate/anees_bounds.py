"""Bounds of the per-node ANEES when a scene's nodes are correlated.

The per-node ANEES of a benchmark is the mean over all its nodes of ``e_i^T P_ii^-1 e_i``
(``e_i`` a node's position error, ``P_ii`` its marginal covariance, ``d`` = 2 planar or 3
dof). Summed over one scene it is ``S = e^T D^-1 e``, ``e`` the scene's stacked node errors,
``C`` their joint covariance and ``D`` the block diagonal of ``C``'s ``d x d`` diagonal
blocks (the marginals). For ``e ~ N(0, C)``, ``S`` is a generalized chi-square
``sum_k lambda_k chi2_1``, ``lambda`` the eigenvalues of ``D^-1/2 C D^-1/2``: its mean is
``d N`` as for independent nodes (the eigenvalues sum to the trace, ``d N``) but its
variance ``2 sum lambda_k^2`` exceeds ``2 d N`` as soon as the nodes correlate (a scene's
nodes share its camera-pose errors). Over independent scenes the eigenvalues pool. The
bounds here are quantiles of that distribution over the total node count; with
block-diagonal ``C`` they are the independent-node chi-square bounds
``chi2.ppf(p, d N) / N``.

Quantiles come from Imhof's (1961) inversion of the characteristic function, integrated
numerically, rather than from a Monte Carlo of ``sum lambda_k chi2_1``: the result is
deterministic and accurate to about 1e-9 in probability (block-diagonal covariances give
the chi-square bounds to that), and takes about 0.3 s for ~1000 eigenvalues. A Monte Carlo
would need ~1e4 sums of ~1000 chi2_1 draws to pin the bounds to ~1e-3, and would still
differ from the chi-square bounds by that much.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.special import roots_legendre

_TAIL_PROBABILITY = 1e-11  # the integral's truncation error allowed, in probability
_GRID_END_CAP = 400.0  # normalized frequency beyond which QAWF integrates the tail (few eigenvalues)
_LEGENDRE_NODES, _LEGENDRE_WEIGHTS = roots_legendre(20)


def node_nees_eigenvalues(covariance: np.ndarray, dim: int) -> np.ndarray:
    """Eigenvalues (ascending, ``dim N`` of them) of ``D^-1/2 C D^-1/2`` for one scene.

    ``covariance`` is ``C``, the (dim N, dim N) joint covariance of the scene's ``N`` node
    positions stacked node by node (``dim`` = 2 planar x, y; 3 for x, y, z; any consistent
    unit: the result is dimensionless). ``D`` keeps only ``C``'s ``dim x dim`` diagonal
    blocks, the nodes' marginals. The sum of the scene's per-node NEES under those marginals
    is then ``sum_k lambda_k chi2_1`` for errors drawn from ``C``. The eigenvalues sum to
    ``dim N``; all equal 1 when the nodes are independent. Tiny negative round-off is
    clipped to 0.
    """
    c = np.asarray(covariance, float)
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] % dim:
        raise ValueError(f"covariance must be square with a multiple of {dim} rows, got shape {c.shape}")
    n = c.shape[0] // dim
    blocks = c.reshape(n, dim, n, dim)[np.arange(n), :, np.arange(n), :]  # (n, dim, dim) marginals
    inverse_factors = np.linalg.inv(np.linalg.cholesky(blocks))  # L_i^-1 with P_ii = L_i L_i^T
    whitening = np.zeros_like(c)
    for i in range(n):
        whitening[i * dim:(i + 1) * dim, i * dim:(i + 1) * dim] = inverse_factors[i]
    whitened = whitening @ c @ whitening.T  # similar to D^-1 C: the same eigenvalues
    eigenvalues = np.linalg.eigvalsh(0.5 * (whitened + whitened.T))
    if eigenvalues[0] < -1e-9 * max(eigenvalues[-1], 1.0):
        raise ValueError(f"covariance is not positive semi-definite (eigenvalue {eigenvalues[0]:.3g})")
    return np.clip(eigenvalues, 0.0, None)


def generalized_chi2_quantiles(eigenvalues: np.ndarray, probabilities: Sequence[float]) -> np.ndarray:
    """Quantiles of ``Q = sum_k lambda_k chi2_1`` (independent chi-square variables of 1 dof,
    ``lambda`` = ``eigenvalues``, all >= 0 and not all 0) at ``probabilities`` (each in (0, 1)).

    Imhof (1961): ``P(Q > x) = 1/2 + 1/pi int_0^inf sin(theta(u)) / (u rho(u)) du`` with
    ``theta(u) = sum_k arctan(lambda_k u) / 2 - x u / 2`` and ``rho(u) = prod_k (1 +
    lambda_k^2 u^2)^(1/4)``. The weights are scaled to sum 1 (so ``x`` is in units of the
    mean). The integral runs on composite 20-point Gauss-Legendre panels, geometric near 0
    (where ``rho`` turns at ``u ~ 1 / lambda_k``) and at most 3 rad of phase wide further
    out, up to where the tail is below 1e-11 in probability. That bound: for ``u >= U``,
    ``rho(u) >= rho(U) (u / U)^s`` with ``s = sum_k q_k / 2``, ``q_k = lambda_k^2 U^2 / (1 +
    lambda_k^2 U^2)`` (Bernoulli's inequality per factor), so the tail is at most ``1 / (pi
    s rho(U))``. Few eigenvalues decay only as a power of ``u``; there the grid stops at
    ``max(400, 20 / sd)`` (``sd`` the standard deviation of ``Q`` over its mean; the
    characteristic function is then below ``exp(-50)`` wherever ``Q`` is near normal) and
    QUADPACK's Fourier rule (QAWF) integrates the rest. Each quantile is the
    root of the CDF by Brent's method to 1e-12 of the mean.
    """
    lam = np.asarray(eigenvalues, float).ravel()
    if lam.size == 0 or np.any(lam < 0) or not np.any(lam > 0) or not np.all(np.isfinite(lam)):
        raise ValueError("eigenvalues must be finite, >= 0 and not all 0")
    ps = [float(p) for p in probabilities]
    if not all(0.0 < p < 1.0 for p in ps):
        raise ValueError(f"probabilities must lie in (0, 1), got {ps}")
    scale = float(lam.sum())
    w = lam[lam > 0] / scale
    sd = math.sqrt(2.0 * float(np.sum(w * w)))
    # Cantelli: P(Q >= 1 + k sd) <= 1 / (1 + k^2), so every quantile asked lies below x_max
    x_max = 1.0 + sd * math.sqrt(max(ps) / (1.0 - max(ps)))
    cdf = _ImhofCdf(w, x_max, max(_GRID_END_CAP, 20.0 / sd))
    return scale * np.array([brentq(lambda x: cdf(x) - p, 0.0, x_max, xtol=1e-12, rtol=1e-12) for p in ps])


class _ImhofCdf:
    """``P(Q <= x)`` for ``Q = sum_k w_k chi2_1``, ``sum w = 1``, ``0 <= x <= x_max``: the
    x-independent parts of Imhof's integrand are tabulated once on the quadrature nodes."""

    def __init__(self, w: np.ndarray, x_max: float, end_cap: float) -> None:
        self.w = w
        end = 1.0 / float(w.max())
        while self._tail_bound(end) > _TAIL_PROBABILITY and end < end_cap:
            end *= 2.0
        end = min(end, end_cap)
        self.end, self.needs_tail = end, self._tail_bound(end) > _TAIL_PROBABILITY
        phase_rate = 0.5 * (1.0 + x_max)  # bounds |d theta / du| for every x <= x_max
        start = 1e-3 / float(w.max())
        edges = np.unique(np.concatenate([[0.0, end], np.geomspace(start, end, 60) if start < end else []]))
        pieces = np.maximum(1, np.ceil(np.diff(edges) * phase_rate / 3.0)).astype(int)  # <= 3 rad of phase a panel
        edges = np.concatenate([np.linspace(a, b, k + 1)[:-1] for a, b, k in zip(edges[:-1], edges[1:], pieces)]
                               + [[end]])
        half, middle = 0.5 * np.diff(edges), 0.5 * (edges[:-1] + edges[1:])
        self.u = (middle[:, None] + half[:, None] * _LEGENDRE_NODES[None, :]).ravel()
        self.half_arctan, log_rho = self._phase_and_log_rho(self.u)
        self.coefficient = (half[:, None] * _LEGENDRE_WEIGHTS[None, :]).ravel() / (self.u * np.exp(log_rho))

    def _phase_and_log_rho(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``sum_k arctan(w_k u) / 2`` and ``log rho(u)`` at each of ``u`` (1-d)."""
        wu = np.multiply.outer(u, self.w)
        return 0.5 * np.arctan(wu).sum(axis=1), 0.25 * np.log1p(wu * wu).sum(axis=1)

    def _tail_bound(self, end: float) -> float:
        """Bound on ``|int_end^inf sin(theta) / (u rho) du| / pi`` (see
        :func:`generalized_chi2_quantiles`)."""
        wu2 = (self.w * end) ** 2
        return math.exp(-0.25 * float(np.sum(np.log1p(wu2)))) / (math.pi * 0.5 * float(np.sum(wu2 / (1.0 + wu2))))

    def _tail(self, x: float) -> float:
        """``int_end^inf sin(theta(u)) / (u rho(u)) du`` by QAWF, with ``sin(a - x u / 2) = sin a
        cos(x u / 2) - cos a sin(x u / 2)``, ``a`` the slowly turning arctan sum."""
        def envelope(u: float, trig: Callable[[float], float]) -> float:
            half_arctan, log_rho = self._phase_and_log_rho(np.array([u]))
            return trig(float(half_arctan[0])) * math.exp(-float(log_rho[0])) / u

        options = {"wvar": 0.5 * x, "limlst": 200, "epsabs": 1e-12}
        sin_part = quad(envelope, self.end, np.inf, args=(math.sin,), weight="cos", **options)[0]
        cos_part = quad(envelope, self.end, np.inf, args=(math.cos,), weight="sin", **options)[0]
        return float(sin_part - cos_part)

    def __call__(self, x: float) -> float:
        if x <= 0.0:
            return 0.0
        integral = float(np.dot(self.coefficient, np.sin(self.half_arctan - 0.5 * x * self.u)))
        if self.needs_tail:
            integral += self._tail(x)
        return 0.5 - integral / math.pi


def anees_bounds_of_eigenvalues(eigenvalues: Sequence[np.ndarray], dim: int,
                                probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` bounds (lower, upper) of the per-node ANEES over independent
    scenes, from each scene's :func:`node_nees_eigenvalues` (``dim`` per node): the
    ``(1 - probability) / 2`` and ``(1 + probability) / 2`` quantiles of the pooled
    ``sum_k lambda_k chi2_1`` over the total node count."""
    pooled = np.concatenate([np.asarray(e, float).ravel() for e in eigenvalues])
    if pooled.size == 0 or pooled.size % dim:
        raise ValueError(f"{pooled.size} eigenvalues is not a positive multiple of dim {dim}")
    tail = 0.5 * (1.0 - probability)
    lo, hi = generalized_chi2_quantiles(pooled, [tail, 1.0 - tail]) / (pooled.size // dim)
    return float(lo), float(hi)


def anees_bounds(covariances: Sequence[np.ndarray], dim: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` bounds (lower, upper) of the per-node ANEES (the mean over
    all nodes of all scenes of ``e_i^T P_ii^-1 e_i``, ``dim`` dof each, ``P_ii`` the node's
    marginal) when each scene's errors follow its joint covariance and scenes are independent.

    ``covariances``: per scene the (dim N, dim N) joint covariance of its node positions,
    stacked node by node (:func:`fgloc.evaluate.joint_nees.joint_node_covariance`; any unit,
    the bounds are dimensionless). Block-diagonal covariances give the independent-node
    bounds ``chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], dim N) / N``.
    """
    return anees_bounds_of_eigenvalues([node_nees_eigenvalues(c, dim) for c in covariances], dim, probability)
