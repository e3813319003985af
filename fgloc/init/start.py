"""The start-up both closed-form initializations share (planar and 3d).

Both begin alike: average the readings into one bearing per (camera, node) pair
(:class:`BearingSet`), choose the starting camera pair (:func:`starting_pair`),
seed RANSAC (:data:`RANSAC_SEED`), then grow: add the unplaced camera seeing the
most placed nodes (:func:`next_camera`), resect it, place the nodes it newly
covers (:func:`grow`). Both end alike: a similarity moves cameras and nodes into
the gauge (:func:`move_into_gauge`) and the indices become ids
(:func:`initial_estimate`). The geometry in between is the mode's own
(:mod:`fgloc.init.planar`: homographies, ground plane; :mod:`fgloc.init.three_d`:
essential matrix, triangulation).

Cameras and nodes are indexed by their position in ``Survey.camera_ids`` /
``Survey.node_ids`` while growing; angles are radians; positions are in the
frame of the starting pair until :func:`move_into_gauge`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, pan_tilt_bearing
from fgloc.core.model import CameraPose, NodeMode, Survey
from fgloc.init.homography import DegenerateGeometryError

#: Floor of every RANSAC angle threshold (radians): numerical noise of noise-free data.
MIN_THRESHOLD = 1e-9
#: RANSAC is seeded so that a survey always gives the same start.
RANSAC_SEED = 20260101


@dataclass
class InitialEstimate:
    """Camera bases and node positions (world, gauge frame) to start the joint solve."""

    cameras: dict[str, CameraPose]
    nodes: dict[str, FloatArray]
    unlocalized: dict[str, str] = field(default_factory=dict)
    #: (camera, node) pairs RANSAC found inconsistent while building the start.
    suspected_outliers: int = 0


@dataclass(frozen=True)
class BearingSet:
    """One averaged unit bearing per observed (camera, node) pair, as a dense table."""

    bearings: FloatArray  # (n_cameras, n_nodes, 3), NaN where not observed
    seen: np.ndarray  # (n_cameras, n_nodes) bool
    sigma: float  # typical reading noise, radians

    @classmethod
    def from_survey(cls, survey: Survey) -> BearingSet:
        t = survey.observation_table
        n_cam, n_nodes = len(survey.camera_ids), len(survey.node_ids)
        acc = np.zeros((n_cam, n_nodes, 3))
        np.add.at(acc, (t.camera_index, t.node_index), pan_tilt_bearing(t.pan, t.tilt))
        norm = np.linalg.norm(acc, axis=-1)
        seen = norm > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            bearings = np.where(seen[..., None], acc / norm[..., None], np.nan)
        return cls(bearings=bearings, seen=seen, sigma=float(np.median(t.sigma)) if len(t) else survey.sigma)


def ransac_threshold(sigmas: float, bs: BearingSet) -> float:
    """A RANSAC inlier threshold (radians) of ``sigmas`` reading sigmas, floored at :data:`MIN_THRESHOLD`."""
    return max(sigmas * bs.sigma, MIN_THRESHOLD)


def shared_bearings(bs: BearingSet, a: int, b: int) -> tuple[FloatArray, FloatArray]:
    """Unit bearings (K, 3) of the K nodes both cameras ``a`` and ``b`` see, in each camera's base frame."""
    shared = bs.seen[a] & bs.seen[b]
    return bs.bearings[a, shared], bs.bearings[b, shared]


def covisibility(bs: BearingSet) -> np.ndarray:
    """(n_cameras, n_cameras) number of nodes each pair of cameras both sees."""
    s = bs.seen.astype(np.int64)
    return s @ s.T


def starting_pair(bs: BearingSet, survey: Survey, min_shared: int) -> tuple[int, int]:
    """The gauge pair if it shares ``min_shared`` nodes, else the pair of cameras sharing the most."""
    ids = survey.camera_ids
    origin, baseline = ids.index(survey.gauge.origin), ids.index(survey.gauge.baseline)
    shared = covisibility(bs)
    if shared[origin, baseline] >= min_shared:
        return origin, baseline
    off = shared - np.diag(np.diag(shared))
    a, b = (int(v) for v in np.unravel_index(int(np.argmax(off)), off.shape))
    if off[a, b] < min_shared:
        raise DegenerateGeometryError(
            f"no two cameras share {min_shared} nodes (best: {ids[a]} and {ids[b]} share {off[a, b]})"
        )
    return a, b


def next_camera(
    bs: BearingSet, cameras: dict[int, CameraPose], nodes: dict[int, FloatArray], ids: list[str], min_shared: int
) -> tuple[int, np.ndarray]:
    """The unplaced camera seeing the most placed nodes, and which nodes those are (mask).

    Raises, naming the cameras, when none sees ``min_shared`` placed nodes (the
    co-visibility graph is disconnected or too weakly connected).
    """
    placed = np.zeros(bs.seen.shape[1], dtype=bool)
    placed[list(nodes)] = True
    counts = [(int(np.sum(bs.seen[i] & placed)), i) for i in range(len(ids)) if i not in cameras]
    n_best, k = max(counts)
    if n_best < min_shared:
        missing = sorted(ids[i] for _, i in counts)
        raise DegenerateGeometryError(
            f"camera(s) {', '.join(missing)} share fewer than {min_shared} nodes with the placed cameras"
        )
    return k, bs.seen[k] & placed


@dataclass(frozen=True)
class StartUp:
    """What every initialization begins with: the bearings, the camera ids, the gauge
    cameras' and the starting pair's indices, and the seeded RANSAC generator."""

    bs: BearingSet
    ids: list[str]
    origin: int
    baseline: int
    pair: tuple[int, int]
    rng: np.random.Generator


def start_up(survey: Survey, mode: NodeMode, min_shared: int, caller: str) -> StartUp:
    """Check the survey's mode, average its bearings and choose the starting pair
    (sharing at least ``min_shared`` nodes); ``caller`` names the function in the error."""
    if survey.mode is not mode:
        raise FglocError(f"{caller} needs a {mode.value} survey")
    bs = BearingSet.from_survey(survey)
    ids = survey.camera_ids
    origin, baseline = ids.index(survey.gauge.origin), ids.index(survey.gauge.baseline)
    pair = starting_pair(bs, survey, min_shared)
    return StartUp(bs, ids, origin, baseline, pair, np.random.default_rng(RANSAC_SEED))


#: Places every still unplaced node it can from the placed cameras (updates ``nodes``).
PlaceNodes = Callable[[dict[int, CameraPose], BearingSet, dict[int, FloatArray]], None]
#: Resects camera k from the placed nodes it sees (mask over nodes) and the placed nodes.
Resect = Callable[[int, np.ndarray, dict[int, FloatArray]], CameraPose]


def grow(
    bs: BearingSet, cameras: dict[int, CameraPose], ids: list[str], min_shared: int, resect: Resect, place: PlaceNodes
) -> dict[int, FloatArray]:
    """Place nodes from the starting cameras, then add every other camera (the one
    seeing the most placed nodes first, at least ``min_shared``) and its nodes.
    ``cameras`` is updated in place; returns the placed nodes."""
    nodes: dict[int, FloatArray] = {}
    place(cameras, bs, nodes)
    while len(cameras) < len(ids):
        k, vis = next_camera(bs, cameras, nodes, ids, min_shared)
        cameras[k] = resect(k, vis, nodes)
        place(cameras, bs, nodes)
    return nodes


def move_into_gauge(
    cameras: dict[int, CameraPose], nodes: dict[int, FloatArray], rotation: FloatArray, shift: FloatArray,
    length: float,
) -> tuple[dict[int, CameraPose], dict[int, FloatArray]]:
    """Apply the similarity ``p -> rotation @ (p - shift) / length`` to camera centres and
    nodes, and ``R -> rotation @ R`` to camera base rotations (base -> world)."""

    def move(p: FloatArray) -> FloatArray:
        return rotation @ (p - shift) / length

    new_cams = {i: CameraPose(move(cam.position), rotation @ cam.rotation) for i, cam in cameras.items()}
    new_nodes = {j: move(p) for j, p in nodes.items()}
    return new_cams, new_nodes


def initial_estimate(
    survey: Survey,
    bs: BearingSet,
    cameras: dict[int, CameraPose],
    nodes: dict[int, FloatArray],
    suspected_outliers: int,
    why_unplaced: Callable[[int], str],
) -> InitialEstimate:
    """The estimate keyed by ids. A node not placed is unlocalized: "seen by no camera",
    else ``why_unplaced(number of cameras that see it)``."""
    unlocalized = {}
    for j, nid in enumerate(survey.node_ids):
        if j in nodes:
            continue
        n_seen = int(bs.seen[:, j].sum())
        unlocalized[nid] = "seen by no camera" if n_seen == 0 else why_unplaced(n_seen)
    return InitialEstimate(
        cameras={survey.camera_ids[i]: cam for i, cam in cameras.items()},
        nodes={survey.node_ids[j]: p for j, p in nodes.items()},
        unlocalized=unlocalized,
        suspected_outliers=suspected_outliers,
    )
