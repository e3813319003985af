"""The pan-tilt bearing factor: one (pan, tilt) reading linking a camera base to a node.

Variables:

* camera base ``gtsam.Pose3`` ``T = (R, c)``: R maps base-frame vectors to world;
* node ``gtsam.Point3`` (3d surveys) or ``gtsam.Point2`` (planar surveys: the node
  is ``(x, y, 0)``).

Error (2-vector, radians, unwhitened; the noise model divides by sigma)::

    q = R^T (x - c)                         node in the base frame
    e = [wrap(pan_meas - atan2(q_y, q_x)),  measured minus predicted,
         tilt_meas - atan2(q_z, hypot(q_x, q_y))]   pan wrapped to (-pi, pi]

Jacobians are analytic in GTSAM's conventions: Pose3 tangent ``xi = [omega, v]``
(rotation first) with right perturbation ``T * Exp(xi)``, so
``dq/dxi = [skew(q) | -I]`` and ``dq/dx = R^T``; then ``de/dq = -D`` with D
from :func:`fgloc.core.geometry.pan_tilt_jacobian`.

Near the pole. As the node approaches the vertical through the camera (tilt
-> +-90 degrees, ``hypot(q_x, q_y) -> 0``) pan becomes undefined and its
derivative grows like 1 / hypot(q_x, q_y). The error stays bounded (pan is
wrapped, tilt is finite) and the Jacobian is clamped to stay finite, but such
a reading carries almost no pan information: avoid observing at the pole.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_jacobian, pan_tilt_residual, skew


def pan_tilt_error(
    rotation: FloatArray, position: FloatArray, point: FloatArray, pan: float, tilt: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Error and analytic Jacobians of one reading (the readable reference).

    Returns ``(e (2,), H_pose (2, 6), H_point (2, 3))`` for the camera base
    (rotation, position) and the world point.
    """
    q = rotation.T @ (point - position)
    pred_pan, pred_tilt = bearing_pan_tilt(q)
    e = pan_tilt_residual(pan, tilt, pred_pan, pred_tilt)
    d = -pan_tilt_jacobian(q)  # de/dq
    h_pose = np.hstack([d @ skew(q), -d])
    h_point = d @ rotation.T
    return e, h_pose, h_point


def _noise(sigma: float | gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    if isinstance(sigma, gtsam.noiseModel.Base):
        return sigma
    return gtsam.noiseModel.Isotropic.Sigma(2, float(sigma))


def pan_tilt_factor(
    camera_key: int, node_key: int, pan: float, tilt: float, noise: float | gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """A (pan, tilt) reading in radians linking a ``Pose3`` camera base and a ``Point3`` node.

    ``noise`` is sigma in radians (isotropic over pan and tilt) or any 2-D GTSAM
    noise model (e.g. a robust one).
    """
    pan, tilt = float(pan), float(tilt)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        keys = this.keys()
        m = values.atPose3(keys[0]).matrix()
        e, h_pose, h_point = pan_tilt_error(m[:3, :3], m[:3, 3], values.atPoint3(keys[1]), pan, tilt)
        if H is not None:
            H[0] = h_pose
            H[1] = h_point
        return e

    return gtsam.CustomFactor(_noise(noise), [camera_key, node_key], error)


def planar_pan_tilt_factor(
    camera_key: int, node_key: int, pan: float, tilt: float, noise: float | gtsam.noiseModel.Base
) -> gtsam.CustomFactor:
    """A (pan, tilt) reading in radians linking a ``Pose3`` camera base and a ``Point2``
    node on the ground plane z = 0."""
    pan, tilt = float(pan), float(tilt)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        keys = this.keys()
        m = values.atPose3(keys[0]).matrix()
        xy = values.atPoint2(keys[1])
        e, h_pose, h_point = pan_tilt_error(m[:3, :3], m[:3, 3], np.array([xy[0], xy[1], 0.0]), pan, tilt)
        if H is not None:
            H[0] = h_pose
            H[1] = np.ascontiguousarray(h_point[:, :2])
        return e

    return gtsam.CustomFactor(_noise(noise), [camera_key, node_key], error)

