"""Fisher information of the pan-tilt model for planning, vectorized in numpy.

Planning frame: metres, world z up, nodes on the ground z = 0 (planar surveys
only). A camera is a level pan-tilt base at ``(x, y, h)``; its pose is unknown
to the solver (6 DOF, GTSAM ``Pose3`` tangent ``[omega, v]`` with right
perturbation, as in :func:`fgloc.factors.pan_tilt_batch.batch_pan_tilt_error`),
each node's position is unknown (2 DOF). A reading (camera i, node j) adds
``J^T J / sigma^2`` (J the 2 x 8 Jacobian of (pan, tilt)) to the information.

Two gauges are used:

* the **solver's gauge** (:func:`gauge_frame_covariances`): the ground points of
  the gauge pair are pinned exactly (hard constraint: the pose tangents of the
  two gauge cameras are restricted to the null space of ``d c_xy``). This is the
  frame fgloc reports (cam0 above the origin, cam1 above (1, 0), scaled by the
  baseline in metres), so these covariances equal ``fgloc.cramer_rao_bound`` of
  the simulated survey times the baseline squared.
* the **node-cloud gauge** (:class:`CandidateInfo` / :func:`cloud_evaluate`): the
  four similarity directions of the node cloud (translation, rotation, scale
  about its centroid) are pinned and every node carries a weak prior of standard
  deviation ``prior_m``. It does not depend on which cameras are chosen, so the
  node information is ``M = D + sum_i (C_i - V_i V_i^T)`` with one PSD term per
  camera (its pose marginalized out): log det M is monotone submodular in the
  chosen set and concave in fractional weights (the relaxation of
  :mod:`fgloc.plan.relaxation`). Selection runs in this gauge; the reported
  prediction in the solver's gauge.

Node covariances come from the Schur complement / Woodbury identity over the
few camera unknowns, never a dense (2N x 2N) inverse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.factors.pan_tilt_batch import batch_pan_tilt_error


@dataclass(frozen=True)
class Jacobians:
    """Whitened Jacobians of C candidate cameras x N nodes.

    ``pose`` (C, N, 2, 6) and ``point`` (C, N, 2, 2) are divided by sigma and
    zeroed where ``visible`` (C, N) is False; ``rotations`` (C, 3, 3) and
    ``positions`` (C, 3) are the candidate bases.
    """

    pose: FloatArray
    point: FloatArray
    visible: np.ndarray
    rotations: FloatArray
    positions: FloatArray


def level_rotation(position: FloatArray, target_xy: FloatArray) -> FloatArray:
    """A level base (no roll or pitch) whose pan zero faces ``target_xy`` (an arbitrary, harmless choice)."""
    d = np.asarray(target_xy, float) - np.asarray(position, float)[:2]
    yaw = float(np.arctan2(d[1], d[0])) if np.hypot(*d) > 0 else 0.0
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def jacobians(
    positions: FloatArray, rotations: FloatArray, nodes_xy: FloatArray, visible: np.ndarray, sigma: float
) -> Jacobians:
    """Whitened pan-tilt Jacobians of every candidate camera (C, 3) against every node (N, 2)."""
    positions = np.asarray(positions, float)
    rotations = np.asarray(rotations, float)
    c, n = len(positions), len(nodes_xy)
    points = np.column_stack([np.asarray(nodes_xy, float), np.zeros(n)])
    cam_idx = np.repeat(np.arange(c), n)
    node_idx = np.tile(np.arange(n), c)
    zeros = np.zeros(c * n)
    _, h_pose, h_point = batch_pan_tilt_error(
        rotations[cam_idx], positions[cam_idx], points[node_idx], zeros, zeros
    )
    mask = np.asarray(visible, bool).reshape(-1)[:, None, None]
    pose = np.where(mask, h_pose, 0.0).reshape(c, n, 2, 6) / sigma
    point = np.where(mask, h_point[:, :, :2], 0.0).reshape(c, n, 2, 2) / sigma
    return Jacobians(pose, point, np.asarray(visible, bool), rotations, positions)


def _inv2(m: FloatArray) -> tuple[FloatArray, np.ndarray]:
    """Inverses of (N, 2, 2) symmetric matrices and a mask of the invertible ones."""
    det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    scale = np.maximum(np.abs(m[:, 0, 0]) + np.abs(m[:, 1, 1]), 1e-300)
    ok = det > 1e-12 * scale * scale
    safe = np.where(ok, det, 1.0)
    inv = np.empty_like(m)
    inv[:, 0, 0] = m[:, 1, 1] / safe
    inv[:, 1, 1] = m[:, 0, 0] / safe
    inv[:, 0, 1] = -m[:, 0, 1] / safe
    inv[:, 1, 0] = -m[:, 1, 0] / safe
    inv[~ok] = np.inf
    return inv, ok


def gauge_basis(rotation: FloatArray) -> FloatArray:
    """(6, 4) basis of pose tangents that keep the base's ground point (x, y) fixed."""
    block = np.hstack([np.zeros((2, 3)), rotation[:2, :]])  # d c_xy / d [omega, v]
    _, _, vt = np.linalg.svd(block)
    return vt[2:].T


def gauge_frame_covariances(
    jac: Jacobians, chosen: list[int], gauge: tuple[int, int], weights: FloatArray | None = None
) -> tuple[FloatArray, np.ndarray]:
    """Per-node CRB covariances (N, 2, 2) in m^2 in the solver's gauge of ``gauge`` (two entries of ``chosen``).

    ``weights`` (len(chosen), N) counts readings per (camera, node) (default: one
    per visible pair). Returns the covariances and a mask of the localizable nodes
    (others get inf)."""
    k = len(chosen)
    w = np.ones((k, jac.pose.shape[1])) if weights is None else np.asarray(weights, float)
    w = w * jac.visible[chosen]
    bases = [gauge_basis(jac.rotations[c]) if c in gauge else np.eye(6) for c in chosen]
    dims = [b.shape[1] for b in bases]
    offs = np.concatenate([[0], np.cumsum(dims)])
    n = jac.pose.shape[1]
    jp = [jac.pose[c] @ b for c, b in zip(chosen, bases)]  # (N, 2, d_i)
    jx = jac.point[chosen]  # (k, N, 2, 2)
    h_nn = np.einsum("kn,knai,knaj->nij", w, jx, jx)
    w_inv, ok = _inv2(h_nn)
    big = int(offs[-1])
    b_stack = np.zeros((n, big, 2))
    s = np.zeros((big, big))
    for i in range(k):
        sl = slice(offs[i], offs[i + 1])
        b_stack[:, sl, :] = np.einsum("n,nai,naj->nij", w[i], jp[i], jx[i])
        s[sl, sl] = np.einsum("n,nai,naj->ij", w[i], jp[i], jp[i])
    wi = np.where(ok[:, None, None], w_inv, 0.0)
    z = np.einsum("nij,njk->nik", b_stack, wi)  # B W  (N, D, 2)
    s -= np.einsum("nik,njk->ij", z, b_stack)
    s_inv = np.linalg.pinv(s, hermitian=True)
    cov = wi + np.einsum("nki,kl,nlj->nij", z, s_inv, z)
    cov[~ok] = np.inf
    return cov, ok


# --- node-cloud gauge: camera-independent, for selection and the relaxation -------------------


@dataclass(frozen=True)
class CandidateInfo:
    """Per-candidate node information with the candidate's pose marginalized out.

    ``local`` (C, N, 2, 2): the node blocks ``C_i``; ``coupling`` (C, N, 2, 6): ``V_i``
    with ``C_i - V_i V_i^T`` the candidate's contribution; ``cloud`` (N, 2, 4): the
    similarity directions pinned by the gauge; ``prior`` (1/m^2) the weak node prior.
    """

    local: FloatArray
    coupling: FloatArray
    cloud: FloatArray
    prior: float


def candidate_info(jac: Jacobians, nodes_xy: FloatArray, prior_m: float) -> CandidateInfo:
    """Marginalize each candidate's own pose: ``V_i = B_i^T A_i^{-1/2}`` (pseudo-inverse if A_i is singular)."""
    local = np.einsum("cnai,cnaj->cnij", jac.point, jac.point)
    b = np.einsum("cnai,cnaj->cnij", jac.point, jac.pose)  # (C, N, 2, 6) = Jx^T Jp
    a = np.einsum("cnai,cnaj->cij", jac.pose, jac.pose)
    vals, vecs = np.linalg.eigh(a)
    tol = 1e-10 * np.maximum(vals[:, -1:], 1e-300)
    inv_sqrt = np.where(vals > tol, 1.0 / np.sqrt(np.where(vals > tol, vals, 1.0)), 0.0)
    a_isqrt = np.einsum("cij,cj,ckj->cik", vecs, inv_sqrt, vecs)
    coupling = np.einsum("cnij,cjk->cnik", b, a_isqrt)
    xy = np.asarray(nodes_xy, float)
    centred = xy - xy.mean(axis=0)
    scale = max(float(np.sqrt(np.mean(np.sum(centred**2, axis=1)))), 1e-12)
    u = np.zeros((len(xy), 2, 4))
    u[:, 0, 0] = 1.0
    u[:, 1, 1] = 1.0
    u[:, 0, 2], u[:, 1, 2] = -centred[:, 1] / scale, centred[:, 0] / scale
    u[:, :, 3] = centred / scale
    return CandidateInfo(local, coupling, u, 1.0 / prior_m**2)


@dataclass(frozen=True)
class CloudEvaluation:
    """Node-cloud-gauge covariances (N, 2, 2) in m^2 and log det of the node information (+ constant)."""

    covariances: FloatArray
    logdet: float


def cloud_evaluate(info: CandidateInfo, weights: dict[int, float]) -> CloudEvaluation:
    """Evaluate fractional or 0/1 candidate ``weights`` {candidate: z in (0, 1]} in the node-cloud gauge.

    ``M = D + Y Q Y^T`` with ``D = prior I + sum z_i C_i`` block diagonal, ``Y = [V_i..., U]`` and
    ``Q = diag(-z_i I_6, lambda I_4)``, lambda -> infinity (exact gauge). Woodbury:
    ``M^-1 = D^-1 - D^-1 Y K^-1 Y^T D^-1`` with ``K = Q^-1 + Y^T D^-1 Y``; the determinant lemma
    gives ``log det M = log det D + log det K + 6 sum log z_i + 4 log lambda`` (the constant is dropped).
    """
    ids = [c for c, z in weights.items() if z > 0]
    z = np.array([weights[c] for c in ids], float)
    n = info.local.shape[1]
    d = info.prior * np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    if ids:
        d += np.einsum("c,cnij->nij", z, info.local[ids])
    d_inv, _ = _inv2(d)
    y = np.concatenate([info.coupling[ids].transpose(1, 2, 0, 3).reshape(n, 2, 6 * len(ids)), info.cloud], axis=2)
    q_inv = np.concatenate([np.repeat(-1.0 / z, 6) if ids else np.zeros(0), np.zeros(4)])
    r = np.einsum("nij,njk->nik", d_inv, y)  # D^-1 Y (N, 2, r)
    k = np.diag(q_inv) + np.einsum("nai,naj->ij", y, r)
    k = 0.5 * (k + k.T)
    sign, logdet_k = np.linalg.slogdet(k)
    k_inv = np.linalg.inv(k)
    cov = d_inv - np.einsum("nai,ij,nbj->nab", r, k_inv, r)
    logdet_d = float(np.sum(np.log(d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])))
    # det Q = prod z_i^6 * lambda^4: the z part matters for fractional weights.
    logdet = logdet_d + float(logdet_k) + 6.0 * float(np.sum(np.log(z))) if sign > 0 else -np.inf
    return CloudEvaluation(cov, logdet)


def traces(cov: FloatArray) -> FloatArray:
    """Per-node trace of (N, 2, 2) covariances: the expected squared position error (m^2)."""
    return cov[:, 0, 0] + cov[:, 1, 1]
