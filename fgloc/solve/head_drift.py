"""Calibration-only mode: re-survey known motes to update a camera's head calibration and flag drift.

After a survey (and its self-calibration) the motes' positions, the camera's
base pose and its head calibration are known. Re-reading a few motes with that
camera tests whether the head has moved since: each reading's residual
``r = (wrap(pan - pan_pred), tilt - tilt_pred)`` (radians) under the old
calibration is modelled as ``r = delta + noise`` with ``delta = (pan offset,
tilt index change)``: a pan offset is a base-yaw change (a slipped mount or a
lost pan index), a tilt offset a change of the tilt index error. The noise
covariance is ``sigma^2 I`` plus the mote's position covariance pushed through
the head model; the calibration's own uncertainty is common to all readings and
enters the test once, as the mean of its projection over the readings. The
camera pose is taken as exact (after a survey its angular uncertainty is far
below sigma; see docs/head-calibration.md).

:class:`DriftMonitor` accumulates readings one mote at a time; after each it
gives the generalized-least-squares estimate of ``delta``, its covariance, the
chi-square statistic (2 dof) and whether it exceeds the threshold (``alpha``
per look, 1e-3 by default), plus the updated calibration and yaw correction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fgloc.core.geometry import FloatArray, pan_tilt_residual, rot_z
from fgloc.core.head_model import HEAD_DIM, HeadCalibration, head_pan_tilt
from fgloc.core.model import CameraPose


@dataclass(frozen=True)
class DriftCheck:
    """The drift test after ``n_readings`` readings of ``n_motes`` motes.

    ``offset`` (2,) is the estimated (pan offset, tilt index change) in radians,
    ``covariance`` its 2x2 covariance, ``chi2`` the test statistic against zero
    drift, ``drifted`` whether it exceeds ``threshold``.
    """

    n_motes: int
    n_readings: int
    offset: FloatArray
    covariance: FloatArray
    chi2: float
    threshold: float
    drifted: bool


@dataclass
class DriftMonitor:
    """Sequential drift test of one camera against its last calibration (see module docstring).

    ``camera`` is the base pose, ``calibration`` the head calibration (its
    ``covariance`` optional, 7x7), ``sigma`` the reading noise in radians.
    """

    camera: CameraPose
    calibration: HeadCalibration
    sigma: float
    alpha: float = 1e-3
    _info: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    _vec: FloatArray = field(default_factory=lambda: np.zeros(2))
    _cal_cov_sum: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    _motes: set[str] = field(default_factory=set)
    _n: int = 0

    @property
    def threshold(self) -> float:
        """Chi-square (2 dof) quantile at 1 - alpha: exactly ``-2 ln(alpha)``."""
        return -2.0 * math.log(self.alpha)

    def add(self, mote: str, position: FloatArray, pan: float, tilt: float,
            position_covariance: FloatArray | None = None) -> DriftCheck:
        """Add one reading of a known mote (world position (3,), covariance 2x2 planar or 3x3) and test."""
        R, c = self.camera.rotation, self.camera.position
        q = R.T @ (np.asarray(position, dtype=float) - c)
        pred_pan, pred_tilt, d_q, d_p = head_pan_tilt(q, self.calibration.values)
        assert d_q is not None and d_p is not None
        r = pan_tilt_residual(pan, tilt, pred_pan, pred_tilt)
        C = self.sigma**2 * np.eye(2)
        if position_covariance is not None:
            P = np.zeros((3, 3))
            k = np.asarray(position_covariance).shape[0]
            P[:k, :k] = position_covariance
            D = d_q @ R.T
            C = C + D @ P @ D.T
        if self.calibration.covariance is not None:
            self._cal_cov_sum += d_p @ self.calibration.covariance @ d_p.T
        Ci = np.linalg.inv(C)
        self._info += Ci
        self._vec += Ci @ r
        self._n += 1
        self._motes.add(mote)
        return self.check()

    def check(self) -> DriftCheck:
        """The test on the readings so far."""
        cov: FloatArray = np.asarray(np.linalg.inv(self._info) if self._n else np.full((2, 2), np.inf), dtype=float)
        offset: FloatArray = cov @ self._vec if self._n else np.zeros(2)
        total = cov + (self._cal_cov_sum / self._n if self._n else 0.0)
        chi2 = float(offset @ np.linalg.solve(total, offset)) if self._n else 0.0
        return DriftCheck(len(self._motes), self._n, offset, cov, chi2, self.threshold, chi2 > self.threshold)

    def updated(self) -> tuple[CameraPose, HeadCalibration]:
        """Camera and calibration corrected by the estimated offsets (pan offset as a base-yaw turn)."""
        check = self.check()
        values = np.array(self.calibration.values, dtype=float).copy()
        values[0] += check.offset[1]
        cov = None
        if self.calibration.covariance is not None:
            cov = np.array(self.calibration.covariance, dtype=float).copy()
            cov[0, 0] = check.covariance[1, 1]
            cov[0, 1:] = cov[1:, 0] = 0.0
        # A pan reading larger by d means the base turned by -d about its z axis.
        rotation = self.camera.rotation @ rot_z(-float(check.offset[0]) / (1.0 + values[3]))
        assert values.shape == (HEAD_DIM,)
        return CameraPose(self.camera.position, rotation), HeadCalibration(values, cov)
