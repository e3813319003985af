"""Levenberg-Marquardt driven from Python around GTSAM's linearize / eliminate / retract.

Why not ``gtsam.LevenbergMarquardtOptimizer``: with Python ``CustomFactor``s the
binding copies the optimizer's whole ``Values`` for every factor callback, so the
C++ loop costs O(n^2) in the number of variables (measured: 28 s at 3,000 nodes,
``shared/reference/measured-pitfalls.md``). Here the callbacks receive the
Python-owned ``Values`` itself and the loop is linear in n.

Damping is diagonal (Marquardt): ``lambda * diag(J^T J)`` per variable, which is
invariant to the strong whitening of 0.1-degree bearings (information ~3e5 would
otherwise swamp an isotropic ``lambda I``). Lambda follows Nielsen's gain-ratio
rule, but a very good step may shrink it 10x (``min_lambda_factor``) instead of
Nielsen's 3x: from the closed-form start that took the 100-node survey from
8-11 iterations to 4 (starting at lambda 1e-7 did the same on planar
surveys, but sent robust 3d solves into other basins). A rejected step raises
it. The linear systems are solved by GTSAM's multifrontal Cholesky in the
given elimination ordering.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np

IterationCallback = Callable[[int, gtsam.Values, float], None]
PrepareHook = Callable[[gtsam.Values], None]
ErrorFunction = Callable[[gtsam.Values], float]


@dataclass(frozen=True)
class LMParams:
    """Stopping and damping settings. Errors are GTSAM's 0.5 * sum of squared whitened residuals."""

    max_iterations: int = 100
    relative_error_tol: float = 1e-10
    absolute_error_tol: float = 1e-12
    initial_lambda: float = 1e-4
    min_lambda_factor: float = 0.1  # smallest multiplier of lambda after a good step (Nielsen: 1/3)
    max_lambda: float = 1e12
    min_diagonal: float = 1e-9


@dataclass
class LMOutcome:
    """Optimized values, the error after each accepted step (index 0: initial) and why it stopped."""

    values: gtsam.Values
    error_history: list[float] = field(default_factory=list)
    iterations: int = 0
    converged: bool = False
    reason: str = ""


def hessian_diagonal(linear: gtsam.GaussianFactorGraph, key_dims: list[tuple[int, int]]) -> dict[int, np.ndarray]:
    """Diagonal of ``J^T J`` per variable from the sparse whitened Jacobian.

    ``key_dims`` lists (key, dimension) in sorted key order, which is GTSAM's
    column order for ``sparseJacobian_`` (its last column is the right-hand side).
    """
    ijs = linear.sparseJacobian_()
    cols = ijs[1].astype(np.int64) - 1
    total = sum(d for _, d in key_dims)
    keep = cols < total
    diag = np.bincount(cols[keep], weights=ijs[2][keep] ** 2, minlength=total)
    out: dict[int, np.ndarray] = {}
    offset = 0
    for key, dim in key_dims:
        out[key] = diag[offset : offset + dim]
        offset += dim
    return out


def _diagonal_vector(linear: gtsam.GaussianFactorGraph, total: int) -> np.ndarray:
    """Diagonal of ``J^T J`` as one vector in sorted key order (see :func:`hessian_diagonal`)."""
    ijs = linear.sparseJacobian_()
    cols = ijs[1].astype(np.int64) - 1
    keep = cols < total
    return np.bincount(cols[keep], weights=ijs[2][keep] ** 2, minlength=total)


def levenberg_marquardt(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    ordering: gtsam.Ordering | None = None,
    params: LMParams = LMParams(),
    on_iteration: IterationCallback | None = None,
    prepare: PrepareHook | None = None,
    error_function: ErrorFunction | None = None,
) -> LMOutcome:
    """Minimize ``graph.error`` from ``initial``.

    ``on_iteration(k, values, error)`` sees every accepted step; ``prepare(values)``
    is called before the graph is evaluated at new values (a vectorized factor
    cache hooks in here). ``error_function(values)``, if given, must return
    ``graph.error(values)`` (a faster route to the same number).
    """
    prep: PrepareHook = prepare if prepare is not None else (lambda v: None)
    values = initial
    graph_error: ErrorFunction = error_function if error_function is not None else graph.error
    prep(values)
    error = graph_error(values)
    outcome = LMOutcome(values=values, error_history=[error])
    if on_iteration is not None:
        on_iteration(0, values, error)
    key_dims = sorted((int(k), int(d)) for k, d in values.dims().items())
    rhs = {d: np.zeros(d) for _, d in key_dims}
    total_dim = sum(d for _, d in key_dims)
    offsets_all = np.cumsum([0] + [d for _, d in key_dims])[:-1]
    by_dim = {
        d: (
            [k for k, dd in key_dims if dd == d],
            np.array([o for (k, dd), o in zip(key_dims, offsets_all) if dd == d], dtype=np.int64),
        )
        for d in rhs
    }
    lam, nu = params.initial_lambda, 2.0
    for iteration in range(1, params.max_iterations + 1):
        if error <= params.absolute_error_tol:
            outcome.converged, outcome.reason = True, "error below absolute tolerance"
            break
        prep(values)
        linear = graph.linearize(values)
        diag = _diagonal_vector(linear, total_dim)
        floor = params.min_diagonal * max(float(np.max(diag)), 1.0)
        accepted = False
        # The damping blocks sqrt(diag) are built once per linearization (one
        # vectorized pass); each inner try only changes the noise model:
        # sigma = 1/sqrt(lambda) whitens them to sqrt(lambda * diag).
        root = np.sqrt(np.maximum(diag, floor))
        damping_blocks: list[tuple[int, int, np.ndarray]] = []  # (key, dim, diagonal block)
        for dim, (keys, offsets) in by_dim.items():
            blocks = np.zeros((len(keys), dim, dim))
            idx = np.arange(dim)
            blocks[:, idx, idx] = root[offsets[:, None] + idx[None, :]]
            damping_blocks.extend((key, dim, block) for key, block in zip(keys, blocks))
        while lam <= params.max_lambda:
            damped = linear.clone()
            sigma = 1.0 / float(np.sqrt(lam))
            noise = {d: gtsam.noiseModel.Isotropic.Sigma(d, sigma) for d in rhs}
            for key, dim, block in damping_blocks:
                damped.add(key, block, rhs[dim], noise[dim])
            try:
                delta = damped.optimize(ordering) if ordering is not None else damped.optimize()
            except RuntimeError:
                # Cholesky met a numerically indefinite system: with little damping a
                # poorly conditioned problem can do that; more damping always cures it.
                lam *= nu
                nu *= 2.0
                continue
            predicted = error - linear.error(delta)
            candidate = values.retract(delta)
            prep(candidate)
            new_error = graph_error(candidate)
            if np.isfinite(new_error) and new_error < error and predicted > 0:
                rho = (error - new_error) / predicted
                lam *= max(params.min_lambda_factor, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            lam *= nu
            nu *= 2.0
        if not accepted:
            outcome.converged, outcome.reason = True, "no further decrease (at a minimum to machine precision)"
            break
        decrease = error - new_error
        values, error = candidate, new_error
        outcome.values, outcome.iterations = values, iteration
        outcome.error_history.append(error)
        if on_iteration is not None:
            on_iteration(iteration, values, error)
        if decrease <= params.relative_error_tol * max(error, 1e-300):
            outcome.converged, outcome.reason = True, "relative decrease below tolerance"
            break
    else:
        outcome.reason = f"stopped after {params.max_iterations} iterations"
    return outcome
