"""Homographies between bearing spheres, and from the ground plane to a bearing sphere.

Bearings are unit vectors, so the two-view relations hold on the whole sphere,
not only in front of an image plane, and they keep their sign: a node seen
along ``b`` lies at ``+s b`` with s > 0. Every estimate here uses that sign
(chirality) to choose among the algebraic solutions.

* Two cameras seeing coplanar nodes: ``b2 ∝ H b1`` with ``H = R + T N^T``,
  where ``X2 = R X1 + T`` maps camera-1 base coordinates to camera-2 base
  coordinates and ``N = n / d`` for the plane ``n^T X1 = d`` (d > 0, n the unit
  normal pointing from camera 1 towards the plane).
* One camera and nodes at known ground positions (x, y, 0):
  ``b ∝ G (x, y, 1)`` with ``G = R^T [e1, e2, -c]`` for the base (R, c).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, nearest_rotation, skew
from fgloc.core.model import CameraPose


class DegenerateGeometryError(FglocError):
    """The observations do not determine the requested geometry."""


@dataclass(frozen=True)
class RelativePlanarPose:
    """One decomposition of ``H = R + T N^T`` (see the module docstring)."""

    rotation: FloatArray  # R, camera-1 base -> camera-2 base
    translation: FloatArray  # T = t / d, in units of camera 1's height above the plane
    normal: FloatArray  # N = n / d, in camera-1 base coordinates


def _null_vector(a: FloatArray) -> tuple[FloatArray, float]:
    """Unit right null vector of ``a`` and the ratio of its two smallest singular values."""
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    ratio = s[-1] / s[-2] if s[-2] > 0 else 1.0
    return vt[-1], float(ratio)


def check_spans_plane(b1: FloatArray, b2: FloatArray, sigma: float) -> None:
    """Raise if the shared nodes are (nearly) collinear.

    Collinear ground nodes lie in one plane through each camera, so their
    bearings fill only a great circle: the stacked bearings have rank 2. The
    smallest singular value of the stack, relative to the largest, is then at
    the noise level (a node spread over a field gives 0.05 or more even from a
    camera 0.05 baselines high); below 10 sigma the survey is refused.
    """
    for b in (b1, b2):
        s = np.linalg.svd(np.asarray(b, dtype=float), compute_uv=False)
        if len(b) < 4 or s[-1] < 10.0 * sigma * s[0]:
            raise DegenerateGeometryError(
                "the shared nodes are (nearly) collinear: a planar survey needs nodes that span the ground plane"
            )


def estimate_bearing_homography(b1: FloatArray, b2: FloatArray) -> FloatArray:
    """DLT estimate of H with ``b2 = lambda H b1``, lambda > 0, from >= 4 bearing pairs (M, 3).

    Scaled so that its middle singular value is 1 (then ``H = R + T N^T``
    exactly for noise-free data) and signed so that most pairs have positive
    lambda.
    """
    b1 = np.asarray(b1, dtype=float)
    b2 = np.asarray(b2, dtype=float)
    if len(b1) < 4:
        raise DegenerateGeometryError(f"a homography needs at least 4 shared nodes, got {len(b1)}")
    # [b2]_x H b1 = 0: three rows per pair, kron(S[k], b1) against row-major vec(H).
    s = skew(b2)  # (M, 3, 3)
    rows = np.einsum("mki,mj->mkij", s, b1).reshape(-1, 9)
    h, _ = _null_vector(rows)
    H = h.reshape(3, 3)
    sv = np.linalg.svd(H, compute_uv=False)
    if sv[1] <= 1e-12 * sv[0]:
        raise DegenerateGeometryError("bearing homography is degenerate (are the nodes collinear?)")
    H = H / sv[1]
    if np.sum(np.einsum("mi,ij,mj->m", b2, H, b1) > 0) < len(b1) / 2:
        H = -H
    return H


def decompose_bearing_homography(H: FloatArray) -> list[RelativePlanarPose]:
    """The four algebraic decompositions ``H = R + T N^T`` (Ma, Soatto, Kosecka, Sastry §5.3).

    ``H`` must be normalized to a middle singular value of 1. For a pure
    rotation (the two cameras at the same place) translation and normal are
    undetermined and :class:`DegenerateGeometryError` is raised.
    """
    _, s, vt = np.linalg.svd(H.T @ H)
    v = vt.T
    if np.linalg.det(v) < 0:
        v = -v
    s1, s3 = s[0], s[2]
    if s1 - s3 < 1e-12:
        raise DegenerateGeometryError("the two cameras see the nodes from the same point (no baseline)")
    v1, v2, v3 = v[:, 0], v[:, 1], v[:, 2]
    a = np.sqrt(max(1.0 - s3, 0.0))
    b = np.sqrt(max(s1 - 1.0, 0.0))
    den = np.sqrt(s1 - s3)
    out: list[RelativePlanarPose] = []
    for u in ((a * v1 + b * v3) / den, (a * v1 - b * v3) / den):
        U = np.column_stack([v2, u, np.cross(v2, u)])
        hv2, hu = H @ v2, H @ u
        W = np.column_stack([hv2, hu, np.cross(hv2, hu)])
        R = nearest_rotation(W @ U.T)
        N = np.cross(v2, u)
        T = (H - R) @ N
        out.append(RelativePlanarPose(R, T, N))
        out.append(RelativePlanarPose(R, -T, -N))
    return out


def chirality_score(pose: RelativePlanarPose, b1: FloatArray, b2: FloatArray) -> int:
    """Number of bearing pairs whose plane point lies in front of both cameras."""
    depth1 = b1 @ pose.normal  # 1 / s for X1 = s b1 on the plane N^T X1 = 1
    ok = depth1 > 0
    x1 = b1[ok] / depth1[ok, None]
    x2 = x1 @ pose.rotation.T + pose.translation
    return int(np.sum(np.einsum("mi,mi->m", x2, b2[ok]) > 0))


def plane_to_bearing_homography(ground_xy: FloatArray, bearings: FloatArray) -> FloatArray:
    """DLT estimate of G with ``b = lambda G (x, y, 1)``, lambda > 0, from >= 4 nodes."""
    xy = np.asarray(ground_xy, dtype=float)
    if len(xy) < 4:
        raise DegenerateGeometryError(f"placing a camera needs at least 4 placed nodes it sees, got {len(xy)}")
    p = np.column_stack([xy, np.ones(len(xy))])
    rows = np.einsum("mki,mj->mkij", skew(np.asarray(bearings, dtype=float)), p).reshape(-1, 9)
    g, _ = _null_vector(rows)
    G = g.reshape(3, 3)
    if np.sum(np.einsum("mi,mi->m", bearings, p @ G.T) > 0) < len(xy) / 2:
        G = -G
    return G


def camera_from_plane_homography(G: FloatArray) -> CameraPose:
    """Recover a camera base from ``G = lambda R^T [e1, e2, -c]``, lambda > 0.

    The scale comes from the orthonormal first two columns; the sign of G (from
    chirality) fixes the handedness, so there is no mirror ambiguity. Raises
    when the nodes do not span the plane (then G is rank deficient).
    """
    scale = 0.5 * (np.linalg.norm(G[:, 0]) + np.linalg.norm(G[:, 1]))
    if scale <= 1e-12 * np.linalg.norm(G):
        raise DegenerateGeometryError("cannot place camera: its nodes do not span the ground plane")
    Gs = G / scale
    rt = np.column_stack([Gs[:, 0], Gs[:, 1], np.cross(Gs[:, 0], Gs[:, 1])])
    Rt = nearest_rotation(rt)  # R^T
    R = Rt.T
    c = -R @ Gs[:, 2]
    return CameraPose(position=c, rotation=R)
