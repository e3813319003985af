"""A result and its survey as drawable arrays (no Rerun): node positions and
covariances, measured rays, camera frusta.

All positions are in the gauge frame (baseline = 1, z up); planar nodes lie on z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray, pan_tilt_bearing
from fgloc.core.model import Result, Survey


@dataclass(frozen=True)
class NodeArrays:
    """A result's localized nodes as arrays (ids sorted like the survey when given)."""

    ids: list[str]
    positions: FloatArray  # (N, 3) gauge frame
    covariances: FloatArray  # (N, d, d)


def node_arrays(result: Result, survey: Survey | None = None) -> NodeArrays:
    """Localized nodes of ``result`` as arrays, in survey order when a survey is given."""
    order = [n for n in survey.node_ids if n in result.nodes] if survey is not None else list(result.nodes)
    d = result.mode.position_dim
    if not order:
        return NodeArrays([], np.zeros((0, 3)), np.zeros((0, d, d)))
    positions = np.array([result.nodes[n].position for n in order], dtype=float).reshape(-1, 3)
    covariances = np.array([result.nodes[n].covariance for n in order], dtype=float).reshape(-1, d, d)
    return NodeArrays(order, positions, covariances)


def frustum_strips(depth: float, half_width: float = 0.6, half_height: float = 0.4) -> list[np.ndarray]:
    """Wireframe of a frustum in the base frame looking along +x (pan = tilt = 0), z up:
    four edges from the apex plus the far rectangle at x = ``depth`` (strips (5, *, 3))."""
    w, h = half_width * depth, half_height * depth
    corners = np.array([[depth, w, h], [depth, -w, h], [depth, -w, -h], [depth, w, -h]])
    edges = [np.stack([np.zeros(3), c]) for c in corners]
    return [*edges, np.vstack([corners, corners[:1]])]


def ray_segments(survey: Survey, result: Result, overshoot: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured bearings as world segments (M, 2, 3), with each segment's observation
    index and camera index into ``survey.camera_ids``.

    A ray starts at the estimated camera centre and follows ``R b(pan, tilt)``;
    its length is the range to the estimated node times ``1 + overshoot`` (or to
    the farthest estimated node when that node was not localized).
    Observations by unlocalized cameras are skipped.
    """
    table = survey.observation_table
    cam_ok = np.array([c in result.cameras for c in survey.camera_ids], dtype=bool)
    keep = np.flatnonzero(cam_ok[table.camera_index]) if len(table) else np.zeros(0, dtype=int)
    if keep.size == 0:
        return np.zeros((0, 2, 3)), np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    centres = np.array([result.cameras[c].position if ok else np.zeros(3) for c, ok in zip(survey.camera_ids, cam_ok)])
    rotations = np.array([result.cameras[c].rotation if ok else np.eye(3) for c, ok in zip(survey.camera_ids, cam_ok)])
    node_pos = np.array([result.nodes[n].position if n in result.nodes else np.full(3, np.nan) for n in survey.node_ids])
    ci, ni = table.camera_index[keep], table.node_index[keep]
    b_world = np.einsum("mij,mj->mi", rotations[ci], pan_tilt_bearing(table.pan[keep], table.tilt[keep]))
    start = centres[ci]
    rng = np.linalg.norm(node_pos[ni] - start, axis=1)
    finite = np.isfinite(node_pos).all(axis=1)
    fallback = np.linalg.norm(node_pos[finite][None, :, :] - centres[:, None, :], axis=2).max() if finite.any() else 1.0
    rng = np.where(np.isfinite(rng), rng, fallback) * (1.0 + overshoot)
    segments = np.stack([start, start + rng[:, None] * b_world], axis=1)
    return segments, keep, ci
