"""Nodes marginalized out of an incremental solver, kept as linear conditionals on the cameras.

When a planar node ``j`` is eliminated from the linearized survey graph, what
remains of it is a Gaussian conditional on the cameras it was seen by,

    R_j dn_j + S_j dc = d_j,

with ``dn_j`` the node's step from its linearization point ``theta_j`` (2-vector,
baseline units) and ``dc`` the stacked tangent steps (GTSAM ``localCoordinates``,
rotation first, then translation: 6 per camera) of *all* cameras from the
camera linearization point of the batch the node was eliminated in. ``R_j`` is
2 x 2 upper triangular and whitened (unit noise), ``S_j`` is 2 x 6C with zero
columns for cameras the node was not seen by.

Given the current camera steps and the cameras' joint marginal covariance
``Sigma_c`` (same stacking), every stored node's estimate and marginal
covariance follow in a few batched numpy operations:

    n_j      = theta_j + R_j^-1 (d_j - S_j dc)
    Sigma_j  = R_j^-1 R_j^-T + (R_j^-1 S_j) Sigma_c (R_j^-1 S_j)^T

which is the same back-substitution a Bayes tree does for a child clique of the
camera clique, without that clique having to be re-eliminated with every node.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ConditionalBatch:
    """What the conditionals of nodes eliminated together share: the camera linearization point.

    ``camera_points`` maps camera slot (index into the stacking) to whatever the
    caller uses as that camera's linearization point (a ``gtsam.Pose3``); it is
    only handed back by :meth:`MarginalizedNodes.batches`.
    """

    camera_points: dict[int, Any]


class MarginalizedNodes:
    """Store of eliminated planar nodes (see module docstring), growing one batch at a time."""

    def __init__(self, n_cameras: int) -> None:
        self.n_cameras = n_cameras
        self._batches: list[ConditionalBatch] = []
        self._row: dict[str, int] = {}
        self._ids: list[str] = []
        self._batch_of: list[int] = []
        self._theta: list[np.ndarray] = []
        self._r_inv: list[np.ndarray] = []
        self._s: list[np.ndarray] = []
        self._d: list[np.ndarray] = []
        self._alive: list[bool] = []
        self._arrays: tuple[np.ndarray, ...] | None = None

    def __contains__(self, node_id: object) -> bool:
        return node_id in self._row

    def __len__(self) -> int:
        return len(self._row)

    @property
    def batches(self) -> list[ConditionalBatch]:
        return self._batches

    def new_batch(self, camera_points: dict[int, Any]) -> int:
        """Open a batch whose conditionals refer to ``camera_points``; returns its index."""
        self._batches.append(ConditionalBatch(dict(camera_points)))
        return len(self._batches) - 1

    def add(self, batch: int, node_id: str, theta: np.ndarray, r: np.ndarray, s: np.ndarray, d: np.ndarray) -> None:
        """Store node ``node_id``'s conditional ``r dn + s dc = d`` about ``theta`` (shapes 2, 2x2, 2x6C, 2)."""
        if node_id in self._row:
            raise ValueError(f"node {node_id!r} is already marginalized")
        if s.shape != (2, 6 * self.n_cameras):
            raise ValueError(f"S of node {node_id!r} has shape {s.shape}, expected (2, {6 * self.n_cameras})")
        self._row[node_id] = len(self._ids)
        self._ids.append(node_id)
        self._batch_of.append(batch)
        self._theta.append(np.asarray(theta, float))
        self._r_inv.append(np.linalg.inv(np.asarray(r, float)))
        self._s.append(np.asarray(s, float))
        self._d.append(np.asarray(d, float))
        self._alive.append(True)
        self._arrays = None

    def pop(self, node_id: str) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Remove a node (it becomes a variable again): (batch, theta, R, S, d)."""
        row = self._row.pop(node_id)
        self._alive[row] = False
        self._arrays = None
        r = np.linalg.inv(self._r_inv[row])
        return self._batch_of[row], self._theta[row], r, self._s[row], self._d[row]

    def _stacked(self) -> tuple[np.ndarray, ...]:
        if self._arrays is None:
            rows = np.flatnonzero(np.array(self._alive, bool)) if self._alive else np.zeros(0, int)
            c6 = 6 * self.n_cameras
            self._arrays = (
                rows,
                np.array(self._batch_of, int)[rows] if rows.size else np.zeros(0, int),
                np.array(self._theta).reshape(-1, 2)[rows],
                np.array(self._r_inv).reshape(-1, 2, 2)[rows],
                np.array(self._s).reshape(-1, 2, c6)[rows],
                np.array(self._d).reshape(-1, 2)[rows],
            )
        return self._arrays

    def node_ids(self) -> list[str]:
        """Stored node ids, in the row order of :meth:`positions` and :meth:`covariances`."""
        rows = self._stacked()[0]
        return [self._ids[r] for r in rows]

    def positions(self, camera_steps: np.ndarray) -> np.ndarray:
        """(n, 2) node positions given ``camera_steps`` (batches x 6C): each batch's
        camera step from its own linearization point to the current cameras."""
        _, batch, theta, r_inv, s, d = self._stacked()
        steps = np.asarray(camera_steps, float)[batch]
        return theta + np.einsum("nij,nj->ni", r_inv, d - np.einsum("nij,nj->ni", s, steps))

    def covariances(self, camera_covariance: np.ndarray) -> np.ndarray:
        """(n, 2, 2) marginal covariances given the cameras' joint covariance (6C x 6C)."""
        _, _, _, r_inv, s, _ = self._stacked()
        gain = np.einsum("nij,njk->nik", r_inv, s)
        own = np.einsum("nij,nkj->nik", r_inv, r_inv)
        spread = gain @ np.asarray(camera_covariance, float)  # (n, 2, 6C), no (n, 6C, 6C) temporary
        return own + np.einsum("nik,nlk->nil", spread, gain)
