"""Camera-side variables beyond the poses, for the node-eliminated readings factor.

The node-eliminated factor (:mod:`fgloc.factors.eliminated_readings`) leaves a reduced
system over everything that is not a node. Besides the camera poses that can be

* one **head calibration vector per camera** (:mod:`fgloc.core.head_model`; the
  camera's *active* entries of its extended vector, the rest held at fixed values; with
  several zooms a reading sees the shared five and its zoom group's lever arm), or
* one **(pan, tilt) head error per view** (:mod:`fgloc.factors.view_offset`), shared
  by the readings of that view.

A reading then depends on its camera's pose, its node and these few extra numbers,
so nodes are still eliminated one by one: the reduced system just gains columns.
:class:`CameraSide` holds their layout (which columns of the reduced system a
reading touches) and evaluates a reading's prediction and its derivatives with
respect to ``q`` (the node in the camera base frame) and the extra variables.
Heads and views are exclusive (the reference graph has no factor with both).

Units: angles radians, head vector as in :mod:`fgloc.core.head_model`.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_jacobian
from fgloc.core.head_model import HEAD_DIM, head_pan_tilt, local_index, reading_params
from fgloc.factors.view_offset import rotate_by_view


@dataclass(frozen=True)
class SideState:
    """The extra variables' values at one linearization point."""

    params: FloatArray  # (k, D) full (extended) head vectors per camera slot (fixed values where not active)
    offsets: FloatArray  # (V, 2) view offsets
    vector: FloatArray  # (size,) the active entries, in column order


class CameraSide:
    """Layout and evaluation of head vectors or view offsets (see module docstring).

    Args:
        n_cameras: k, the camera slots of the reduced system (columns 0..6k-1 are poses).
        camera: (m,) each reading's camera slot.
        head_keys, head_active: per camera slot, the key of its head Vector (-1: none)
            and the indices (into its extended vector) it holds.
        head_fixed: (k, D) extended parameter values where not active (D = 7 for one zoom).
        head_group: (m,) each reading's zoom group (None: all 0).
        view_keys: GTSAM keys of the views (``Vector2``); view: (m,) each reading's view
            slot (-1: none); view_pan: (m,) head pan of the reading's view, radians.
    """

    def __init__(
        self,
        n_cameras: int,
        camera: np.ndarray,
        head_keys: list[int] | None = None,
        head_active: list[tuple[int, ...]] | None = None,
        head_fixed: FloatArray | None = None,
        view_keys: list[int] | None = None,
        view: np.ndarray | None = None,
        view_pan: FloatArray | None = None,
        head_group: np.ndarray | None = None,
    ) -> None:
        self.k = n_cameras
        self.camera = np.asarray(camera, dtype=np.int64)
        hk = [-1] * n_cameras if head_keys is None else [int(x) for x in head_keys]
        self.head_active = [tuple(a) if hk[i] >= 0 else () for i, a in
                            enumerate(head_active if head_active is not None else [()] * n_cameras)]
        self.head_keys = hk
        self.head_fixed = np.zeros((n_cameras, HEAD_DIM)) if head_fixed is None else np.array(head_fixed, dtype=float)
        self.view_keys = [] if view_keys is None else [int(x) for x in view_keys]
        self.view = np.full(len(self.camera), -1, dtype=np.int64) if view is None else np.asarray(view, np.int64)
        self.view_pan = np.zeros(len(self.camera)) if view_pan is None else np.asarray(view_pan, dtype=float)
        self.group = (np.zeros(len(self.camera), dtype=np.int64) if head_group is None
                      else np.asarray(head_group, dtype=np.int64))
        # Per camera slot and zoom group: (positions in the active vector, places in the 7-vector).
        self._seen: dict[tuple[int, int], tuple[list[int], list[int]]] = {}
        for i, idx in enumerate(self.head_active):
            for g in np.unique(self.group[self.camera == i]) if idx else ():
                pairs = [(j, local_index(e, int(g))) for j, e in enumerate(idx)]
                self._seen[(i, int(g))] = ([j for j, k in pairs if k is not None],
                                           [k for _, k in pairs if k is not None])
        self.has_heads = any(self.head_active)
        self.has_views = bool(self.view_keys)
        if self.has_heads and self.has_views:
            raise ValueError("head vectors and view offsets together are not supported")
        # Column offsets (relative to 6k) of each camera's head block, then the views.
        sizes = [len(a) for a in self.head_active]
        self.head_offset = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self.view_offset = int(self.head_offset[-1])
        self.size = self.view_offset + 2 * len(self.view_keys)
        self.width = max(sizes) if self.has_heads else (2 if self.has_views else 0)

    @property
    def keys(self) -> list[int]:
        """GTSAM keys of the extra variables, in column order."""
        return [k for k, a in zip(self.head_keys, self.head_active) if a] + self.view_keys

    @property
    def dims(self) -> list[int]:
        return [len(a) for a in self.head_active if a] + [2] * len(self.view_keys)

    def reorder(self, order: np.ndarray) -> None:
        """Permute the per-reading arrays (the factor sorts readings by camera)."""
        self.camera, self.view, self.view_pan = self.camera[order], self.view[order], self.view_pan[order]
        self.group = self.group[order]

    def state(self, values: gtsam.Values) -> SideState:
        params = self.head_fixed.copy()
        parts: list[FloatArray] = []
        for i, (key, idx) in enumerate(zip(self.head_keys, self.head_active)):
            if idx:
                vec = np.asarray(values.atVector(key), dtype=float)
                params[i, list(idx)] = vec
                parts.append(vec)
        offsets = np.array([np.asarray(values.atVector(k), dtype=float) for k in self.view_keys]).reshape(-1, 2)
        parts.append(offsets.ravel())
        return SideState(params, offsets, np.concatenate(parts) if parts else np.zeros(0))

    def predict(self, q: FloatArray, rows: np.ndarray | None, state: SideState, jacobians: bool = True) -> tuple[
            FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
        """Predicted (pan, tilt) of readings ``rows`` (None: all) at base-frame points ``q`` (m, 3),
        and (when asked) d(pan, tilt)/dq (m, 2, 3) and d(pan, tilt)/d(extra) (m, 2, width)."""
        cam = self.camera if rows is None else self.camera[rows]
        if self.has_heads:
            group = self.group if rows is None else self.group[rows]
            params = (state.params[cam] if state.params.shape[1] == HEAD_DIM
                      else reading_params(state.params[cam], group))
            pan, tilt, d_q, d_p = head_pan_tilt(q, params, jacobians)
            if not jacobians:
                return pan, tilt, None, None
            assert d_p is not None
            dx = np.zeros((len(q), 2, self.width))
            for (i, g), (cols, loc) in self._seen.items():
                sel = (cam == i) & (group == g)
                if cols and sel.any():
                    dx[np.ix_(sel, [0, 1], cols)] = d_p[np.ix_(sel, [0, 1], loc)]
            return pan, tilt, d_q, dx
        view = self.view if rows is None else self.view[rows]
        has = view >= 0
        qp = np.array(q, dtype=float)
        M = dv = None
        if has.any():
            qp[has], M, dv = rotate_by_view(q[has], state.offsets[view[has]],
                                            (self.view_pan if rows is None else self.view_pan[rows])[has])
        pan, tilt = bearing_pan_tilt(qp)
        if not jacobians:
            return pan, tilt, None, None
        D = pan_tilt_jacobian(qp)
        d_q = np.array(D)
        dx = np.zeros((len(q), 2, self.width))
        if M is not None and dv is not None:
            d_q[has] = D[has] @ M
            dx[has] = D[has] @ dv
        return pan, tilt, d_q, dx

    def columns(self) -> np.ndarray:
        """(m, width) column of each reading's extra Jacobian entries in the reduced system
        (absolute, after the 6k pose columns); padding entries point at column ``6k + size``."""
        pad = 6 * self.k + self.size
        cols = np.full((len(self.camera), self.width), pad, dtype=np.int64)
        if self.has_heads:
            for i, idx in enumerate(self.head_active):
                sel = self.camera == i
                cols[np.ix_(sel, np.arange(len(idx)))] = 6 * self.k + self.head_offset[i] + np.arange(len(idx))
        elif self.has_views:
            has = self.view >= 0
            cols[has] = 6 * self.k + self.view_offset + 2 * self.view[has, None] + np.arange(2)[None, :]
        return cols
