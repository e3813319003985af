"""The benchmark's "speed limit": a plain vectorized numpy Levenberg-Marquardt with the
nodes eliminated in closed form (Schur complement) at every iteration.

Deliberately independent of the production solvers (it shares only the pan-tilt
geometry of :mod:`fgloc.core.geometry` and the reading Jacobians of
:func:`fgloc.factors.pan_tilt_batch.batch_pan_tilt_error`), so the benchmark can
cross-check their optima. Per iteration: whiten the readings, form each node's
d x d block ``A_j``, its coupling ``B_j`` to the cameras (dense, d x 6k) and the
cameras' own block-diagonal ``H_cc`` plus the gauge; with Marquardt damping
``lambda * diag``, eliminate every node (``S = H_cc - sum B_j^T A_j^-1 B_j``),
solve the 6k x 6k camera system, back-substitute the nodes, accept or reject
by the true cost (Nielsen's gain-ratio rule, 0.1x floor, as
:mod:`fgloc.solve.levenberg_marquardt`). The node marginals come from the same
pieces: ``A_j^-1 + A_j^-1 B_j S^-1 B_j^T A_j^-1``.

Planar surveys only (the benchmark scenes): nodes (x, y, 0); the spec's planar
gauge (origin camera's ground point at (0, 0), baseline camera's at (1, 0)) as
four whitened residuals. Cameras: ``Pose3`` tangent ``[omega, v]``, right
perturbation (``R Exp(omega)``, ``c + R v``), the convention of the GTSAM graph.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.factors.pan_tilt_batch import batch_pan_tilt_error


def _so3_exp(w: FloatArray) -> FloatArray:
    """Rotation matrices (K, 3, 3) of rotation vectors (K, 3) (Rodrigues)."""
    theta = np.linalg.norm(w, axis=1)
    k = np.where(theta[:, None] > 1e-12, w / np.maximum(theta, 1e-300)[:, None], 0.0)
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3)[None] + s * K + (1 - c) * (K @ K)


@dataclass
class NumpySchurOutcome:
    """Final cameras (rotations (k,3,3), positions (k,3)), nodes (n,2), cost, iterations, node covariances."""

    rotations: FloatArray
    positions: FloatArray
    nodes: FloatArray
    cost: float
    iterations: int
    covariances: FloatArray | None


def _sum_by(index: np.ndarray, values: FloatArray, size: int) -> FloatArray:
    """``out[i] = sum of values[r] over r with index[r] == i``; values (m, ...)."""
    flat = values.reshape(len(values), -1)
    out = np.empty((size, flat.shape[1]))
    for col in range(flat.shape[1]):
        out[:, col] = np.bincount(index, weights=flat[:, col], minlength=size)
    return out.reshape((size,) + values.shape[1:])


def numpy_schur_lm(
    rotations: FloatArray,
    positions: FloatArray,
    nodes: FloatArray,
    cam: np.ndarray,
    node: np.ndarray,
    pan: FloatArray,
    tilt: FloatArray,
    sigma: FloatArray,
    gauge: tuple[int, int],
    gauge_sigma: float,
    max_iterations: int = 100,
    relative_tol: float = 1e-10,
    marginals: bool = True,
) -> NumpySchurOutcome:
    """Minimize 0.5 * (sum of squared whitened pan-tilt residuals + gauge) over cameras and planar nodes.

    ``cam``/``node`` (m,) index each reading's camera/node; angles and sigma in
    radians; ``gauge`` = (origin camera, baseline camera) indices.
    """
    R, p, X = rotations.copy(), positions.copy(), nodes.copy()
    k, n, d = len(R), len(X), 2
    w = 1.0 / sigma
    g0, g1 = gauge
    pair = node * k + cam  # (node, camera) slot of each reading in the dense coupling

    def residuals(R: FloatArray, p: FloatArray, X: FloatArray, jac: bool) -> tuple:
        pts = np.column_stack([X, np.zeros(n)])
        e, hc, hn = batch_pan_tilt_error(R[cam], p[cam], pts[node], pan, tilt)
        e = e * w[:, None]
        gauge_r = np.concatenate([p[g0, :2], p[g1, :2] - [1.0, 0.0]]) / gauge_sigma
        cost = 0.5 * (float(np.sum(e * e)) + float(gauge_r @ gauge_r))
        if not jac:
            return (cost,)
        return cost, e, hc * w[:, None, None], hn[:, :, :d] * w[:, None, None], gauge_r

    cost, e, jc, jn, gauge_r = residuals(R, p, X, True)
    lam, nu = 1e-4, 2.0
    iterations = 0
    for _ in range(max_iterations):
        # Gauss-Newton pieces (gradient of 0.5|r|^2 is J^T r).
        A = _sum_by(node, np.einsum("mki,mkj->mij", jn, jn), n)  # (n, d, d)
        gn = _sum_by(node, np.einsum("mki,mk->mi", jn, e), n)  # (n, d)
        Bp = _sum_by(pair, np.einsum("mki,mkj->mij", jn, jc), n * k)  # (n*k, d, 6)
        B = Bp.reshape(n, k, d, 6).transpose(0, 2, 1, 3).reshape(n, d, 6 * k)
        Hc = _sum_by(cam, np.einsum("mki,mkj->mij", jc, jc), k)  # (k, 6, 6)
        gc = _sum_by(cam, np.einsum("mki,mk->mi", jc, e), k).reshape(6 * k)
        Hcc = np.zeros((6 * k, 6 * k))
        for i in range(k):
            Hcc[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = Hc[i]
        # Gauge rows: d(c_xy)/dv = R[:2, :] / gauge_sigma on the translation tangent.
        Jg = np.zeros((4, 6 * k))
        Jg[0:2, 6 * g0 + 3 : 6 * g0 + 6] = R[g0, :2, :] / gauge_sigma
        Jg[2:4, 6 * g1 + 3 : 6 * g1 + 6] = R[g1, :2, :] / gauge_sigma
        Hcc += Jg.T @ Jg
        gc += Jg.T @ gauge_r
        diag_a = np.maximum(np.diagonal(A, axis1=1, axis2=2), 1e-9)
        diag_c = np.maximum(np.diagonal(Hcc), 1e-9)
        accepted = False
        while lam < 1e12:
            Ad = A + lam * diag_a[:, :, None] * np.eye(d)
            Ai = np.linalg.inv(Ad)
            AiB = Ai @ B
            Aig = np.einsum("nij,nj->ni", Ai, gn)
            S = Hcc + lam * np.diag(diag_c) - B.reshape(-1, 6 * k).T @ AiB.reshape(-1, 6 * k)
            rhs = gc - B.reshape(-1, 6 * k).T @ Aig.reshape(-1)
            try:
                dc = -np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                lam *= nu
                nu *= 2.0
                continue
            dn = -(Aig + AiB @ dc)
            # Predicted decrease of the undamped Gauss-Newton model: -g.dx - 0.5 |J dx|^2.
            jdx = np.einsum("mkj,mj->mk", jc, dc.reshape(k, 6)[cam]) + np.einsum("mkj,mj->mk", jn, dn[node])
            predicted = -(gc @ dc + float(np.sum(gn * dn))) - 0.5 * (float(np.sum(jdx * jdx)) + float(np.sum((Jg @ dc) ** 2)))
            step = dc.reshape(k, 6)
            Rn = R @ _so3_exp(step[:, :3])
            pn = p + np.einsum("kij,kj->ki", R, step[:, 3:])
            Xn = X + dn
            new_cost = residuals(Rn, pn, Xn, False)[0]
            if np.isfinite(new_cost) and new_cost < cost and predicted > 0:
                rho = (cost - new_cost) / predicted
                lam *= max(0.1, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            lam *= nu
            nu *= 2.0
        if not accepted:
            break
        decrease = cost - new_cost
        iterations += 1
        R, p, X = Rn, pn, Xn
        cost, e, jc, jn, gauge_r = residuals(R, p, X, True)
        if decrease <= relative_tol * cost:
            break
    covariances = None
    if marginals:
        # Undamped pieces at the final estimate.
        A = _sum_by(node, np.einsum("mki,mkj->mij", jn, jn), n)
        Bp = _sum_by(pair, np.einsum("mki,mkj->mij", jn, jc), n * k)
        B = Bp.reshape(n, k, d, 6).transpose(0, 2, 1, 3).reshape(n, d, 6 * k)
        Hc = _sum_by(cam, np.einsum("mki,mkj->mij", jc, jc), k)
        Hcc = np.zeros((6 * k, 6 * k))
        for i in range(k):
            Hcc[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = Hc[i]
        Jg = np.zeros((4, 6 * k))
        Jg[0:2, 6 * g0 + 3 : 6 * g0 + 6] = R[g0, :2, :] / gauge_sigma
        Jg[2:4, 6 * g1 + 3 : 6 * g1 + 6] = R[g1, :2, :] / gauge_sigma
        Hcc += Jg.T @ Jg
        Ai = np.linalg.inv(A)
        AiB = Ai @ B
        S = Hcc - B.reshape(-1, 6 * k).T @ AiB.reshape(-1, 6 * k)
        sigma_cc = np.linalg.inv(S)
        spread = AiB @ sigma_cc
        covariances = Ai + np.einsum("nik,njk->nij", spread, AiB)
    return NumpySchurOutcome(R, p, X, cost, iterations, covariances)
