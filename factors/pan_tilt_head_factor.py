"""The pan-tilt factor of a non-ideal head: a reading links a camera base, a node and a head calibration.

Variables: the camera base ``Pose3`` ``T = (R, c)`` (as in
:mod:`fgloc.factors.pan_tilt_factor`), the node (``Point2`` on z = 0 or
``Point3``) and, optionally, the camera's head calibration: a ``gtsam`` Vector
holding the *active* entries of the camera's extended head vector of
:mod:`fgloc.core.head_model` (``active`` lists their indices; the rest are held at fixed
values, zero by default). With one zoom the extended vector is the 7-vector; with
several, a reading of zoom group g sees the shared five and group g's lever arm, and
its Jacobian has zero columns for the other groups' lever arms.

Error (2-vector, radians, measured minus predicted, pan wrapped)::

    q = R^T (x - c);  (pan, tilt)_pred = head_pan_tilt(q, params)

or, for an **off-centre** reading (a coded survey's, composed at its view's encoder readings
``(view_pan, view_tilt)``, ``Observation.view_angles``),
``head_view_pan_tilt(q, params, view_pan, view_tilt)``: what the ideal pixel composition
reads where the imperfect head at the view's readings shows the LED.

Jacobians are analytic: ``de/dq = -D_q`` and ``de/dparams = -D_p`` from
:func:`fgloc.core.head_model.head_pan_tilt`, chained with ``dq/dxi = [skew(q) | -I]``
(GTSAM's right perturbation, rotation first) and ``dq/dx = R^T``.

:class:`HeadFactorSet` evaluates every reading of a survey in one numpy pass per
linearization point, like :class:`fgloc.factors.pan_tilt_batch.PanTiltFactorSet`.
:func:`head_prior_factor` is the datasheet-tolerance prior on the calibration.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, pan_tilt_residual, skew
from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS, HEAD_DIM, head_pan_tilt, head_view_pan_tilt, local_index


def predicted_readings(
    q: FloatArray, params: FloatArray, view: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Head-model (pan, tilt) of base-frame points ``q`` (M, 3) with ``params`` (M, 7) and their
    Jacobians (M, 2, 3), (M, 2, 7): centred readings by :func:`head_pan_tilt`, rows whose
    ``view`` (M, 2) radians is finite off-centre at that view by :func:`head_view_pan_tilt`."""
    q = np.asarray(q, dtype=float)
    params = np.broadcast_to(np.asarray(params, dtype=float), q.shape[:-1] + (HEAD_DIM,))
    off = np.zeros(q.shape[:-1], dtype=bool) if view is None else np.isfinite(np.asarray(view)[..., 0])
    if not off.any():
        pan, tilt, d_q, d_p = head_pan_tilt(q, params)
        assert d_q is not None and d_p is not None
        return pan, tilt, d_q, d_p
    assert view is not None
    pan, tilt = np.zeros(q.shape[:-1]), np.zeros(q.shape[:-1])
    d_q, d_p = np.zeros(q.shape[:-1] + (2, 3)), np.zeros(q.shape[:-1] + (2, HEAD_DIM))
    for rows, fn in ((~off, None), (off, head_view_pan_tilt)):
        if not rows.any():
            continue
        out = head_pan_tilt(q[rows], params[rows]) if fn is None else fn(q[rows], params[rows], view[rows, 0],
                                                                         view[rows, 1])
        pan[rows], tilt[rows], d_q[rows], d_p[rows] = out
    return pan, tilt, d_q, d_p


def head_pan_tilt_error(
    rotation: FloatArray, position: FloatArray, point: FloatArray, params: FloatArray, pan: FloatArray, tilt: FloatArray,
    view: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Errors and Jacobians of readings, batched over a leading axis M (or unbatched).

    ``rotation`` (..., 3, 3), ``position`` / ``point`` (..., 3), ``params`` (..., 7);
    ``view`` (M, 2) radians, batched only: each reading's view angles, NaN for a centred
    reading (None: every reading centred). Returns ``e`` (..., 2), ``H_pose`` (..., 2, 6),
    ``H_point`` (..., 2, 3) and ``H_params`` (..., 2, 7) over the full 7-vector.
    """
    q = np.einsum("...ji,...j->...i", rotation, point - position)
    if view is None:
        pred_pan, pred_tilt, d_q, d_p = head_pan_tilt(q, params)
        assert d_q is not None and d_p is not None
    else:
        pred_pan, pred_tilt, d_q, d_p = predicted_readings(q, params, view)
    e = pan_tilt_residual(pan, tilt, pred_pan, pred_tilt)
    d = -d_q
    h_pose = np.concatenate([d @ skew(q), -d], axis=-1)
    h_point = np.einsum("...ij,...kj->...ik", d, rotation)
    return e, h_pose, h_point, -d_p


def head_prior_factor(
    key: int, active: Sequence[int], mean: FloatArray | None = None, sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS
) -> gtsam.NonlinearFactor:
    """Gaussian prior on a head-calibration Vector of the ``active`` parameters.

    ``mean`` and ``sigmas`` are full (extended) vectors (default: zero mean, datasheet tolerances;
    :func:`fgloc.core.head_model.extend_vector` repeats the lever arm's per zoom).
    """
    idx = list(active)
    mu = np.zeros(len(sigmas)) if mean is None else np.asarray(mean, dtype=float)
    return gtsam.PriorFactorVector(key, mu[idx].copy(), gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas)[idx]))


def _seen(active: tuple[int, ...], group: int) -> tuple[list[int], list[int]]:
    """Of the ``active`` extended indices, the positions a zoom-``group`` reading sees and
    their places in its 7-vector."""
    pairs = [(j, local_index(e, group)) for j, e in enumerate(active)]
    kept = [(j, k) for j, k in pairs if k is not None]
    return [j for j, _ in kept], [k for _, k in kept]


class HeadFactorSet:
    """Head-model pan-tilt factors for many readings with a shared vectorized cache.

    Args:
        camera_keys, node_keys: (M,) keys of each reading's camera ``Pose3`` and node.
        head_keys: (M,) key of the reading camera's head Vector, or -1 for a camera
            whose calibration is held fixed (then the factor has two keys).
        active: per head key, the indices (into the camera's extended vector) it holds.
        fixed: (M, 7) each reading's parameter values used where not active (e.g. zeros).
        pan, tilt: (M,) readings in radians; noise_models: (M,) 2-D noise models.
        zoom_group: (M,) each reading's zoom group (None: all 0, one zoom).
        view: (M, 2) radians, each reading's view angles (``Observation.view_angles``) for an
            off-centre reading, NaN for a centred one (None: every reading centred).
    """

    def __init__(
        self,
        camera_keys: np.ndarray,
        node_keys: np.ndarray,
        head_keys: np.ndarray,
        active: dict[int, tuple[int, ...]],
        fixed: FloatArray,
        pan: FloatArray,
        tilt: FloatArray,
        noise_models: list[gtsam.noiseModel.Base],
        planar: bool,
        zoom_group: np.ndarray | None = None,
        view: FloatArray | None = None,
    ) -> None:
        self.camera_keys = np.asarray(camera_keys, dtype=np.int64)
        self.node_keys = np.asarray(node_keys, dtype=np.int64)
        self.head_keys = np.asarray(head_keys, dtype=np.int64)
        self.active = {int(k): tuple(v) for k, v in active.items()}
        self.fixed = np.asarray(fixed, dtype=float)
        self.pan = np.asarray(pan, dtype=float)
        self.tilt = np.asarray(tilt, dtype=float)
        self.planar = planar
        self.zoom_group = (np.zeros(len(self.pan), dtype=np.int64) if zoom_group is None
                           else np.asarray(zoom_group, dtype=np.int64))
        self.view = None if view is None or not np.isfinite(view).any() else np.asarray(view, dtype=float).reshape(-1, 2)
        self.inv_sigmas = np.array([1.0 / np.asarray(nm.sigmas(), dtype=float) for nm in noise_models]).reshape(-1, 2)
        self._values: gtsam.Values | None = None
        self._errors = np.empty((0, 2))
        self._h: list[FloatArray] = []
        self.factors = [self._make_factor(i, noise_models[i]) for i in range(len(self.pan))]

    def __len__(self) -> int:
        return len(self.pan)

    def _params(self, values: gtsam.Values) -> FloatArray:
        params = self.fixed.copy()
        for key, idx in self.active.items():
            vec = np.asarray(values.atVector(key), dtype=float)
            mine = self.head_keys == key
            for g in np.unique(self.zoom_group[mine]):
                rows = mine & (self.zoom_group == g)
                j, loc = _seen(idx, int(g))
                params[np.ix_(rows, loc)] = vec[j][None, :]
        return params

    def _evaluate(self, values: gtsam.Values, rows: np.ndarray) -> tuple[FloatArray, list[FloatArray]]:
        m = np.array([values.atPose3(int(k)).matrix() for k in self.camera_keys[rows]]).reshape(-1, 4, 4)
        if self.planar:
            xy = np.array([values.atPoint2(int(k)) for k in self.node_keys[rows]]).reshape(-1, 2)
            points = np.column_stack([xy, np.zeros(len(xy))])
        else:
            points = np.array([values.atPoint3(int(k)) for k in self.node_keys[rows]]).reshape(-1, 3)
        params = self._params(values)[rows]
        e, h_pose, h_point, h_par = head_pan_tilt_error(
            m[:, :3, :3], m[:, :3, 3], points, params, self.pan[rows], self.tilt[rows],
            None if self.view is None else self.view[rows],
        )
        if self.planar:
            h_point = np.ascontiguousarray(h_point[:, :, :2])
        return e, [h_pose, h_point, h_par]

    def _make_factor(self, i: int, noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
        cache = self
        head = int(self.head_keys[i])
        idx = list(self.active.get(head, ())) if head >= 0 else []
        cols, loc = _seen(tuple(idx), int(self.zoom_group[i]))
        keys = [int(self.camera_keys[i]), int(self.node_keys[i])] + ([head] if head >= 0 else [])

        def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
            if values is cache._values:
                e, hs, row = cache._errors, cache._h, i
            else:
                e, hs = cache._evaluate(values, np.array([i]))
                row = 0
            if H is not None:
                H[0] = hs[0][row]
                H[1] = hs[1][row]
                if idx:
                    h = np.zeros((2, len(idx)))
                    h[:, cols] = hs[2][row][:, loc]
                    H[2] = h
            return e[row]

        return gtsam.CustomFactor(noise, keys, error)

    def prepare(self, values: gtsam.Values) -> None:
        """Evaluate every reading at ``values`` (do not modify ``values`` in place afterwards)."""
        if values is self._values or len(self.pan) == 0:
            return
        self._errors, self._h = self._evaluate(values, np.arange(len(self.pan)))
        self._values = values

    def errors(self, values: gtsam.Values) -> FloatArray:
        """Unwhitened errors (M, 2) at ``values``."""
        self.prepare(values)
        return self._errors

    def error(self, values: gtsam.Values) -> float:
        """Sum of the factors' errors (0.5 * squared whitened norm), Gaussian noise only."""
        if len(self.pan) == 0:
            return 0.0
        self.prepare(values)
        return float(0.5 * np.sum((self._errors * self.inv_sigmas) ** 2))
