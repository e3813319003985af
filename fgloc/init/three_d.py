"""Closed-form initial estimate for 3d surveys (node heights unknown), from bearings alone.

1. Start from the gauge pair if it shares >= 8 nodes, else from the pair of
   cameras sharing the most nodes: essential matrix by RANSAC over 8-node
   samples, the decomposition with the most nodes in front of both cameras,
   baseline length 1.
2. Triangulate the nodes both see; add every other camera by a linear absolute
   pose from >= 6 placed nodes it sees (RANSAC), triangulate newly covered nodes.
3. Move everything into the spec's 3d gauge: the origin camera's base is the
   world frame and the baseline camera is at distance 1.

A node seen by fewer than two placed cameras cannot be triangulated and is
reported unlocalized.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.geometry import FloatArray, angle_between
from fgloc.core.model import CameraPose, NodeMode, Survey
from fgloc.init.essential import (
    MIN_RESECTION_3D,
    MIN_SHARED_3D,
    RelativePose,
    check_not_coplanar,
    decompose_essential,
    epipolar_angles,
    estimate_essential,
    resect_camera,
    triangulate_rays,
)
from fgloc.init.homography import DegenerateGeometryError
from fgloc.init.ransac import ransac
from fgloc.init.start import (
    BearingSet,
    InitialEstimate,
    grow,
    initial_estimate,
    move_into_gauge,
    ransac_threshold,
    shared_bearings,
    start_up,
)

PAIR_THRESHOLD_SIGMAS = 10.0
RESECTION_THRESHOLD_SIGMAS = 30.0


def _triangulate_all(cameras: dict[int, CameraPose], bs: BearingSet, nodes: dict[int, FloatArray]) -> None:
    for j in range(bs.seen.shape[1]):
        if j in nodes:
            continue
        seen = [i for i in cameras if bs.seen[i, j]]
        if len(seen) < 2:
            continue
        origins = np.array([cameras[i].position for i in seen])
        dirs = np.array([cameras[i].rotation @ bs.bearings[i, j] for i in seen])
        x = triangulate_rays(origins, dirs)
        if x is not None and np.all(np.einsum("ki,ki->k", x - origins, dirs) > 0):
            nodes[j] = x


def _name(ids: list[str] | None, i: int) -> str:
    return ids[i] if ids is not None else f"#{i}"


def _pair(bs: BearingSet, a: int, b: int, rng: np.random.Generator, ids: list[str] | None = None
) -> tuple[dict[int, CameraPose], int]:
    b1, b2 = shared_bearings(bs, a, b)
    E, inliers = ransac(
        len(b1), MIN_SHARED_3D,
        lambda idx: estimate_essential(b1[idx], b2[idx]),
        lambda E: epipolar_angles(E, b1, b2),
        threshold=ransac_threshold(PAIR_THRESHOLD_SIGMAS, bs), rng=rng,
        what=f"essential matrix of the {len(b1)} nodes cameras {_name(ids, a)} and {_name(ids, b)} both see",
    )
    check_not_coplanar(b1[inliers], b2[inliers], bs.sigma)
    pose, _ = decompose_essential(E, b1[inliers], b2[inliers])
    rel = RelativePose(pose.rotation, pose.translation)
    cam_a = CameraPose(np.zeros(3), np.eye(3))
    cam_b = CameraPose(-rel.rotation.T @ rel.translation, rel.rotation.T)
    return {a: cam_a, b: cam_b}, int(len(inliers) - inliers.sum())


def _to_3d_gauge(
    cameras: dict[int, CameraPose], nodes: dict[int, FloatArray], origin: int, baseline: int
) -> tuple[dict[int, CameraPose], dict[int, FloatArray]]:
    """Similarity taking the origin camera's base to the world frame and the baseline camera to distance 1."""
    o = cameras[origin]
    length = float(np.linalg.norm(cameras[baseline].position - o.position))
    if length < 1e-12:
        raise DegenerateGeometryError("the gauge cameras are at the same place: no baseline")
    return move_into_gauge(cameras, nodes, o.rotation.T, o.position, length)


def initialize_3d(survey: Survey) -> InitialEstimate:
    """Closed-form start for a 3d survey (see the module docstring)."""
    st = start_up(survey, NodeMode.THREE_D, MIN_SHARED_3D, "initialize_3d")
    bs, rng = st.bs, st.rng
    cameras, outliers = _pair(bs, *st.pair, rng, st.ids)

    def resect(k: int, mask: np.ndarray, nodes: dict[int, FloatArray]) -> CameraPose:
        vis = np.flatnonzero(mask)
        pts = np.array([nodes[int(j)] for j in vis])
        bk = bs.bearings[k, vis]
        cam, _ = ransac(
            len(vis), MIN_RESECTION_3D,
            lambda idx: resect_camera(pts[idx], bk[idx]),
            lambda c: angle_between((pts - c.position) @ c.rotation, bk),
            threshold=ransac_threshold(RESECTION_THRESHOLD_SIGMAS, bs), rng=rng,
            what=f"placing camera {st.ids[k]} from the {len(vis)} placed nodes it sees",
        )
        return cam

    nodes = grow(bs, cameras, st.ids, MIN_RESECTION_3D, resect, _triangulate_all)
    if st.origin not in cameras or st.baseline not in cameras:
        raise DegenerateGeometryError("the gauge cameras could not be placed")
    cameras, nodes = _to_3d_gauge(cameras, nodes, st.origin, st.baseline)
    return initial_estimate(
        survey, bs, cameras, nodes, outliers,
        lambda n_seen: "seen by one camera only: a 3d node needs two" if n_seen == 1
        else "its rays do not meet in front of the cameras",
    )
