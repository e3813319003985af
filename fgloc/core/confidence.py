"""Confidence regions of Gaussian position estimates: pure numpy, no drawing.

A position with covariance ``C`` (d x d, d = 2 or 3) lies, with probability
``p``, inside the ellipse/ellipsoid ``e^T C^-1 e <= k^2`` where ``k^2`` is the
chi-square quantile with d degrees of freedom. Its half axes are ``k sqrt(l_i)``
along the eigenvectors ``v_i`` of ``C``. For p = 0.95: k = 2.4477 (d = 2) and
k = 2.7955 (d = 3).

Rotations are returned as quaternions in Rerun's order ``(x, y, z, w)``; they
rotate the ellipsoid's local axes (x = smallest eigenvalue ... ) into the world
frame and are proper (determinant +1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray

DEFAULT_CONFIDENCE = 0.95

#: Flat ellipses (planar covariances) get this z half size, relative to their major half axis.
FLAT_Z_FRACTION = 1e-4


def chi2_cdf(x: float, dof: int) -> float:
    """Chi-square cumulative distribution for 1, 2 or 3 degrees of freedom (closed forms)."""
    if x <= 0.0:
        return 0.0
    if dof == 1:
        return math.erf(math.sqrt(x / 2.0))
    if dof == 2:
        return 1.0 - math.exp(-x / 2.0)
    if dof == 3:
        return math.erf(math.sqrt(x / 2.0)) - math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)
    raise ValueError(f"dof must be 1, 2 or 3, got {dof}")


def confidence_scale(dof: int, confidence: float = DEFAULT_CONFIDENCE) -> float:
    """``k = sqrt(chi2_dof^-1(confidence))``: the Mahalanobis radius of the confidence region."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if dof == 2:
        return math.sqrt(-2.0 * math.log1p(-confidence))
    lo, hi = 0.0, 1.0
    while chi2_cdf(hi, dof) < confidence:
        hi *= 2.0
    for _ in range(200):  # bisection to machine precision
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < confidence:
            lo = mid
        else:
            hi = mid
    return math.sqrt(0.5 * (lo + hi))


def rotation_to_quaternion_xyzw(rotations: FloatArray) -> FloatArray:
    """Unit quaternions (N, 4) in (x, y, z, w) order of proper rotation matrices (N, 3, 3).

    Shepperd's method, vectorized: each row uses the numerically largest of
    (w, x, y, z) as pivot. The sign is normalized so that w >= 0.
    """
    R = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    trace = m00 + m11 + m22
    pivots = np.stack([trace, m00, m11, m22], axis=1).argmax(axis=1)
    q = np.empty((R.shape[0], 4))  # x, y, z, w
    for case in range(4):
        sel = pivots == case
        if not sel.any():
            continue
        r = R[sel]
        if case == 0:
            s = 2.0 * np.sqrt(1.0 + r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2])
            q[sel] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                               (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], axis=1)
        elif case == 1:
            s = 2.0 * np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2])
            q[sel] = np.stack([0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                               (r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 2, 1] - r[:, 1, 2]) / s], axis=1)
        elif case == 2:
            s = 2.0 * np.sqrt(1.0 - r[:, 0, 0] + r[:, 1, 1] - r[:, 2, 2])
            q[sel] = np.stack([(r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s,
                               (r[:, 1, 2] + r[:, 2, 1]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s], axis=1)
        else:
            s = 2.0 * np.sqrt(1.0 - r[:, 0, 0] - r[:, 1, 1] + r[:, 2, 2])
            q[sel] = np.stack([(r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s,
                               0.25 * s, (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
    q *= np.where(q[:, 3:4] < 0.0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@dataclass(frozen=True)
class ConfidenceEllipsoids:
    """Confidence regions in the world frame, ready to draw.

    ``half_sizes`` (N, 3) are along the local axes, ``rotations`` (N, 3, 3)
    map local axes to world (columns = eigenvectors), ``quaternions`` (N, 4)
    are the same rotations as (x, y, z, w). Planar (2x2) covariances give flat
    ellipses in z = const with a z half size of ``FLAT_Z_FRACTION`` times the
    major half axis. ``scale`` is the k used.
    """

    half_sizes: FloatArray
    rotations: FloatArray
    quaternions: FloatArray
    scale: float


def confidence_ellipsoids(covariances: FloatArray, confidence: float = DEFAULT_CONFIDENCE) -> ConfidenceEllipsoids:
    """Confidence ellipses (covariances (N, 2, 2)) or ellipsoids ((N, 3, 3)) at ``confidence``.

    Negative eigenvalues from round-off are clipped to zero; NaN covariances
    give NaN half sizes (draw nothing for them).
    """
    C = np.asarray(covariances, dtype=float)
    if C.ndim != 3 or C.shape[1] != C.shape[2] or C.shape[1] not in (2, 3):
        raise ValueError(f"covariances must be (N, 2, 2) or (N, 3, 3), got {C.shape}")
    n, d = C.shape[0], C.shape[1]
    k = confidence_scale(d, confidence)
    finite = np.isfinite(C).all(axis=(1, 2))
    safe = np.where(finite[:, None, None], 0.5 * (C + C.transpose(0, 2, 1)), np.eye(d))
    eigenvalues, eigenvectors = np.linalg.eigh(safe)
    flip = np.linalg.det(eigenvectors) < 0.0
    eigenvectors[flip, :, 0] *= -1.0  # proper rotation; an axis' sign is irrelevant to the region
    axes = k * np.sqrt(np.clip(eigenvalues, 0.0, None))
    axes[~finite] = np.nan
    rotations = np.zeros((n, 3, 3))
    half_sizes = np.empty((n, 3))
    if d == 2:
        rotations[:, :2, :2] = eigenvectors
        rotations[:, 2, 2] = 1.0
        half_sizes[:, :2] = axes
        half_sizes[:, 2] = FLAT_Z_FRACTION * axes.max(axis=1)
    else:
        rotations[:] = eigenvectors
        half_sizes[:] = axes
    return ConfidenceEllipsoids(half_sizes, rotations, rotation_to_quaternion_xyzw(rotations), k)
