"""Simulated surveys with known truth, deterministic by seed.

The default is the paper's scenario: nodes uniform in the unit square on z = 0,
camera 0 above (0, 0) and camera 1 above (1, 0), base rotations with random yaw
and a few degrees of random roll and pitch, pan and tilt noise N(0, sigma) with
sigma = 0.1 degree. Positions are in the planar gauge frame (baseline = 1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fgloc.core.geometry import FloatArray, base_rotation, project_pan_tilt, wrap_angle
from fgloc.core.model import CameraPose, Gauge, NodeMode, Observation, Survey, Truth
from fgloc.core.subsets import draw_subsets

PAPER_SIGMA = float(np.deg2rad(0.1))


@dataclass(frozen=True)
class PaperScenario:
    """Parameters of the paper's two-camera planar scenario.

    Heights are in baseline units; ``max_roll_pitch_deg`` bounds the uniform
    random roll and pitch of each camera base; ``repeats`` is how many
    independent (pan, tilt) readings each camera takes of each node.

    ``subset_schedule = (k, T)`` re-measures instead, as the paper's system
    does: T random subsets of k nodes are drawn (:mod:`fgloc.core.subsets`)
    and for each subset every camera takes ``repeats`` fresh readings of each
    of its nodes, tagged with the subset's index. A node in c subsets then
    has ``c * repeats`` readings per camera; the joint solve uses them all.
    """

    n_nodes: int = 100
    sigma: float = PAPER_SIGMA
    heights: tuple[float, float] = (0.1, 0.1)
    max_roll_pitch_deg: float = 3.0
    repeats: int = 1
    seed: int = 0
    subset_schedule: tuple[int, int] | None = None


def simulated_survey(
    mode: NodeMode,
    sigma: float,
    camera_ids: list[str],
    cameras: list[CameraPose],
    node_ids: list[str],
    nodes: FloatArray,
    observations: list[Observation],
) -> Survey:
    """A survey whose truth (in the gauge frame, cameras 'cam0'/'cam1' by default) is known."""
    return Survey(
        mode=mode,
        gauge=Gauge(origin=camera_ids[0], baseline=camera_ids[1]),
        sigma=sigma,
        camera_ids=camera_ids,
        node_ids=node_ids,
        observations=observations,
        truth=Truth(cameras=dict(zip(camera_ids, cameras)), nodes={n: p for n, p in zip(node_ids, nodes)}),
    )


def random_base_rotation(rng: np.random.Generator, max_roll_pitch_deg: float) -> FloatArray:
    """Base rotation with uniform yaw in [-pi, pi) and roll, pitch uniform within the bound."""
    yaw = rng.uniform(-np.pi, np.pi)
    bound = np.deg2rad(max_roll_pitch_deg)
    pitch, roll = rng.uniform(-bound, bound, size=2)
    return base_rotation(yaw, pitch, roll)


def observe(
    camera_ids: list[str],
    cameras: list[CameraPose],
    node_ids: list[str],
    nodes: FloatArray,
    sigma: float,
    rng: np.random.Generator,
    repeats: int = 1,
    visible: np.ndarray | None = None,
) -> list[Observation]:
    """Noisy (pan, tilt) observations of ``nodes`` (N, 3) by each camera.

    ``visible`` (n_cameras, N) bool masks occluded pairs; each visible pair is
    observed ``repeats`` times with independent noise. Order: by repeat, then
    node, then camera (a survey lights one node at a time).
    """
    n_cam, n_nodes = len(cameras), len(nodes)
    if visible is None:
        visible = np.ones((n_cam, n_nodes), dtype=bool)
    pans = np.empty((n_cam, n_nodes))
    tilts = np.empty((n_cam, n_nodes))
    for i, cam in enumerate(cameras):
        pans[i], tilts[i] = project_pan_tilt(cam.rotation, cam.position, nodes)
    observations: list[Observation] = []
    for _ in range(repeats):
        noise = rng.normal(0.0, sigma, size=(2, n_cam, n_nodes))
        pan_meas = wrap_angle(pans + noise[0])
        # Tilt noise can push a reading past the pole; keep it physical.
        tilt_meas = np.clip(tilts + noise[1], -np.pi / 2, np.pi / 2)
        for j in range(n_nodes):
            for i in range(n_cam):
                if visible[i, j]:
                    observations.append(
                        Observation(camera_ids[i], node_ids[j], float(pan_meas[i, j]), float(tilt_meas[i, j]))
                    )
    return observations


def paper_scenario(config: PaperScenario = PaperScenario()) -> Survey:
    """The paper's simulated survey (planar, two cameras), truth in the gauge frame."""
    if config.n_nodes < 1:
        raise ValueError(f"n_nodes must be >= 1, got {config.n_nodes}")
    if min(config.heights) <= 0:
        raise ValueError(f"camera heights must be > 0, got {config.heights}")
    if config.sigma <= 0:
        raise ValueError(f"sigma must be > 0, got {config.sigma}")
    if config.repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {config.repeats}")
    rng = np.random.default_rng(config.seed)
    camera_ids = ["cam0", "cam1"]
    cameras = [
        CameraPose(np.array([0.0, 0.0, config.heights[0]]), random_base_rotation(rng, config.max_roll_pitch_deg)),
        CameraPose(np.array([1.0, 0.0, config.heights[1]]), random_base_rotation(rng, config.max_roll_pitch_deg)),
    ]
    width = max(3, len(str(config.n_nodes - 1)))
    node_ids = [f"n{j:0{width}d}" for j in range(config.n_nodes)]
    nodes = np.column_stack([rng.uniform(0.0, 1.0, size=(config.n_nodes, 2)), np.zeros(config.n_nodes)])
    if config.subset_schedule is None:
        observations = observe(camera_ids, cameras, node_ids, nodes, config.sigma, rng, repeats=config.repeats)
    else:
        k, n_subsets = config.subset_schedule
        if not 1 <= k <= config.n_nodes or n_subsets < 1:
            raise ValueError(f"subset schedule needs 1 <= k <= {config.n_nodes} and T >= 1, got k={k}, T={n_subsets}")
        schedule = draw_subsets(config.n_nodes, k, n_subsets, rng)
        observations = []
        for s, subset in enumerate(schedule):
            readings = observe(
                camera_ids, cameras, [node_ids[j] for j in subset], nodes[subset], config.sigma, rng, config.repeats
            )
            observations += [replace(o, subset=s) for o in readings]
    return simulated_survey(NodeMode.PLANAR, config.sigma, camera_ids, cameras, node_ids, nodes, observations)


@dataclass(frozen=True)
class RandomScene:
    """A random deployment for stress tests: N cameras around a field, occlusions, any mount.

    Lengths are in field units before the gauge normalization (the field is the
    unit square; nodes of 3d scenes get heights up to ``max_node_height``).
    Each camera sees each node with probability ``visibility``; a share
    ``ceiling_share`` of cameras hang upside down (base roll pi plus a tilt).
    """

    n_cameras: int = 4
    n_nodes: int = 100
    mode: NodeMode = NodeMode.PLANAR
    sigma: float = PAPER_SIGMA
    height_range: tuple[float, float] = (0.05, 1.0)
    visibility: float = 0.8
    ceiling_share: float = 0.25
    max_node_height: float = 0.3
    repeats: int = 1
    seed: int = 0


def _to_gauge(
    cameras: list[CameraPose], nodes: FloatArray, mode: NodeMode
) -> tuple[list[CameraPose], FloatArray]:
    """Similarity taking a scene into the spec's gauge for cameras 0 (origin) and 1 (baseline)."""
    if mode is NodeMode.PLANAR:
        g0, g1 = cameras[0].position[:2], cameras[1].position[:2]
        d = g1 - g0
        scale, ang = float(np.linalg.norm(d)), float(np.arctan2(d[1], d[0]))
        c, s = np.cos(-ang), np.sin(-ang)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        shift = np.array([g0[0], g0[1], 0.0])
    else:
        rot = cameras[0].rotation.T
        shift = cameras[0].position
        scale = float(np.linalg.norm(cameras[1].position - cameras[0].position))

    def move(p: FloatArray) -> FloatArray:
        return (np.asarray(p) - shift) @ rot.T / scale

    moved = [CameraPose(move(cam.position), rot @ cam.rotation) for cam in cameras]
    return moved, move(nodes)


def random_scene(config: RandomScene = RandomScene()) -> Survey:
    """A random multi-camera survey with truth in the gauge frame (cameras 'cam0', 'cam1' hold it)."""
    if config.n_cameras < 2:
        raise ValueError(f"n_cameras must be >= 2, got {config.n_cameras}")
    rng = np.random.default_rng(config.seed)
    planar = config.mode is NodeMode.PLANAR
    nodes = rng.uniform(0.0, 1.0, size=(config.n_nodes, 3))
    nodes[:, 2] = 0.0 if planar else nodes[:, 2] * config.max_node_height
    cameras: list[CameraPose] = []
    for i in range(config.n_cameras):
        while True:
            xy = rng.uniform(-0.3, 1.3, size=2)
            if i != 1 or np.linalg.norm(xy - cameras[0].position[:2]) > 0.2:
                break
        h = rng.uniform(*config.height_range)
        rotation = random_base_rotation(rng, 15.0)
        if rng.uniform() < config.ceiling_share:
            rotation = rotation @ base_rotation(0.0, 0.0, np.pi)
        cameras.append(CameraPose(np.array([xy[0], xy[1], h + (config.max_node_height if not planar else 0.0)]), rotation))
    visible = rng.uniform(size=(config.n_cameras, config.n_nodes)) < config.visibility
    cameras, nodes = _to_gauge(cameras, nodes, config.mode)
    camera_ids = [f"cam{i}" for i in range(config.n_cameras)]
    node_ids = [f"n{j:04d}" for j in range(config.n_nodes)]
    observations = observe(camera_ids, cameras, node_ids, nodes, config.sigma, rng, config.repeats, visible)
    return simulated_survey(config.mode, config.sigma, camera_ids, cameras, node_ids, nodes, observations)
