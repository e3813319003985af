"""All pan-tilt readings of a survey as ``CustomFactor``s evaluated in one numpy pass.

Each reading is still its own GTSAM factor (one bearing, one camera, one node,
its own noise model, robust or not), with the error and Jacobians of
:func:`fgloc.factors.pan_tilt_factor.pan_tilt_error`. What changes is where the
arithmetic happens: :meth:`PanTiltFactorSet.prepare` computes the errors and
Jacobians of every reading for one ``gtsam.Values`` in a vectorized pass, and
each factor's callback only copies its row out. GTSAM hands the callbacks the
very ``Values`` object that was passed to ``linearize`` / ``error`` (no copy),
so the callback recognizes a prepared linearization point by identity.

A callback that sees any other ``Values`` (for example inside GTSAM's own C++
optimizer, which passes copies) falls back to the per-reading reference
computation: slower, same numbers.

View offsets (optional ``view_keys``): a reading taken in a view whose head reading
is shared by several readings gets a third key, the view's ``Vector2`` head error
``v = (pan, tilt)`` in radians, which turns the predicted bearing as the head would
(:mod:`fgloc.factors.view_offset`; at the view centre it adds ``v`` to the predicted
angles).
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_jacobian, pan_tilt_residual, skew
from fgloc.factors.pan_tilt_factor import pan_tilt_error
from fgloc.factors.view_offset import view_pan_tilt_error


def batch_pan_tilt_error(
    rotations: FloatArray, positions: FloatArray, points: FloatArray, pan: FloatArray, tilt: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Vectorized :func:`pan_tilt_error`: rotations (M,3,3), positions (M,3), points (M,3).

    Returns errors (M, 2), pose Jacobians (M, 2, 6) and point Jacobians (M, 2, 3).
    """
    q = np.einsum("mji,mj->mi", rotations, points - positions)
    pred_pan, pred_tilt = bearing_pan_tilt(q)
    e = pan_tilt_residual(pan, tilt, pred_pan, pred_tilt)
    d = -pan_tilt_jacobian(q)
    h_pose = np.concatenate([d @ skew(q), -d], axis=2)
    h_point = np.einsum("mij,mkj->mik", d, rotations)  # d @ R^T
    return e, h_pose, h_point


def _diagonal_inverse_sigmas(noise_models: list[gtsam.noiseModel.Base]) -> FloatArray | None:
    """(M, 2) 1/sigma of each model if all are plain diagonal Gaussians, else None."""
    inv = np.empty((len(noise_models), 2))
    cache: dict[int, np.ndarray] = {}
    for i, nm in enumerate(noise_models):
        key = id(nm)
        if key not in cache:
            if not isinstance(nm, gtsam.noiseModel.Diagonal) or isinstance(nm, gtsam.noiseModel.Constrained):
                return None
            cache[key] = 1.0 / np.asarray(nm.sigmas(), dtype=float)
        inv[i] = cache[key]
    return inv


class PanTiltFactorSet:
    """Pan-tilt factors for many readings, with a shared vectorized evaluation cache.

    Args:
        camera_keys, node_keys: (M,) GTSAM keys of each reading's camera base
            (``Pose3``) and node (``Point2`` on z = 0 if ``planar``, else ``Point3``).
        pan, tilt: (M,) measured angles in radians.
        noise_models: (M,) 2-D noise models (sigma in radians; may be robust).
        view_keys: (M,) key of each reading's view offset (``Vector2``), -1 for none;
            None: no reading has a view.
        view_pans: (M,) head pan (radians) of each reading's view (used where it has one).
    """

    def __init__(
        self,
        camera_keys: np.ndarray,
        node_keys: np.ndarray,
        pan: FloatArray,
        tilt: FloatArray,
        noise_models: list[gtsam.noiseModel.Base],
        planar: bool,
        view_keys: np.ndarray | None = None,
        view_pans: FloatArray | None = None,
    ) -> None:
        self.camera_keys = np.asarray(camera_keys, dtype=np.int64)
        self.view_keys = (np.full(len(self.camera_keys), -1, dtype=np.int64) if view_keys is None
                          else np.asarray(view_keys, dtype=np.int64))
        self.view_pans = np.asarray(pan if view_pans is None else view_pans, dtype=float)
        self._unique_views, self._view_index = np.unique(self.view_keys, return_inverse=True)
        self._h_view = np.empty((0, 2, 2))
        self.node_keys = np.asarray(node_keys, dtype=np.int64)
        self.pan = np.asarray(pan, dtype=float)
        self.tilt = np.asarray(tilt, dtype=float)
        self.planar = planar
        self._unique_cameras, self._cam_index = np.unique(self.camera_keys, return_inverse=True)
        self._unique_nodes, self._node_index = np.unique(self.node_keys, return_inverse=True)
        self._values: gtsam.Values | None = None
        self._errors = np.empty((0, 2))
        self._h_pose = np.empty((0, 2, 6))
        self._h_point = np.empty((0, 2, 3))
        self.factors = [self._make_factor(i, noise_models[i]) for i in range(len(self.pan))]
        self._inv_sigmas = _diagonal_inverse_sigmas(noise_models)

    def __len__(self) -> int:
        return len(self.pan)

    def _make_factor(self, i: int, noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
        cache = self
        pan, tilt, planar = float(self.pan[i]), float(self.tilt[i]), self.planar
        view = int(self.view_keys[i])
        view_pan = float(self.view_pans[i])

        def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
            if values is cache._values:
                if H is not None:
                    H[0] = cache._h_pose[i]
                    H[1] = cache._h_point[i]
                    if view >= 0:
                        H[2] = cache._h_view[i]
                return cache._errors[i]
            keys = this.keys()
            m = values.atPose3(keys[0]).matrix()
            if planar:
                xy = values.atPoint2(keys[1])
                point = np.array([xy[0], xy[1], 0.0])
            else:
                point = np.asarray(values.atPoint3(keys[1]), dtype=float)
            if view >= 0:
                ev, hp, hx, hv = view_pan_tilt_error(m[None, :3, :3], m[None, :3, 3], point[None], np.array([pan]),
                                                     np.array([tilt]), np.asarray(values.atVector(view))[None],
                                                     np.array([view_pan]))
                e, h_pose, h_point = ev[0], hp[0], hx[0]
            else:
                e, h_pose, h_point = pan_tilt_error(m[:3, :3], m[:3, 3], point, pan, tilt)
            if H is not None:
                H[0] = h_pose
                H[1] = np.ascontiguousarray(h_point[:, :2]) if planar else h_point
                if view >= 0:
                    H[2] = hv[0]
            return e

        keys = [int(self.camera_keys[i]), int(self.node_keys[i])] + ([view] if view >= 0 else [])
        return gtsam.CustomFactor(noise, keys, error)

    def error(self, values: gtsam.Values) -> float | None:
        """Sum of the factors' errors (GTSAM's 0.5 * squared whitened norm) in one pass.

        Equal to summing ``factor.error(values)`` over :attr:`factors`, without one
        Python callback per reading. None when a noise model is not plain
        Gaussian diagonal (e.g. robust): then only GTSAM knows the loss.
        """
        if self._inv_sigmas is None:
            return None
        if len(self.pan) == 0:
            return 0.0
        self.prepare(values)
        return float(0.5 * np.sum((self._errors * self._inv_sigmas) ** 2))

    def errors(self, values: gtsam.Values) -> FloatArray:
        """Unwhitened errors (M, 2) of every reading at ``values`` (measured minus predicted)."""
        self.prepare(values)
        return self._errors

    def prepare(self, values: gtsam.Values) -> None:
        """Evaluate every reading at ``values`` (do not modify ``values`` in place afterwards)."""
        if values is self._values or len(self.pan) == 0:
            return
        poses = [values.atPose3(int(k)).matrix() for k in self._unique_cameras]
        rot = np.array([m[:3, :3] for m in poses])
        pos = np.array([m[:3, 3] for m in poses])
        if self.planar:
            xy = np.array([values.atPoint2(int(k)) for k in self._unique_nodes])
            points = np.column_stack([xy, np.zeros(len(xy))])
        else:
            points = np.array([values.atPoint3(int(k)) for k in self._unique_nodes])
        e, h_pose, h_point = batch_pan_tilt_error(
            rot[self._cam_index], pos[self._cam_index], points[self._node_index], self.pan, self.tilt
        )
        if self._unique_views[-1] >= 0:
            offsets = np.array([np.zeros(2) if k < 0 else np.asarray(values.atVector(int(k)), dtype=float)
                                for k in self._unique_views])
            rows = np.flatnonzero(self.view_keys >= 0)
            ci = self._cam_index[rows]
            ev, hp, hx, hv = view_pan_tilt_error(rot[ci], pos[ci], points[self._node_index[rows]], self.pan[rows],
                                                 self.tilt[rows], offsets[self._view_index[rows]], self.view_pans[rows])
            e[rows], h_pose[rows], h_point[rows] = ev, hp, hx
            self._h_view = np.zeros((len(self.pan), 2, 2))
            self._h_view[rows] = hv
        self._errors = e
        self._h_pose = h_pose
        self._h_point = np.ascontiguousarray(h_point[:, :, :2]) if self.planar else h_point
        self._values = values
