"""Two-view and one-view relations for free (3D) nodes, on the bearing sphere.

* Two cameras: ``b2^T E b1 = 0`` with ``E = [t]_x R`` where ``X2 = R X1 + t``
  maps camera-1 base coordinates to camera-2 base coordinates (8-point linear
  estimate on unit bearings, projected onto the essential manifold).
* One camera and known points: ``b ∝ P (X, 1)`` with ``P = R^T [I | -c]``
  (linear absolute pose, >= 6 points).
* Triangulation: the point closest to several rays (least squares).

Bearings keep their sign, so chirality (depth > 0 along every ray) picks the
physical decomposition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray, angle_between, nearest_rotation, skew
from fgloc.core.model import CameraPose
from fgloc.init.homography import DegenerateGeometryError

MIN_SHARED_3D = 8
MIN_RESECTION_3D = 6


@dataclass(frozen=True)
class RelativePose:
    """``X2 = R X1 + t`` with ``|t| = 1`` (the scale is not observable)."""

    rotation: FloatArray
    translation: FloatArray


def estimate_essential(b1: FloatArray, b2: FloatArray) -> FloatArray:
    """Linear 8-point estimate of E from >= 8 bearing pairs, with singular values (1, 1, 0)."""
    if len(b1) < MIN_SHARED_3D:
        raise DegenerateGeometryError(f"an essential matrix needs at least {MIN_SHARED_3D} shared nodes, got {len(b1)}")
    rows = np.einsum("mi,mj->mij", b2, b1).reshape(-1, 9)
    _, _, vt = np.linalg.svd(rows, full_matrices=True)  # 8 rows: the null vector is the 9th
    E = vt[-1].reshape(3, 3)
    u, _, wt = np.linalg.svd(E)
    return u @ np.diag([1.0, 1.0, 0.0]) @ wt


def check_not_coplanar(b1: FloatArray, b2: FloatArray, sigma: float) -> None:
    """Raise if one plane explains the pairs as well as free 3d points (model selection).

    Coplanar nodes make the essential matrix ambiguous. A bearing homography fits
    such pairs to within the reading noise, while nodes with real relief leave
    parallax far above it: the median two-way transfer error decides (3 sigma).
    """
    from fgloc.init.homography import estimate_bearing_homography  # local: homography imports this module's error

    H = estimate_bearing_homography(b1, b2)
    err = np.minimum(angle_between(b1 @ H.T, b2), angle_between(b2 @ np.linalg.inv(H).T, b1))
    if np.median(err) < 3.0 * sigma:
        raise DegenerateGeometryError(
            "the shared nodes are (nearly) coplanar: a 3d survey needs nodes off one plane (use planar mode)"
        )


def triangulate_pair(pose: RelativePose, b1: FloatArray, b2: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Depths (s1, s2) along b1 and b2 (M,) that best satisfy ``s2 b2 = R s1 b1 + t``."""
    rb1 = b1 @ pose.rotation.T
    # Normal equations of [rb1, -b2] [s1, s2]^T = -t per pair, solved in closed form.
    a11 = np.einsum("mi,mi->m", rb1, rb1)
    a12 = -np.einsum("mi,mi->m", rb1, b2)
    a22 = np.einsum("mi,mi->m", b2, b2)
    r1 = -rb1 @ pose.translation
    r2 = b2 @ pose.translation
    det = a11 * a22 - a12 * a12
    det = np.where(np.abs(det) < 1e-15, np.nan, det)
    return (a22 * r1 - a12 * r2) / det, (a11 * r2 - a12 * r1) / det


def decompose_essential(E: FloatArray, b1: FloatArray, b2: FloatArray) -> tuple[RelativePose, int]:
    """The decomposition of E with the most pairs in front of both cameras, and that count."""
    u, _, vt = np.linalg.svd(E)
    if np.linalg.det(u) < 0:
        u = -u
    if np.linalg.det(vt) < 0:
        vt = -vt
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    best: tuple[RelativePose, int] | None = None
    for R in (u @ W @ vt, u @ W.T @ vt):
        for t in (u[:, 2], -u[:, 2]):
            pose = RelativePose(nearest_rotation(R), t / np.linalg.norm(t))
            s1, s2 = triangulate_pair(pose, b1, b2)
            count = int(np.sum((s1 > 0) & (s2 > 0)))
            if best is None or count > best[1]:
                best = (pose, count)
    assert best is not None
    return best


def epipolar_angles(E: FloatArray, b1: FloatArray, b2: FloatArray) -> FloatArray:
    """Angle (radians) between each b2 and the epipolar plane of its b1 (a Sampson-like residual)."""
    n = b1 @ E.T  # plane normals in camera 2
    norm = np.linalg.norm(n, axis=1)
    return np.abs(np.arcsin(np.clip(np.einsum("mi,mi->m", b2, n) / np.maximum(norm, 1e-300), -1.0, 1.0)))


def resect_camera(points: FloatArray, bearings: FloatArray) -> CameraPose:
    """Linear absolute pose of a camera base from >= 6 world points and their bearings."""
    if len(points) < MIN_RESECTION_3D:
        raise DegenerateGeometryError(
            f"placing a camera needs at least {MIN_RESECTION_3D} placed nodes it sees, got {len(points)}"
        )
    centre = points.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1)))) or 1.0
    xh = np.column_stack([(points - centre) / scale, np.ones(len(points))])  # normalized for conditioning
    rows = np.einsum("mki,mj->mkij", skew(bearings), xh).reshape(-1, 12)
    _, s, vt = np.linalg.svd(rows, full_matrices=False)
    if s[-2] < 1e-9 * s[0]:
        raise DegenerateGeometryError("cannot place camera: its nodes are degenerate (collinear or coplanar with it)")
    P = vt[-1].reshape(3, 4)
    if np.sum(np.einsum("mi,mi->m", bearings, xh @ P.T) > 0) < len(points) / 2:
        P = -P
    A = P[:, :3]
    lam = float(np.mean(np.linalg.svd(A, compute_uv=False)))
    Rt = nearest_rotation(A / lam)
    R = Rt.T
    c_normalized = -R @ (P[:, 3] / lam)
    return CameraPose(position=centre + scale * c_normalized, rotation=R)


def triangulate_rays(origins: FloatArray, directions: FloatArray) -> FloatArray | None:
    """Least-squares point nearest to rays (K >= 2, world frame); None if they are parallel."""
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    proj = np.eye(3)[None] - np.einsum("ki,kj->kij", d, d)
    A = proj.sum(axis=0)
    if np.linalg.cond(A) > 1e10:
        return None
    return np.linalg.solve(A, np.einsum("kij,kj->i", proj, origins))
