"""Benchmark scenes: planar surveys with N cameras around a field, with occlusions.

Deterministic by seed. Positions are in the planar gauge frame: the field is
the unit square [0, 1]^2 on z = 0, camera 0 stands above (0, 0) and camera 1
above (1, 0) (the gauge pair, as in the paper); further cameras stand on a
ring around the field (radius 0.75-0.95 from its centre). Heights are uniform
in [0.05, 1.0] baseline units, bases get a random yaw and a few degrees of
roll and pitch.

Occlusion model: a camera sees a node with probability ``p_visible``
(default: 0.85 with 2 cameras, 5 / n_cameras with more, i.e. ~5 views per
node), never within ``blind_radius`` of its own foot point (a pan-tilt head
looking straight down has an undefined pan; see measured-pitfalls), and every
node is seen by at least two cameras.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.model import CameraPose, NodeMode, Survey
from fgloc.sim.scenes import PAPER_SIGMA, observe, random_base_rotation, simulated_survey


@dataclass(frozen=True)
class BenchScene:
    """Parameters of one benchmark scene."""

    n_nodes: int
    n_cameras: int
    seed: int = 0
    sigma: float = PAPER_SIGMA
    p_visible: float | None = None
    blind_radius: float = 0.15
    min_height: float = 0.05
    max_height: float = 1.0

    @property
    def label(self) -> str:
        return f"{self.n_nodes} x {self.n_cameras}"


def scene_survey(scene: BenchScene) -> Survey:
    """The simulated survey of ``scene`` (planar, truth attached)."""
    if scene.n_cameras < 2 or scene.n_nodes < 4:
        raise ValueError("a scene needs >= 2 cameras and >= 4 nodes")
    rng = np.random.default_rng(scene.seed)
    n_cam, n = scene.n_cameras, scene.n_nodes
    ground = [np.array([0.0, 0.0]), np.array([1.0, 0.0])]
    for _ in range(n_cam - 2):
        ang = rng.uniform(-np.pi, np.pi)
        radius = rng.uniform(0.75, 0.95)
        ground.append(np.array([0.5, 0.5]) + radius * np.array([np.cos(ang), np.sin(ang)]))
    heights = rng.uniform(scene.min_height, scene.max_height, size=n_cam)
    cameras = [CameraPose(np.array([g[0], g[1], h]), random_base_rotation(rng, 3.0)) for g, h in zip(ground, heights)]
    camera_ids = [f"cam{i}" for i in range(n_cam)]
    nodes = np.column_stack([rng.uniform(0.0, 1.0, size=(n, 2)), np.zeros(n)])
    p = scene.p_visible if scene.p_visible is not None else (0.85 if n_cam == 2 else min(1.0, 5.0 / n_cam))
    foot = np.array([c.position[:2] for c in cameras])
    dist = np.linalg.norm(nodes[None, :, :2] - foot[:, None, :], axis=2)
    allowed = dist > scene.blind_radius
    visible = allowed & (rng.uniform(size=(n_cam, n)) < p)
    for j in np.flatnonzero(visible.sum(axis=0) < 2):
        choices = np.flatnonzero(allowed[:, j])
        pick = rng.choice(choices, size=min(2, len(choices)), replace=False)
        visible[pick, j] = True
    width = max(3, len(str(n - 1)))
    node_ids = [f"n{j:0{width}d}" for j in range(n)]
    observations = observe(camera_ids, cameras, node_ids, nodes, scene.sigma, rng, visible=visible)
    return simulated_survey(NodeMode.PLANAR, scene.sigma, camera_ids, cameras, node_ids, nodes, observations)
