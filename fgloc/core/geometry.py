"""Pan-tilt geometry in pure numpy, vectorized over many observations.

Conventions (``docs/file-format.md``, version 1):

* World frame: right-handed, z up. Lengths are in survey units (the planar
  gauge makes the ground baseline between the two gauge cameras the unit).
* A pan-tilt camera has a *base* with position ``c`` (world) and rotation
  ``R`` (3x3, maps base-frame vectors to world vectors).
* Pan ``p`` turns about the base z axis, counter-clockwise seen from +z,
  zero along base x. Tilt ``t`` is the elevation above the base x-y plane,
  positive up. Both in radians.
* ``(p, t)`` is the unit bearing ``b = (cos t cos p, cos t sin p, sin t)`` in
  the base frame, and ``R^T (x - c) / |x - c| = b`` for the observed point x.

Every function accepts leading batch dimensions and broadcasts; nothing here
imports GTSAM, I/O or hardware code.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Below this horizontal distance (relative to the range) pan is treated as
#: undefined and its derivative is clamped to stay finite.
PAN_SINGULARITY_EPS = 1e-12


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Wrap angles (radians) into the half-open interval (-pi, pi]."""
    a = np.asarray(angle, dtype=float)
    wrapped = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # in [-pi, pi)
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def pan_tilt_bearing(pan: ArrayLike, tilt: ArrayLike) -> FloatArray:
    """Unit bearing(s) in the camera base frame for (pan, tilt) in radians.

    Returns an array of shape ``broadcast(pan, tilt).shape + (3,)``.
    """
    p = np.asarray(pan, dtype=float)
    t = np.asarray(tilt, dtype=float)
    ct = np.cos(t)
    return np.stack(np.broadcast_arrays(ct * np.cos(p), ct * np.sin(p), np.sin(t)), axis=-1)


def bearing_pan_tilt(direction: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(pan, tilt) in radians of base-frame direction vector(s) of shape (..., 3).

    The vectors need not be unit length. Pan lies in (-pi, pi]; tilt in
    [-pi/2, pi/2]. Straight up or down (zero horizontal part) gives pan = 0.
    """
    q = np.asarray(direction, dtype=float)
    x, y, z = q[..., 0], q[..., 1], q[..., 2]
    pan = wrap_angle(np.arctan2(y, x))
    tilt = np.arctan2(z, np.hypot(x, y))
    return pan, tilt


def world_to_base(rotation: ArrayLike, position: ArrayLike, points: ArrayLike) -> FloatArray:
    """Express world point(s) in a camera base frame: ``R^T (x - c)``.

    ``rotation`` (..., 3, 3), ``position`` (..., 3), ``points`` (..., 3), broadcast.
    """
    R = np.asarray(rotation, dtype=float)
    d = np.asarray(points, dtype=float) - np.asarray(position, dtype=float)
    return np.einsum("...ji,...j->...i", R, d)


def project_pan_tilt(
    rotation: ArrayLike, position: ArrayLike, points: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """(pan, tilt) in radians at which a camera base (R, c) sees world point(s)."""
    return bearing_pan_tilt(world_to_base(rotation, position, points))


def pan_tilt_jacobian(direction: ArrayLike) -> FloatArray:
    """Derivative of (pan, tilt) with respect to the base-frame vector q = (x, y, z).

    Shape ``(..., 2, 3)``::

        d pan /dq = [-y/r^2,        x/r^2,        0   ]
        d tilt/dq = [-x z/(r n^2), -y z/(r n^2),  r/n^2]

    with ``r = hypot(x, y)`` and ``n^2 = r^2 + z^2``. As tilt approaches +-90
    degrees (r -> 0) the pan row grows like 1/r: pan is undefined straight above
    or below the head. ``r`` is clamped at ``PAN_SINGULARITY_EPS * |q|`` so the
    result stays finite (very large, which down-weights nothing but keeps the
    linear algebra free of NaN); callers should avoid observing at the pole.
    """
    q = np.asarray(direction, dtype=float)
    x, y, z = q[..., 0], q[..., 1], q[..., 2]
    n2 = x * x + y * y + z * z
    # Floor 1e-100 keeps r^2 and r * n^2 representable (no 0/0) even for q = 0.
    r = np.maximum(np.hypot(x, y), np.maximum(PAN_SINGULARITY_EPS * np.sqrt(n2), 1e-100))
    r2 = r * r
    n2 = np.maximum(n2, r2)
    jac = np.zeros(q.shape[:-1] + (2, 3))
    jac[..., 0, 0] = -y / r2
    jac[..., 0, 1] = x / r2
    jac[..., 1, 0] = -x * z / (r * n2)
    jac[..., 1, 1] = -y * z / (r * n2)
    jac[..., 1, 2] = r / n2
    return jac


def pan_tilt_residual(
    measured_pan: ArrayLike,
    measured_tilt: ArrayLike,
    predicted_pan: ArrayLike,
    predicted_tilt: ArrayLike,
) -> FloatArray:
    """Measured-minus-predicted (pan, tilt), pan wrapped to (-pi, pi]. Shape (..., 2)."""
    dp = wrap_angle(np.asarray(measured_pan, dtype=float) - np.asarray(predicted_pan, dtype=float))
    dt = np.asarray(measured_tilt, dtype=float) - np.asarray(predicted_tilt, dtype=float)
    return np.stack(np.broadcast_arrays(dp, dt), axis=-1)


def angle_between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Angle in radians between corresponding vectors (..., 3) of any lengths (atan2 form, exact near 0)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i->...", a, b))


def skew(v: ArrayLike) -> FloatArray:
    """Cross-product matrix(es) ``[v]_x`` of shape (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rot_x(angle: float) -> FloatArray:
    """Rotation about x by ``angle`` radians (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> FloatArray:
    """Rotation about y by ``angle`` radians (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> FloatArray:
    """Rotation about z by ``angle`` radians (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def base_rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> FloatArray:
    """Camera base rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (base -> world), radians."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def nearest_rotation(matrix: ArrayLike) -> FloatArray:
    """The rotation matrix closest (Frobenius) to a 3x3 matrix, via SVD."""
    u, _, vt = np.linalg.svd(np.asarray(matrix, dtype=float))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def is_rotation(matrix: ArrayLike, tol: float = 1e-6) -> bool:
    """True if ``matrix`` is a proper 3x3 rotation within ``tol``."""
    m = np.asarray(matrix, dtype=float)
    return (
        m.shape == (3, 3)
        and bool(np.all(np.isfinite(m)))
        and np.allclose(m.T @ m, np.eye(3), atol=tol)
        and abs(np.linalg.det(m) - 1.0) < tol
    )
