"""Gauge-fixing priors: pin the similarity frame that bearings cannot observe.

Bearings are invariant to a similarity transform of the whole scene (7 DOF).
The spec's gauges remove exactly those degrees of freedom:

* planar: nodes are ``Point2`` on z = 0 (removes the plane's height and tilt, 3
  DOF); the origin camera's ground point is pinned to (0, 0) and the baseline
  camera's to (1, 0) (translation, yaw and scale, 4 DOF);
* 3d: the origin camera's base is the world frame (6 DOF) and the baseline
  camera is at distance 1 from it (scale, 1 DOF).

Because the bearing factors cannot resist a gauge motion, these priors are
satisfied exactly at the optimum whatever their sigma: they do not bias the
solution. Their sigma only has to be small against the node covariances so
that the gauge leaks nothing into the marginals (it adds O(sigma^2)), and not
so small that Cholesky loses precision: the solver picks 1e-3 of a typical node
standard deviation (``fgloc.solve.joint.auto_gauge_sigma``); ``GAUGE_SIGMA``
is the default for direct use of these factors.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from fgloc.core.model import NodeMode

GAUGE_SIGMA = 1e-6


def ground_point_factor(camera_key: int, ground_xy: tuple[float, float], sigma: float = GAUGE_SIGMA) -> gtsam.CustomFactor:
    """Pin the (x, y) of a ``Pose3`` camera base's position to ``ground_xy``.

    Error ``c_xy - ground_xy``; with right perturbation ``c' = c + R v`` the
    Jacobian is ``[0_{2x3} | R[:2, :]]``.
    """
    target = np.asarray(ground_xy, dtype=float)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        m = values.atPose3(this.keys()[0]).matrix()
        if H is not None:
            H[0] = np.hstack([np.zeros((2, 3)), m[:2, :3]])
        return m[:2, 3] - target

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(2, sigma), [camera_key], error)


def baseline_length_factor(origin_key: int, baseline_key: int, length: float = 1.0, sigma: float = GAUGE_SIGMA) -> gtsam.CustomFactor:
    """Pin the distance between two ``Pose3`` camera positions to ``length``."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        keys = this.keys()
        mo = values.atPose3(keys[0]).matrix()
        mb = values.atPose3(keys[1]).matrix()
        d = mb[:3, 3] - mo[:3, 3]
        dist = float(np.linalg.norm(d))
        if H is not None:
            u = d / max(dist, 1e-300)
            H[0] = np.hstack([np.zeros((1, 3)), -(u @ mo[:3, :3])[None, :]])
            H[1] = np.hstack([np.zeros((1, 3)), (u @ mb[:3, :3])[None, :]])
        return np.array([dist - length])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, sigma), [origin_key, baseline_key], error)


@dataclass(frozen=True)
class BaselinePrior:
    """The spec's gauge for a survey, as factors on the two gauge cameras' keys."""

    mode: NodeMode
    origin_key: int
    baseline_key: int
    sigma: float = GAUGE_SIGMA

    def factors(self) -> list[gtsam.NonlinearFactor]:
        """Factors that remove exactly the gauge freedom of ``mode``."""
        if self.mode is NodeMode.PLANAR:
            return [
                ground_point_factor(self.origin_key, (0.0, 0.0), self.sigma),
                ground_point_factor(self.baseline_key, (1.0, 0.0), self.sigma),
            ]
        return [
            gtsam.PriorFactorPose3(self.origin_key, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, self.sigma)),
            baseline_length_factor(self.origin_key, self.baseline_key, 1.0, self.sigma),
        ]
