"""The paper's baseline: subset-averaging Newton localization (planar, two cameras).

Procedure (Farrell, Garcia, Lucarelli, Terzis, Wang, "Target localization in
camera wireless networks", Pervasive and Mobile Computing 5 (2009) 165-181, as
described in the project brief):

1. Split the nodes into ``T`` random subsets of ``k`` nodes. With a re-measured
   survey (observations tagged with ``subset``, see ``fgloc simulate
   --subset-schedule``) the subsets and their own readings come from the tags;
   otherwise subsets are drawn here and reuse the survey's readings.
2. For each subset solve the system of pan-tilt constraints of the two gauge
   cameras in the planar gauge: unknowns are the heights ``h0, h1`` of the
   origin camera (above (0, 0)) and baseline camera (above (1, 0)), both base
   rotations, and the subset's node positions (x, y) on z = 0: ``8 + 2k``
   unknowns against ``4 k R`` residuals (R readings per camera and node).
3. The solver is a globally convergent Newton method in the style of Numerical
   Recipes' ``newt`` + ``lnsrch``: Newton-Raphson on the whitened residual
   system ``F(x) = (measured - predicted) / sigma`` with an analytic Jacobian,
   and a backtracking line search (quadratic then cubic interpolation,
   sufficient-decrease constant ``ALF = 1e-4``) that guarantees decrease of
   ``f = |F|^2 / 2``. The system is overdetermined (``4kR > 8 + 2k``), so the
   Newton step is the least-squares (Gauss-Newton) step ``J dx = -F`` solved
   by QR; it is a descent direction for f (``grad f . dx = -|Q^T F|^2 < 0``),
   which is all the line search needs. For a square system it is exactly the
   Newton-Raphson step.
4. Rotations are parameterized by local increments ``R <- R Exp(omega)``, so
   the Jacobian of ``q = R^T (x - c)`` is ``[q]_x`` in omega.
5. Each node's estimate is the mean of its solutions over the subsets that
   contain it and succeeded.

Initial guess (documented choice; the paper's exact guess is not available
to us): cameras level (no roll or pitch) with yaws from a coarse 5-degree
grid search over (yaw0, yaw1): for each pair the pan readings triangulate the
nodes in the plane, the tilts imply camera heights, and the pair whose level
model best explains the tilts is the start. It reads only the readings, never
the truth. ``restarts > 1`` also tries the next best grid candidates.

Failures are detected and counted, never averaged in:
``underdetermined`` (fewer residuals than unknowns), ``degenerate`` (the
Jacobian is rank deficient, e.g. collinear nodes), ``no-convergence``
(iteration limit, or the line search stalled away from a stationary point),
``spurious`` (converged, but ``|F|^2`` exceeds the chi-square 99.9% quantile
for ``4kR - (8 + 2k)`` degrees of freedom: a local minimum the noise cannot
explain), ``non-physical`` (a camera at or below the ground, a node farther
than ``max_extent`` baselines, or NaN).

Units: lengths in baselines (planar gauge), angles in radians.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import (
    FloatArray,
    bearing_pan_tilt,
    nearest_rotation,
    pan_tilt_bearing,
    pan_tilt_jacobian,
    rot_z,
    skew,
    wrap_angle,
)
from fgloc.core.model import CameraPose, NodeEstimate, NodeMode, Result, SolveStats, Survey
from fgloc.core.subsets import draw_subsets

N_CAMERA_PARAMS = 8  # h0, h1, omega0 (3), omega1 (3)

STATUS_OK = "ok"
FAILURE_KINDS = ("underdetermined", "degenerate", "no-convergence", "spurious", "non-physical")


class SubsetNewtonError(FglocError):
    """The survey cannot be solved by the subset-Newton baseline."""


@dataclass(frozen=True)
class SubsetNewtonOptions:
    """Settings of the baseline.

    ``subset_size``/``n_subsets`` are used only when the survey's observations
    carry no ``subset`` tags. ``seed`` drives that draw.
    """

    subset_size: int = 10
    n_subsets: int = 50
    seed: int = 0
    max_iterations: int = 100
    restarts: int = 1
    yaw_grid_deg: float = 5.0
    tolx: float = 1e-12  # scaled step below this: converged (NR's TOLX)
    tol_decrement: float = 1e-14  # Gauss-Newton decrement / max(f, 1) below this: converged
    tol_stall: float = 1e-6  # line search stalled with decrement / max(f, 1) below this: converged
    spurious_quantile: float = 0.999
    max_extent: float = 100.0  # baselines; farther nodes are non-physical


@dataclass(frozen=True)
class SubsetSolutions:
    """Successful per-subset node solutions, one row per (subset, node).

    ``subset_index`` indexes ``SubsetNewtonResult.subsets``; ``node_index``
    indexes ``Survey.node_ids``; ``position`` is (P, 2) on z = 0 (baselines).
    """

    subset_index: np.ndarray
    node_index: np.ndarray
    position: FloatArray


@dataclass
class SubsetNewtonResult:
    """Averaged result plus everything needed to plot Figure 4 (subset point clouds).

    ``result.nodes[...].covariance`` is the sample covariance of that node's
    successful subset solutions divided by their count (the covariance of the
    mean) when the node has >= 3 solutions, else the mean of the subsets'
    Gauss-Newton covariances ``(J^T J)^-1`` divided by the count.
    """

    result: Result
    solutions: SubsetSolutions
    subsets: list[np.ndarray]  # node indices of each subset
    status: list[str]  # per subset: "ok" or a failure kind
    iterations: np.ndarray  # per subset
    failures: dict[str, int]
    seconds: float

    @property
    def n_failed(self) -> int:
        return sum(self.failures.values())


# --------------------------------------------------------------------------- math


def so3_exp(omega: FloatArray) -> FloatArray:
    """Rodrigues: rotation matrices (..., 3, 3) for rotation vectors (..., 3), radians."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    K = skew(omega)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


@dataclass
class SubsetState:
    """Unknowns of S subsets solved side by side.

    ``R`` (S, 2, 3, 3) base rotations of the origin and baseline camera,
    ``h`` (S, 2) their heights, ``xy`` (S, k, 2) node positions.
    """

    R: FloatArray
    h: FloatArray
    xy: FloatArray

    def copy(self) -> SubsetState:
        return SubsetState(self.R.copy(), self.h.copy(), self.xy.copy())

    @property
    def n_params(self) -> int:
        return N_CAMERA_PARAMS + 2 * self.xy.shape[1]

    def retract(self, delta: FloatArray) -> SubsetState:
        """Apply a step (S, 8 + 2k) in the layout [h0, h1, w0, w1, x0, y0, x1, ...]."""
        S = delta.shape[0]
        omega = delta[:, 2:8].reshape(S, 2, 3)
        return SubsetState(self.R @ so3_exp(omega), self.h + delta[:, :2], self.xy + delta[:, 8:].reshape(self.xy.shape))

    def scale(self) -> FloatArray:
        """|x_i| per parameter for NR's scaled tests (rotation increments scale as 1)."""
        S = self.h.shape[0]
        return np.concatenate([np.abs(self.h), np.zeros((S, 6)), np.abs(self.xy.reshape(S, -1))], axis=1)

    def camera_positions(self) -> FloatArray:
        S = self.h.shape[0]
        c = np.zeros((S, 2, 3))
        c[:, 1, 0] = 1.0
        c[:, :, 2] = self.h
        return c


@dataclass(frozen=True)
class SubsetReadings:
    """Readings of S subsets of k nodes, padded to M per subset.

    ``camera`` (S, M) 0 = origin, 1 = baseline; ``slot`` (S, M) node slot in
    0..k-1; ``pan``/``tilt``/``sigma`` (S, M) radians; ``mask`` (S, M) bool
    (False marks padding).
    """

    camera: np.ndarray
    slot: np.ndarray
    pan: FloatArray
    tilt: FloatArray
    sigma: FloatArray
    mask: np.ndarray
    k: int

    def take(self, rows: np.ndarray) -> SubsetReadings:
        return SubsetReadings(
            self.camera[rows], self.slot[rows], self.pan[rows], self.tilt[rows], self.sigma[rows], self.mask[rows], self.k
        )


def _gather(state: SubsetState, obs: SubsetReadings) -> tuple[FloatArray, FloatArray]:
    """Per reading: camera rotation (S, M, 3, 3) and base-frame vector q (S, M, 3)."""
    S = state.h.shape[0]
    s_idx = np.arange(S)[:, None]
    X = np.concatenate([state.xy, np.zeros(state.xy.shape[:2] + (1,))], axis=2)
    Xo = X[s_idx, obs.slot]
    Ro = state.R[s_idx, obs.camera]
    co = state.camera_positions()[s_idx, obs.camera]
    q = np.einsum("smji,smj->smi", Ro, Xo - co)
    return Ro, q


def residuals(state: SubsetState, obs: SubsetReadings) -> FloatArray:
    """Whitened residuals F (S, 2M): (measured - predicted) / sigma, pan wrapped, padding zero."""
    _, q = _gather(state, obs)
    pan, tilt = bearing_pan_tilt(q)
    F = np.stack([wrap_angle(obs.pan - pan), obs.tilt - tilt], axis=-1) / obs.sigma[..., None]
    F = np.where(obs.mask[..., None], F, 0.0)
    return F.reshape(F.shape[0], -1)


def residuals_and_jacobian(state: SubsetState, obs: SubsetReadings) -> tuple[FloatArray, FloatArray]:
    """F (S, 2M) and its analytic Jacobian (S, 2M, 8 + 2k) w.r.t. the retraction step."""
    Ro, q = _gather(state, obs)
    S, M = obs.pan.shape
    pan, tilt = bearing_pan_tilt(q)
    w = np.where(obs.mask, 1.0 / obs.sigma, 0.0)[..., None]
    F = np.stack([wrap_angle(obs.pan - pan), obs.tilt - tilt], axis=-1) * w
    A = -pan_tilt_jacobian(q) * w[..., None]  # dF/dq, (S, M, 2, 3)
    n = state.n_params
    J = np.zeros((S, M, n, 2))  # parameter axis before the residual pair for scatter
    is0 = (obs.camera == 0)[..., None]
    # heights: dq/dh = -R^T e3 = -(row 2 of R)
    dh = np.einsum("smij,smj->smi", A, -Ro[..., 2, :])
    J[:, :, 0, :] = np.where(is0, dh, 0.0)
    J[:, :, 1, :] = np.where(is0, 0.0, dh)
    # rotation increments: q(w) = Exp(-w) q  =>  dq/dw = [q]_x
    dw = (A @ skew(q)).swapaxes(-1, -2)  # (S, M, 3, 2)
    J[:, :, 2:5, :] = np.where(is0[..., None], dw, 0.0)
    J[:, :, 5:8, :] = np.where(is0[..., None], 0.0, dw)
    # node (x, y): dq/dx_a = R^T e_a = row a of R
    dxy = A @ Ro[..., :2, :].swapaxes(-1, -2)  # (S, M, 2, 2): [residual, a]
    s_idx = np.arange(S)[:, None]
    m_idx = np.arange(M)[None, :]
    for a in range(2):
        J[s_idx, m_idx, N_CAMERA_PARAMS + 2 * obs.slot + a, :] = dxy[..., :, a]
    J = J.swapaxes(-1, -2).reshape(S, 2 * M, n)
    return F.reshape(S, -1), J


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


# ------------------------------------------------------------------ initial guess


def _lower_median(values: FloatArray, valid: np.ndarray) -> FloatArray:
    """Lower median of the valid entries along the last axis (NaN where none), keepdims."""
    srt = np.sort(np.where(valid, values, np.inf), axis=-1)
    count = valid.sum(axis=-1, keepdims=True)
    med = np.take_along_axis(srt, np.maximum(count - 1, 0) // 2, axis=-1)
    return np.where(count > 0, med, np.nan)


def level_camera_guesses(obs: SubsetReadings, grid_deg: float = 5.0, n_best: int = 1) -> list[SubsetState]:
    """Generic starts from the readings alone: level cameras, yaws from a grid search.

    For every (yaw0, yaw1) on a ``grid_deg`` grid, the pans triangulate each
    node in the plane (rays from (0, 0) and (1, 0)); its tilts imply camera
    heights; the heights are the medians and the score is the squared tilt
    misfit of that level-camera model (nodes behind a camera or implying a
    negative height cost a fixed penalty). Returns the ``n_best`` best
    candidates per subset as states (best first). Never reads truth.
    """
    S, k = obs.pan.shape[0], obs.k
    # Mean bearing per (subset, camera, slot).
    b = np.where(obs.mask[..., None], pan_tilt_bearing(obs.pan, obs.tilt), 0.0)
    acc = np.zeros((S, 2, k, 3))
    s_idx = np.repeat(np.arange(S)[:, None], obs.pan.shape[1], axis=1)
    np.add.at(acc, (s_idx, obs.camera, obs.slot), b)
    pan, tilt = bearing_pan_tilt(acc)  # (S, 2, k)
    grid = np.deg2rad(np.arange(-180.0, 180.0, grid_deg))
    G = grid.size
    a0 = grid[None, :, None, None] + pan[:, None, None, 0, :]  # (S, G, 1, k)
    a1 = grid[None, None, :, None] + pan[:, None, None, 1, :]  # (S, 1, G, k)
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN medians of hopeless yaw pairs
        den = np.sin(a1 - a0)
        t0 = np.sin(a1) / den
        t1 = np.sin(a0) / den
        h0 = -t0 * np.tan(tilt[:, None, None, 0, :])
        h1 = -t1 * np.tan(tilt[:, None, None, 1, :])
        valid = (t0 > 0) & (t1 > 0) & (h0 > 0) & (h1 > 0) & np.isfinite(h0) & np.isfinite(h1)
        h0m = _lower_median(h0, valid)
        h1m = _lower_median(h1, valid)
        e0 = np.arctan2(-h0m, t0) - tilt[:, None, None, 0, :]
        e1 = np.arctan2(-h1m, t1) - tilt[:, None, None, 1, :]
        cost = np.where(valid, e0**2 + e1**2, 1.0).sum(axis=-1)
    cost = np.where(np.isfinite(cost), cost, np.inf).reshape(S, G * G)
    order = np.argsort(cost, axis=1)[:, :n_best]
    states = []
    for c in range(n_best):
        flat = order[:, c]
        i0, i1 = flat // G, flat % G
        y0, y1 = grid[i0], grid[i1]
        rows = np.arange(S)
        pan0 = y0[:, None] + pan[:, 0, :]
        pan1 = y1[:, None] + pan[:, 1, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt0 = np.sin(pan1) / np.sin(pan1 - pan0)
        tt0 = np.where(np.isfinite(tt0), np.clip(tt0, -10.0, 10.0), 0.5)
        xy = np.stack([tt0 * np.cos(pan0), tt0 * np.sin(pan0)], axis=-1)
        hh = np.stack([h0m.reshape(S, G, G)[rows, i0, i1], h1m.reshape(S, G, G)[rows, i0, i1]], axis=1)
        hh = np.where(np.isfinite(hh) & (hh > 0), hh, 0.1)
        R = np.stack([np.stack([rot_z(a), rot_z(b_)]) for a, b_ in zip(y0, y1)])
        states.append(SubsetState(R=R, h=hh, xy=xy))
    return states


# ------------------------------------------------------------------ survey level


def _subset_readings(survey: Survey, options: SubsetNewtonOptions) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Subsets (node indices) and, per subset, the indices of its observations."""
    t = survey.observation_table
    cams = [survey.camera_ids.index(survey.gauge.origin), survey.camera_ids.index(survey.gauge.baseline)]
    gauge_obs = np.isin(t.camera_index, cams)
    tags = np.array([-1 if o.subset is None else o.subset for o in survey.observations], dtype=np.int64)
    if np.any(tags >= 0):
        subsets, members = [], []
        for tag in np.unique(tags[tags >= 0]):
            idx = np.flatnonzero((tags == tag) & gauge_obs)
            subsets.append(np.unique(t.node_index[idx]))
            members.append(idx)
        return subsets, members
    rng = np.random.default_rng(options.seed)
    subsets = draw_subsets(len(survey.node_ids), options.subset_size, options.n_subsets, rng)
    members = [np.flatnonzero(np.isin(t.node_index, s) & gauge_obs) for s in subsets]
    return subsets, members


def _pack(survey: Survey, subsets: list[np.ndarray], members: list[np.ndarray]) -> SubsetReadings:
    t = survey.observation_table
    k = len(subsets[0])
    M = max(1, max(len(m) for m in members))
    S = len(subsets)
    cam = np.zeros((S, M), dtype=np.int64)
    slot = np.zeros((S, M), dtype=np.int64)
    pan = np.zeros((S, M))
    tilt = np.zeros((S, M))
    sig = np.ones((S, M))
    mask = np.zeros((S, M), dtype=bool)
    baseline_index = survey.camera_ids.index(survey.gauge.baseline)
    for s, (nodes, idx) in enumerate(zip(subsets, members)):
        L = len(idx)
        cam[s, :L] = (t.camera_index[idx] == baseline_index).astype(np.int64)
        slot[s, :L] = np.searchsorted(nodes, t.node_index[idx])
        pan[s, :L], tilt[s, :L], sig[s, :L] = t.pan[idx], t.tilt[idx], t.sigma[idx]
        mask[s, :L] = True
    return SubsetReadings(cam, slot, pan, tilt, sig, mask, k)


def solve_packed(obs: SubsetReadings, options: SubsetNewtonOptions) -> NewtonOutcome:
    """Initial guesses + Newton for one batch of equal-size subsets; best restart wins."""
    best: NewtonOutcome | None = None
    for start in level_camera_guesses(obs, options.yaw_grid_deg, max(1, options.restarts)):
        out = solve_subsets(start, obs, options)
        if best is None:
            best = out
            continue
        ok_new, ok_old = out.status == STATUS_OK, best.status == STATUS_OK
        take = (ok_new & ~ok_old) | ((ok_new == ok_old) & (out.f < best.f))
        for name in ("R", "h", "xy"):
            getattr(best.state, name)[take] = getattr(out.state, name)[take]
        best.f[take], best.status[take] = out.f[take], out.status[take]
        best.f_initial[take] = out.f_initial[take]
        best.iterations[take], best.covariance[take] = out.iterations[take], out.covariance[take]
    assert best is not None
    return best


def solve_subset_newton(survey: Survey, options: SubsetNewtonOptions = SubsetNewtonOptions()) -> SubsetNewtonResult:
    """Run the paper's subset-averaging Newton baseline on a planar survey."""
    t_start = time.perf_counter()
    if survey.mode is not NodeMode.PLANAR:
        raise SubsetNewtonError("subset-newton: nodes: only planar surveys are supported (the paper's case)")
    subsets, members = _subset_readings(survey, options)
    S = len(subsets)
    status = [""] * S
    iterations = np.zeros(S, dtype=np.int64)
    sol_s, sol_n, sol_p = [], [], []
    node_gn_cov: dict[int, list[FloatArray]] = {}
    cam_h, cam_R = [], []
    f_total = 0.0
    f_start = 0.0
    sizes = np.array([len(s) for s in subsets])
    for k in np.unique(sizes):
        rows = np.flatnonzero(sizes == k)
        obs = _pack(survey, [subsets[r] for r in rows], [members[r] for r in rows])
        out = solve_packed(obs, options)
        for i, r in enumerate(rows):
            status[r] = str(out.status[i])
            iterations[r] = out.iterations[i]
            if status[r] != STATUS_OK:
                continue
            f_total += float(out.f[i])
            f_start += float(out.f_initial[i])
            cam_h.append(out.state.h[i])
            cam_R.append(out.state.R[i])
            for j_slot, j in enumerate(subsets[r]):
                sol_s.append(r)
                sol_n.append(int(j))
                sol_p.append(out.state.xy[i, j_slot])
                c = N_CAMERA_PARAMS + 2 * j_slot
                node_gn_cov.setdefault(int(j), []).append(out.covariance[i, c : c + 2, c : c + 2])
    solutions = SubsetSolutions(
        subset_index=np.array(sol_s, dtype=np.int64),
        node_index=np.array(sol_n, dtype=np.int64),
        position=np.array(sol_p, dtype=float).reshape(-1, 2),
    )
    nodes: dict[str, NodeEstimate] = {}
    unlocalized: dict[str, str] = {}
    in_subsets = np.zeros(len(survey.node_ids), dtype=np.int64)
    for s in subsets:
        in_subsets[s] += 1
    for j, nid in enumerate(survey.node_ids):
        pts = solutions.position[solutions.node_index == j]
        if len(pts) == 0:
            unlocalized[nid] = (
                "in no subset" if in_subsets[j] == 0 else f"every subset containing it failed ({in_subsets[j]})"
            )
            continue
        mean = pts.mean(axis=0)
        if len(pts) >= 3:
            cov = np.cov(pts.T, ddof=1) / len(pts)
        else:
            cov = np.mean(node_gn_cov[j], axis=0) / len(pts)
        nodes[nid] = NodeEstimate(position=np.array([mean[0], mean[1], 0.0]), covariance=cov)
    cameras: dict[str, CameraPose] = {}
    if cam_h:
        h = np.mean(cam_h, axis=0)
        Rm = np.mean(cam_R, axis=0)
        cameras[survey.gauge.origin] = CameraPose(np.array([0.0, 0.0, h[0]]), nearest_rotation(Rm[0]))
        cameras[survey.gauge.baseline] = CameraPose(np.array([1.0, 0.0, h[1]]), nearest_rotation(Rm[1]))
    failures = {kind: status.count(kind) for kind in FAILURE_KINDS}
    seconds = time.perf_counter() - t_start
    stats = SolveStats(
        method="subset-newton",
        iterations=int(iterations.sum()),
        initial_error=f_start,  # sum over successful subsets of 0.5 |F|^2 at their starts
        final_error=f_total,
        converged=failures["no-convergence"] == 0,
        stage_seconds={"subsets": seconds},
    )
    result = Result(mode=NodeMode.PLANAR, nodes=nodes, cameras=cameras, unlocalized=unlocalized, stats=stats)
    return SubsetNewtonResult(
        result=result,
        solutions=solutions,
        subsets=subsets,
        status=status,
        iterations=iterations,
        failures=failures,
        seconds=seconds,
    )
