"""Globally convergent Newton in the style of Numerical Recipes' ``newt`` + ``lnsrch``,
on S subset systems at once: Gauss-Newton step by QR, backtracking line search
(quadratic then cubic), convergence and failure tests (chi-square for spurious minima).

Residuals are whitened (units of sigma); ``f = |F|^2 / 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgloc.baselines.subset_options import STATUS_OK, SubsetNewtonOptions
from fgloc.baselines.subset_system import SubsetReadings, SubsetState, residuals, residuals_and_jacobian
from fgloc.core.geometry import (
    FloatArray,
)


def gauss_newton_step(J: FloatArray, F: FloatArray, rank_tol: float = 1e-10) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Least-squares Newton step ``argmin |J dx + F|`` by batched QR.

    Returns the step (S, n), the upper-triangular factor (S, n, n) and a bool
    (S,) that is True where J is rank deficient (step set to zero there).
    """
    short = J.shape[2] - J.shape[1]
    if short > 0:  # fewer residuals than unknowns: pad with zero rows (rank deficient)
        J = np.concatenate([J, np.zeros((J.shape[0], short, J.shape[2]))], axis=1)
        F = np.concatenate([F, np.zeros((F.shape[0], short))], axis=1)
    Q, Rt = np.linalg.qr(J)
    d = np.abs(np.diagonal(Rt, axis1=-2, axis2=-1))
    deficient = ~np.all(np.isfinite(Rt), axis=(1, 2)) | (d.min(axis=1) <= rank_tol * np.maximum(d.max(axis=1), 1e-300))
    Rs = np.where(deficient[:, None, None], np.eye(Rt.shape[-1]), Rt)
    rhs = np.where(deficient[:, None], 0.0, -np.einsum("smn,sm->sn", Q, F))
    rhs = np.nan_to_num(rhs)
    step = np.linalg.solve(Rs, rhs[..., None])[..., 0]
    return step, Rs, deficient


def line_search(
    state: SubsetState,
    obs: SubsetReadings,
    fold: FloatArray,
    grad: FloatArray,
    step: FloatArray,
    stpmax: FloatArray,
    tolx: float,
    active: np.ndarray,
    alf: float = 1e-4,
    max_backtracks: int = 40,
) -> tuple[SubsetState, FloatArray, np.ndarray]:
    """Numerical Recipes ``lnsrch``, vectorized over subsets.

    Backtracks along ``step`` until ``f(x + lam p) <= f(x) + alf lam grad.p``
    (sufficient decrease), with quadratic then cubic models of f(lam) and
    lam kept in [0.1, 0.5] of the previous trial. Returns the new state, its f
    and ``check`` (S,) bool: True where lam fell below the TOLX-scaled minimum
    and x was left unchanged (converged on dx, or a spurious stall). Subsets
    not ``active`` are left unchanged. f never increases.
    """
    S = step.shape[0]
    p = step.copy()
    norm = np.linalg.norm(p, axis=1)
    too_long = norm > stpmax
    p[too_long] *= (stpmax[too_long] / norm[too_long])[:, None]
    slope = np.einsum("sn,sn->s", grad, p)
    test = np.max(np.abs(p) / np.maximum(state.scale(), 1.0), axis=1)
    alamin = tolx / np.maximum(test, 1e-300)
    alam = np.ones(S)
    alam2 = np.zeros(S)
    f2 = np.zeros(S)
    new = state.copy()
    fnew = fold.copy()
    check = np.zeros(S, dtype=bool)
    pending = active & (slope < 0)
    check |= active & (slope >= 0)  # roundoff: not a descent direction
    first = np.ones(S, dtype=bool)
    for _ in range(max_backtracks):
        if not pending.any():
            break
        rows = np.flatnonzero(pending)
        sub = SubsetState(state.R[rows], state.h[rows], state.xy[rows])
        trial = sub.retract(alam[rows, None] * p[rows])
        Ft = residuals(trial, obs.take(rows))
        ft = 0.5 * np.einsum("sm,sm->s", Ft, Ft)
        ft = np.where(np.isfinite(ft), ft, np.inf)
        ok = ft <= fold[rows] + alf * alam[rows] * slope[rows]
        acc = rows[ok]
        new.R[acc], new.h[acc], new.xy[acc] = trial.R[ok], trial.h[ok], trial.xy[ok]
        fnew[acc] = ft[ok]
        pending[acc] = False
        stall = rows[~ok & (alam[rows] < alamin[rows])]
        check[stall] = True
        pending[stall] = False
        back = rows[~ok & (alam[rows] >= alamin[rows])]
        if back.size == 0:
            continue
        fb = ft[~ok & (alam[rows] >= alamin[rows])]
        lam, sl, f0 = alam[back], slope[back], fold[back]
        quad = -sl / (2.0 * np.where(np.isfinite(fb), fb - f0 - sl, np.inf))
        lam2, fprev = alam2[back], f2[back]
        with np.errstate(all="ignore"):
            rhs1 = fb - f0 - lam * sl
            rhs2 = fprev - f0 - lam2 * sl
            a = (rhs1 / lam**2 - rhs2 / lam2**2) / (lam - lam2)
            b = (-lam2 * rhs1 / lam**2 + lam * rhs2 / lam2**2) / (lam - lam2)
            disc = b * b - 3.0 * a * sl
            cubic = np.where(
                a == 0.0,
                -sl / (2.0 * b),
                np.where(b <= 0.0, (-b + np.sqrt(np.maximum(disc, 0))) / (3.0 * a), -sl / (b + np.sqrt(np.maximum(disc, 0)))),
            )
            cubic = np.where(disc < 0, 0.5 * lam, cubic)
        tmp = np.where(first[back], quad, cubic)
        tmp = np.where(np.isfinite(tmp), np.minimum(tmp, 0.5 * lam), 0.5 * lam)
        alam2[back], f2[back] = lam, np.where(np.isfinite(fb), fb, fold[back])
        alam[back] = np.maximum(tmp, 0.1 * lam)
        first[back] = False
    check[pending] = True  # ran out of backtracks: leave x unchanged
    return new, fnew, check


def chi2_quantile(p: float, dof: FloatArray) -> FloatArray:
    """Wilson-Hilferty approximation of the chi-square quantile (accurate to ~1% for dof >= 2)."""
    z = _normal_quantile(p)
    d = np.maximum(np.asarray(dof, dtype=float), 1.0)
    return d * (1.0 - 2.0 / (9.0 * d) + z * np.sqrt(2.0 / (9.0 * d))) ** 3


def _normal_quantile(p: float) -> float:
    """Standard normal quantile by bisection on erf (no scipy at run time)."""
    lo, hi = -10.0, 10.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if 0.5 * (1.0 + math.erf(mid / math.sqrt(2.0))) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass
class NewtonOutcome:
    """Per-subset outcome of :func:`solve_subsets`."""

    state: SubsetState
    f: FloatArray  # final 0.5 |F|^2
    f_initial: FloatArray  # 0.5 |F|^2 at the start
    status: np.ndarray  # (S,) object array of status strings
    iterations: np.ndarray
    covariance: FloatArray  # (S, n, n) Gauss-Newton covariance (J^T J)^-1, whitened units folded in


def solve_subsets(state0: SubsetState, obs: SubsetReadings, options: SubsetNewtonOptions = SubsetNewtonOptions()) -> NewtonOutcome:
    """Globally convergent Newton (``newt`` + ``lnsrch``) on S subsets at once."""
    state = state0.copy()
    S, n = state.h.shape[0], state.n_params
    m = 2 * obs.mask.sum(axis=1)
    status = np.full(S, "", dtype=object)
    status[m < n + 1] = "underdetermined"
    iterations = np.zeros(S, dtype=np.int64)
    F, J = residuals_and_jacobian(state, obs)
    f = 0.5 * np.einsum("sm,sm->s", F, F)
    f_initial = f.copy()
    x_norm = np.linalg.norm(np.concatenate([state.h, state.xy.reshape(S, -1)], axis=1), axis=1)
    stpmax = 100.0 * np.maximum(x_norm, float(n))  # NR's STPMX
    active = status == ""
    for it in range(options.max_iterations + 1):
        step, _, deficient = gauss_newton_step(J, F)
        status[active & deficient] = "degenerate"
        active &= ~deficient
        grad = np.einsum("smn,sm->sn", J, F)
        # Gauss-Newton decrement |Q^T F|^2 = -grad . step: twice the reduction of f
        # the full step predicts; it vanishes at a stationary point of f.
        decrement = -np.einsum("sn,sn->s", grad, step)
        converged = active & (decrement <= options.tol_decrement * np.maximum(f, 1.0))
        status[converged] = STATUS_OK
        active &= ~converged
        if not active.any() or it == options.max_iterations:
            break
        iterations[active] += 1
        new, fnew, check = line_search(state, obs, f, grad, step, stpmax, options.tolx, active)
        scale = np.maximum(new.scale(), 1.0)[:, np.r_[0:2, 8:n]]
        moved = np.concatenate([new.h - state.h, (new.xy - state.xy).reshape(S, -1)], axis=1)
        small_step = active & ~check & (np.max(np.abs(moved) / scale, axis=1) < options.tolx)
        # The line search cannot decrease f: fine if f is at its minimum to within
        # roundoff (tiny decrement), otherwise NR's "spurious convergence".
        stalled = active & check
        flat = stalled & (decrement <= options.tol_stall * np.maximum(f, 1.0))
        status[small_step | flat] = STATUS_OK
        status[stalled & ~flat] = "no-convergence"
        active &= ~(small_step | stalled)
        state, f = new, fnew
        F, J = residuals_and_jacobian(state, obs)
    status[active] = "no-convergence"
    # Final Gauss-Newton factor at the solution for covariances and a rank check.
    _, Rt_fin, deficient = gauss_newton_step(J, F)
    status[(status == STATUS_OK) & deficient] = "degenerate"
    dof = (m - n).astype(float)
    limit = chi2_quantile(options.spurious_quantile, dof)
    ok = status == STATUS_OK
    status[ok & (2.0 * f > limit)] = "spurious"
    bad = ~np.isfinite(f) | ~np.all(np.isfinite(state.xy), axis=(1, 2)) | np.any(state.h <= 0, axis=1)
    bad |= np.any(np.linalg.norm(state.xy, axis=2) > options.max_extent, axis=1)
    status[(status == STATUS_OK) & bad] = "non-physical"
    Rinv = np.linalg.inv(Rt_fin)
    cov = Rinv @ Rinv.swapaxes(-1, -2)
    return NewtonOutcome(state=state, f=f, f_initial=f_initial, status=status, iterations=iterations, covariance=cov)
