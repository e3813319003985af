"""Closed-form initial estimate from the bearings alone (no truth, no pose guess).

Planar surveys (the paper's "epipolar geometry in pan-tilt space"):

1. Average repeated readings of a (camera, node) pair into one unit bearing.
2. Start from the gauge pair if it shares >= 4 nodes, else from the pair of
   cameras sharing the most nodes. Estimate the bearing homography
   ``b2 ∝ H b1`` (DLT), decompose it, and keep the decomposition with the most
   nodes in front of both cameras. That fixes camera 1's height as the unit,
   the ground plane as z = 0 and both bases.
3. Place the pair's shared nodes where their rays meet the ground plane.
4. Add every other camera from >= 4 placed nodes it sees (a homography from
   the ground plane to its bearing sphere), then place the nodes it sees.
5. Move everything into the spec's gauge (origin camera above (0, 0),
   baseline camera above (1, 0)) by a similarity of the plane.

Each node is placed by the inverse-variance weighted mean of the ground points
of its rays (a ray's ground error grows as range / sin(grazing angle)). A node
seen by no placed camera is reported as unlocalized.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.geometry import FloatArray, angle_between
from fgloc.core.model import CameraPose, NodeMode, Survey
from fgloc.init.homography import (
    DegenerateGeometryError,
    camera_from_plane_homography,
    check_spans_plane,
    chirality_score,
    decompose_bearing_homography,
    estimate_bearing_homography,
    plane_to_bearing_homography,
)
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

MIN_SHARED_PLANAR = 4
#: RANSAC inlier thresholds in units of the reading sigma: a pair's homography
#: transfer combines two readings; a resection also carries the start's node errors.
PAIR_THRESHOLD_SIGMAS = 25.0
RESECTION_THRESHOLD_SIGMAS = 30.0


def ground_hits(
    positions: FloatArray, directions: FloatArray, sigma: float
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Where rays (world directions from camera positions, (K, 3)) meet z = 0.

    Returns ground points (K, 2), each hit's tolerance radius (a generous
    6 x its along-range error, range x sigma / sin(grazing)), and which rays
    reach the ground in front of their camera.
    """
    d = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    ok = (d[:, 2] < -1e-9) & (positions[:, 2] > 0)
    s = np.where(ok, -positions[:, 2] / np.where(ok, d[:, 2], -1.0), 0.0)
    pts = positions[:, :2] + s[:, None] * d[:, :2]
    tol = 6.0 * s * sigma / np.maximum(-d[:, 2], 1e-9) + 1e-12
    return pts, tol, ok


#: Above this many hits, :func:`consensus_ground_point` tries only this many of them as
#: the consensus centre (evenly spaced in input order), so memory and time stay linear
#: in the number of hits: a node read 20000 times by each camera must not build a
#: 40000 x 40000 distance table.
MAX_CONSENSUS_CANDIDATES = 256


def consensus_ground_point(pts: FloatArray, tol: FloatArray) -> tuple[FloatArray, np.ndarray]:
    """The ground point most hits agree on, and which hits agree (a 1-point RANSAC).

    Two hits agree when they are closer than the sum of their tolerances; the
    candidate hit with the most agreeing hits wins (ties: the sharpest), and the
    result is the inverse-variance mean of its agreeing set. One gross ray among
    three or more cannot drag the point away. Every hit is a candidate up to
    :data:`MAX_CONSENSUS_CANDIDATES` hits; beyond, that many evenly spaced ones are
    (memory O(candidates x hits), i.e. linear in the hits).
    """
    n = len(pts)
    cand = (np.arange(n) if n <= MAX_CONSENSUS_CANDIDATES
            else np.unique(np.linspace(0, n - 1, MAX_CONSENSUS_CANDIDATES).round().astype(np.int64)))
    dist = np.hypot(pts[cand, 0, None] - pts[None, :, 0], pts[cand, 1, None] - pts[None, :, 1])
    agree = dist < tol[cand, None] + tol[None, :]
    counts = agree.sum(axis=1)
    best = int(np.lexsort((tol[cand], -counts))[0])
    inliers = agree[best]
    w = 1.0 / tol[inliers] ** 2
    return (w[:, None] * pts[inliers]).sum(0) / w.sum(), inliers


def _place_nodes(cameras: dict[int, CameraPose], bs: BearingSet, nodes: dict[int, FloatArray]) -> None:
    """Place every unplaced node seen by a placed camera where its rays meet the ground.

    Ground hits are computed per camera for all nodes at once; one or two hits
    are averaged by inverse variance, three or more go through the consensus.
    """
    n_nodes = bs.seen.shape[1]
    todo = np.ones(n_nodes, dtype=bool)
    todo[list(nodes)] = False
    cam_ids = list(cameras)
    pts = np.full((len(cam_ids), n_nodes, 2), np.nan)
    tol = np.full((len(cam_ids), n_nodes), np.inf)
    for row, i in enumerate(cam_ids):
        js = np.flatnonzero(bs.seen[i] & todo)
        if not len(js):
            continue
        cam = cameras[i]
        dirs = bs.bearings[i, js] @ cam.rotation.T
        p, t, ok = ground_hits(np.broadcast_to(cam.position, dirs.shape), dirs, bs.sigma)
        pts[row, js[ok]] = p[ok]
        tol[row, js[ok]] = t[ok]
    hit = np.isfinite(tol)
    n_hits = hit.sum(axis=0)
    w = np.where(hit, 1.0 / np.where(hit, tol, 1.0) ** 2, 0.0)
    mean = np.einsum("cn,cnk->nk", w, np.nan_to_num(pts)) / np.maximum(w.sum(axis=0), 1e-300)[:, None]
    for j in np.flatnonzero(todo & (n_hits >= 1)):
        if n_hits[j] >= 3:
            xy, _ = consensus_ground_point(pts[hit[:, j], j], tol[hit[:, j], j])
        else:
            xy = mean[j]
        nodes[int(j)] = np.array([xy[0], xy[1], 0.0])


def _name(ids: list[str] | None, i: int) -> str:
    return ids[i] if ids is not None else f"#{i}"


def _pair_frames(bs: BearingSet, a: int, b: int, rng: np.random.Generator, ids: list[str] | None = None
) -> tuple[list[dict[int, CameraPose]], int]:
    """Cameras a and b in a frame with the plane at z = 0 and camera a above the origin.

    Returns every decomposition of the pair's homography that puts (nearly) all
    shared nodes in front of both cameras: usually one, but a planar scene seen
    by two cameras can admit two (the classic two-fold ambiguity). The
    homography is fitted by RANSAC over 4-node samples; the second value is the
    number of shared nodes it found inconsistent.
    """
    b1, b2 = shared_bearings(bs, a, b)
    H, inliers = ransac(
        len(b1), 4,
        lambda idx: estimate_bearing_homography(b1[idx], b2[idx]),
        # Transfer both ways and keep the smaller angle: one direction amplifies the
        # noise by the ratio of the node's ranges, the other shrinks it.
        lambda H: np.minimum(angle_between(b1 @ H.T, b2), angle_between(b2 @ np.linalg.inv(H).T, b1)),
        threshold=ransac_threshold(PAIR_THRESHOLD_SIGMAS, bs), rng=rng,
        what=f"ground-plane homography of the {len(b1)} nodes cameras {_name(ids, a)} and {_name(ids, b)} both see",
    )
    b1, b2 = b1[inliers], b2[inliers]
    check_spans_plane(b1, b2, bs.sigma)
    candidates = decompose_bearing_homography(H)
    scores = np.array([chirality_score(c, b1, b2) for c in candidates])
    keep = [c for c, sc in zip(candidates, scores) if sc >= 0.98 * scores.max()]
    frames = []
    for cand in keep:
        n = cand.normal / np.linalg.norm(cand.normal)  # points from camera a down to the plane
        height = 1.0 / np.linalg.norm(cand.normal)
        up = -n
        w = -cand.rotation.T @ cand.translation  # camera b's centre in camera a's base frame
        horiz = w - (w @ up) * up
        if np.linalg.norm(horiz) < 1e-3 * max(float(np.linalg.norm(w)), 1e-300):
            raise DegenerateGeometryError("the two cameras stand on the same vertical: no ground baseline")
        x_axis = horiz / np.linalg.norm(horiz)
        y_axis = np.cross(up, x_axis)
        R_a = np.vstack([x_axis, y_axis, up])  # camera-a base -> world
        c_a = np.array([0.0, 0.0, height])
        frames.append({a: CameraPose(c_a, R_a), b: CameraPose(R_a @ w + c_a, R_a @ cand.rotation.T)})
    return frames, int(len(inliers) - inliers.sum())


def _to_planar_gauge(
    cameras: dict[int, CameraPose], nodes: dict[int, FloatArray], origin: int, baseline: int
) -> tuple[dict[int, CameraPose], dict[int, FloatArray]]:
    """Similarity of the plane taking the gauge cameras' ground points to (0, 0) and (1, 0)."""
    g0 = cameras[origin].position[:2]
    d = cameras[baseline].position[:2] - g0
    length = float(np.linalg.norm(d))
    if length < 1e-3 * max(float(np.linalg.norm(cameras[baseline].position - cameras[origin].position)), 1e-300):
        raise DegenerateGeometryError("the gauge cameras stand on the same vertical: no ground baseline")
    ang = np.arctan2(d[1], d[0])
    c, s = np.cos(-ang), np.sin(-ang)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return move_into_gauge(cameras, nodes, rot, np.array([g0[0], g0[1], 0.0]), length)


def _grow(
    bs: BearingSet, cameras: dict[int, CameraPose], ids: list[str], rng: np.random.Generator
) -> dict[int, FloatArray]:
    """Place nodes from the starting cameras, then add every other camera and its nodes.

    A camera is resected from a ground-plane-to-bearing homography (RANSAC over
    4 placed nodes it sees); nodes are placed where their rays meet z = 0.
    """

    def resect(k: int, vis: np.ndarray, nodes: dict[int, FloatArray]) -> CameraPose:
        xy = np.array([nodes[int(j)][:2] for j in np.flatnonzero(vis)])
        bk = bs.bearings[k, vis]
        p = np.column_stack([xy, np.ones(len(xy))])
        G, _ = ransac(
            len(xy), 4,
            lambda idx: plane_to_bearing_homography(xy[idx], bk[idx]),
            lambda G: angle_between(p @ G.T, bk),
            threshold=ransac_threshold(RESECTION_THRESHOLD_SIGMAS, bs), rng=rng,
            what=f"placing camera {ids[k]} from the {len(xy)} placed nodes it sees",
        )
        return camera_from_plane_homography(G)

    return grow(bs, cameras, ids, MIN_SHARED_PLANAR, resect, _place_nodes)


def angular_cost(bs: BearingSet, cameras: dict[int, CameraPose], nodes: dict[int, FloatArray]) -> float:
    """Sum over observed (camera, node) pairs of the squared angle between bearing and prediction."""
    total = 0.0
    for i, cam in cameras.items():
        js = [int(j) for j in np.flatnonzero(bs.seen[i]) if int(j) in nodes]
        if not js:
            continue
        pred = (np.array([nodes[j] for j in js]) - cam.position) @ cam.rotation
        pred /= np.linalg.norm(pred, axis=1, keepdims=True)
        cos = np.clip(np.einsum("mi,mi->m", pred, bs.bearings[i, js]), -1.0, 1.0)
        total += float(np.sum(np.arccos(cos) ** 2))
    return total


def _uprightness(cameras: dict[int, CameraPose]) -> float:
    """How close the bases are to level or to hanging upside down (sum of |R_zz|)."""
    return float(sum(abs(c.rotation[2, 2]) for c in cameras.values()))


def initialize_planar(survey: Survey) -> InitialEstimate:
    """Closed-form start for a planar survey (see the module docstring).

    When the starting pair's homography admits two physical decompositions,
    each is grown over all cameras and the one whose bearings fit best wins.
    With only two cameras both fit equally (the scene is truly ambiguous from
    bearings alone); then the one with the more level (or upside-down) camera
    bases is kept, which is how PTZ heads are mounted in practice.
    """
    s = start_up(survey, NodeMode.PLANAR, MIN_SHARED_PLANAR, "initialize_planar")
    bs = s.bs
    best: tuple[float, float, dict[int, CameraPose], dict[int, FloatArray]] | None = None
    frames, outliers = _pair_frames(bs, *s.pair, s.rng, s.ids)
    for cameras in frames:
        nodes = _grow(bs, cameras, s.ids, s.rng)
        cost = angular_cost(bs, cameras, nodes)
        key = (round(cost / (len(survey.observations) * survey.sigma**2 + 1e-300), 0), -_uprightness(cameras))
        if best is None or key < best[:2]:
            best = (key[0], key[1], cameras, nodes)
    assert best is not None
    cameras, nodes = _to_planar_gauge(best[2], best[3], s.origin, s.baseline)
    return initial_estimate(survey, bs, cameras, nodes, outliers, lambda n_seen: "no ray reaches the ground plane")
