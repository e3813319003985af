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

from fgloc.core.errors import FglocError
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
from fgloc.init.planar import MIN_THRESHOLD, RANSAC_SEED, BearingSet, InitialEstimate, next_camera, starting_pair
from fgloc.init.ransac import ransac

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


def _pair(bs: BearingSet, a: int, b: int, rng: np.random.Generator) -> tuple[dict[int, CameraPose], int]:
    shared = bs.seen[a] & bs.seen[b]
    b1, b2 = bs.bearings[a, shared], bs.bearings[b, shared]
    E, inliers = ransac(
        len(b1), MIN_SHARED_3D,
        lambda idx: estimate_essential(b1[idx], b2[idx]),
        lambda E: epipolar_angles(E, b1, b2),
        threshold=max(PAIR_THRESHOLD_SIGMAS * bs.sigma, MIN_THRESHOLD), rng=rng,
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
    o = cameras[origin]
    rot = o.rotation.T
    length = float(np.linalg.norm(cameras[baseline].position - o.position))
    if length < 1e-12:
        raise DegenerateGeometryError("the gauge cameras are at the same place: no baseline")

    def move(p: FloatArray) -> FloatArray:
        return rot @ (p - o.position) / length

    return (
        {i: CameraPose(move(c.position), rot @ c.rotation) for i, c in cameras.items()},
        {j: move(p) for j, p in nodes.items()},
    )


def initialize_3d(survey: Survey) -> InitialEstimate:
    """Closed-form start for a 3d survey (see the module docstring)."""
    if survey.mode is not NodeMode.THREE_D:
        raise FglocError("initialize_3d needs a 3d survey")
    bs = BearingSet.from_survey(survey)
    ids = survey.camera_ids
    origin, baseline = ids.index(survey.gauge.origin), ids.index(survey.gauge.baseline)
    a, b = starting_pair(bs, survey, MIN_SHARED_3D)
    rng = np.random.default_rng(RANSAC_SEED)
    cameras, outliers = _pair(bs, a, b, rng)
    nodes: dict[int, FloatArray] = {}
    _triangulate_all(cameras, bs, nodes)
    while len(cameras) < len(ids):
        k, mask = next_camera(bs, cameras, nodes, ids, MIN_RESECTION_3D)
        vis = np.flatnonzero(mask)
        pts = np.array([nodes[j] for j in vis])
        bk = bs.bearings[k, vis]
        cam, _ = ransac(
            len(vis), MIN_RESECTION_3D,
            lambda idx: resect_camera(pts[idx], bk[idx]),
            lambda c: angle_between((pts - c.position) @ c.rotation, bk),
            threshold=max(RESECTION_THRESHOLD_SIGMAS * bs.sigma, MIN_THRESHOLD), rng=rng,
        )
        cameras[k] = cam
        _triangulate_all(cameras, bs, nodes)
    if origin not in cameras or baseline not in cameras:
        raise DegenerateGeometryError("the gauge cameras could not be placed")
    cameras, nodes = _to_3d_gauge(cameras, nodes, origin, baseline)
    unlocalized = {}
    for j, nid in enumerate(survey.node_ids):
        if j in nodes:
            continue
        n_seen = int(bs.seen[:, j].sum())
        unlocalized[nid] = (
            "seen by no camera" if n_seen == 0
            else "seen by one camera only: a 3d node needs two" if n_seen == 1
            else "its rays do not meet in front of the cameras"
        )
    return InitialEstimate(
        cameras={ids[i]: c for i, c in cameras.items()},
        nodes={survey.node_ids[j]: p for j, p in nodes.items()},
        unlocalized=unlocalized,
        suspected_outliers=outliers,
    )
