"""The subset-Newton baseline's system of equations: unknowns of S subsets side by side,
their packed readings, and the whitened (pan, tilt) residuals with their analytic Jacobian.

Planar gauge: the origin camera stands above (0, 0), the baseline camera above (1, 0);
lengths in baselines, angles in radians. Rotations are updated by local increments
``R <- R Exp(omega)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import (
    FloatArray,
    bearing_pan_tilt,
    pan_tilt_jacobian,
    skew,
    wrap_angle,
)

N_CAMERA_PARAMS = 8  # h0, h1, omega0 (3), omega1 (3)


def so3_exp(omega: FloatArray) -> FloatArray:
    """Rodrigues: rotation matrices (..., 3, 3) for rotation vectors (..., 3), radians."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    K = skew(omega)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


@dataclass
class SubsetState:
    """Unknowns of S subsets solved side by side.

    ``R`` (S, 2, 3, 3) base rotations of the origin and baseline camera,
    ``h`` (S, 2) their heights, ``xy`` (S, k, 2) node positions.
    """

    R: FloatArray
    h: FloatArray
    xy: FloatArray

    def copy(self) -> SubsetState:
        return SubsetState(self.R.copy(), self.h.copy(), self.xy.copy())

    @property
    def n_params(self) -> int:
        return N_CAMERA_PARAMS + 2 * self.xy.shape[1]

    def retract(self, delta: FloatArray) -> SubsetState:
        """Apply a step (S, 8 + 2k) in the layout [h0, h1, w0, w1, x0, y0, x1, ...]."""
        S = delta.shape[0]
        omega = delta[:, 2:8].reshape(S, 2, 3)
        return SubsetState(self.R @ so3_exp(omega), self.h + delta[:, :2], self.xy + delta[:, 8:].reshape(self.xy.shape))

    def scale(self) -> FloatArray:
        """|x_i| per parameter for NR's scaled tests (rotation increments scale as 1)."""
        S = self.h.shape[0]
        return np.concatenate([np.abs(self.h), np.zeros((S, 6)), np.abs(self.xy.reshape(S, -1))], axis=1)

    def camera_positions(self) -> FloatArray:
        S = self.h.shape[0]
        c = np.zeros((S, 2, 3))
        c[:, 1, 0] = 1.0
        c[:, :, 2] = self.h
        return c


@dataclass(frozen=True)
class SubsetReadings:
    """Readings of S subsets of k nodes, padded to M per subset.

    ``camera`` (S, M) 0 = origin, 1 = baseline; ``slot`` (S, M) node slot in
    0..k-1; ``pan``/``tilt``/``sigma`` (S, M) radians; ``mask`` (S, M) bool
    (False marks padding).
    """

    camera: np.ndarray
    slot: np.ndarray
    pan: FloatArray
    tilt: FloatArray
    sigma: FloatArray
    mask: np.ndarray
    k: int

    def take(self, rows: np.ndarray) -> SubsetReadings:
        return SubsetReadings(
            self.camera[rows], self.slot[rows], self.pan[rows], self.tilt[rows], self.sigma[rows], self.mask[rows], self.k
        )


def _gather(state: SubsetState, obs: SubsetReadings) -> tuple[FloatArray, FloatArray]:
    """Per reading: camera rotation (S, M, 3, 3) and base-frame vector q (S, M, 3)."""
    S = state.h.shape[0]
    s_idx = np.arange(S)[:, None]
    X = np.concatenate([state.xy, np.zeros(state.xy.shape[:2] + (1,))], axis=2)
    Xo = X[s_idx, obs.slot]
    Ro = state.R[s_idx, obs.camera]
    co = state.camera_positions()[s_idx, obs.camera]
    q = np.einsum("smji,smj->smi", Ro, Xo - co)
    return Ro, q


def residuals(state: SubsetState, obs: SubsetReadings) -> FloatArray:
    """Whitened residuals F (S, 2M): (measured - predicted) / sigma, pan wrapped, padding zero."""
    _, q = _gather(state, obs)
    pan, tilt = bearing_pan_tilt(q)
    F = np.stack([wrap_angle(obs.pan - pan), obs.tilt - tilt], axis=-1) / obs.sigma[..., None]
    F = np.where(obs.mask[..., None], F, 0.0)
    return F.reshape(F.shape[0], -1)


def residuals_and_jacobian(state: SubsetState, obs: SubsetReadings) -> tuple[FloatArray, FloatArray]:
    """F (S, 2M) and its analytic Jacobian (S, 2M, 8 + 2k) w.r.t. the retraction step."""
    Ro, q = _gather(state, obs)
    S, M = obs.pan.shape
    pan, tilt = bearing_pan_tilt(q)
    w = np.where(obs.mask, 1.0 / obs.sigma, 0.0)[..., None]
    F = np.stack([wrap_angle(obs.pan - pan), obs.tilt - tilt], axis=-1) * w
    A = -pan_tilt_jacobian(q) * w[..., None]  # dF/dq, (S, M, 2, 3)
    n = state.n_params
    J = np.zeros((S, M, n, 2))  # parameter axis before the residual pair for scatter
    is0 = (obs.camera == 0)[..., None]
    # heights: dq/dh = -R^T e3 = -(row 2 of R)
    dh = np.einsum("smij,smj->smi", A, -Ro[..., 2, :])
    J[:, :, 0, :] = np.where(is0, dh, 0.0)
    J[:, :, 1, :] = np.where(is0, 0.0, dh)
    # rotation increments: q(w) = Exp(-w) q  =>  dq/dw = [q]_x
    dw = (A @ skew(q)).swapaxes(-1, -2)  # (S, M, 3, 2)
    J[:, :, 2:5, :] = np.where(is0[..., None], dw, 0.0)
    J[:, :, 5:8, :] = np.where(is0[..., None], 0.0, dw)
    # node (x, y): dq/dx_a = R^T e_a = row a of R
    dxy = A @ Ro[..., :2, :].swapaxes(-1, -2)  # (S, M, 2, 2): [residual, a]
    s_idx = np.arange(S)[:, None]
    m_idx = np.arange(M)[None, :]
    for a in range(2):
        J[s_idx, m_idx, N_CAMERA_PARAMS + 2 * obs.slot + a, :] = dxy[..., :, a]
    return F.reshape(S, -1), J.swapaxes(-1, -2).reshape(S, 2 * M, n)
