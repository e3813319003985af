"""Pixel <-> (pan, tilt): exact composition of an image ray with the head's pan and tilt.

Pure numpy (no OpenCV, no I/O). Frames, all right-handed:

* **Optical frame** (OpenCV): x right in the image, y down, z forward along
  the optical axis. A pixel ``(u, v)`` undistorts to normalised ``(x, y)`` and
  the ray ``(x, y, 1)``.
* **Head frame at (pan, tilt) = (0, 0)**: identical to the camera *base* frame
  of the spec (x forward, y left, z up). There, optical z = base +x, optical
  x = base -y, optical y = base -z (``OPTICAL_TO_HEAD``).
* **Head rotation**: ``Rz(pan) @ Ry(-tilt)`` maps head-at-zero vectors to the
  base frame, so the optical axis points along ``pan_tilt_bearing(pan, tilt)``.

A ray ``r`` (optical) seen with the head read back at ``(P, T)`` has base
direction ``d = Rz(P) Ry(-T) OPTICAL_TO_HEAD r`` and the node's (pan, tilt)
is ``bearing_pan_tilt(d)``. This is *not* ``(P + atan x, T - atan y)``: at
non-zero tilt a horizontal image offset changes pan by about 1/cos(tilt) more
and both angles couple (``shared/reference/protocols.md`` section 5.4).

The model assumes the optical centre lies on the pan and tilt axes, true only
near the widest zoom (see docs/camera-model.md). Angles are radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_bearing, rot_y, rot_z

#: Columns are the optical x, y, z axes expressed in the head frame at pan = tilt = 0.
OPTICAL_TO_HEAD: FloatArray = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def head_rotation(pan: float, tilt: float) -> FloatArray:
    """Rotation (3x3) of the head at (pan, tilt) radians: head-at-zero frame -> base frame."""
    return rot_z(pan) @ rot_y(-tilt)


def optical_to_base(pan: float, tilt: float) -> FloatArray:
    """Rotation (3x3) taking optical-frame vectors to base-frame vectors for the head at (pan, tilt)."""
    return head_rotation(pan, tilt) @ OPTICAL_TO_HEAD


def distort_normalized(intr: CameraIntrinsics, xy: ArrayLike) -> FloatArray:
    """Apply OpenCV distortion to normalised coordinates (..., 2) -> distorted normalised (..., 2)."""
    p = np.asarray(xy, dtype=float)
    x, y = p[..., 0], p[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (intr.k1 + r2 * (intr.k2 + r2 * intr.k3))
    xd = x * radial + 2.0 * intr.p1 * x * y + intr.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + intr.p1 * (r2 + 2.0 * y * y) + 2.0 * intr.p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _distortion_jacobian(intr: CameraIntrinsics, x: FloatArray, y: FloatArray) -> FloatArray:
    r2 = x * x + y * y
    radial = 1.0 + r2 * (intr.k1 + r2 * (intr.k2 + r2 * intr.k3))
    dr = 2.0 * intr.k1 + r2 * (4.0 * intr.k2 + 6.0 * intr.k3 * r2)  # d radial / d(r2) * 2
    jac = np.empty(x.shape + (2, 2))
    jac[..., 0, 0] = radial + x * dr * x + 2.0 * intr.p1 * y + 6.0 * intr.p2 * x
    jac[..., 0, 1] = x * dr * y + 2.0 * intr.p1 * x + 2.0 * intr.p2 * y
    jac[..., 1, 0] = y * dr * x + 2.0 * intr.p1 * x + 2.0 * intr.p2 * y
    jac[..., 1, 1] = radial + y * dr * y + 6.0 * intr.p1 * y + 2.0 * intr.p2 * x
    return jac


def undistort_normalized(intr: CameraIntrinsics, xy_distorted: ArrayLike, iterations: int = 20) -> FloatArray:
    """Invert the distortion by Newton's method: distorted normalised (..., 2) -> undistorted (..., 2).

    Converges to ~1e-15 within the calibrated field of view (tested by round trip).
    """
    target = np.asarray(xy_distorted, dtype=float)
    p = target.copy()
    for _ in range(iterations):
        err = distort_normalized(intr, p) - target
        if np.max(np.abs(err), initial=0.0) < 1e-15:
            break
        j = _distortion_jacobian(intr, p[..., 0], p[..., 1])
        det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]  # explicit 2x2 solve
        du = (j[..., 1, 1] * err[..., 0] - j[..., 0, 1] * err[..., 1]) / det
        dv = (j[..., 0, 0] * err[..., 1] - j[..., 1, 0] * err[..., 0]) / det
        p = p - np.stack([du, dv], axis=-1)
    return p


def pixel_to_ray(intr: CameraIntrinsics, uv: ArrayLike) -> FloatArray:
    """Unit ray(s) in the optical frame for pixel(s) ``uv`` (..., 2)."""
    uv = np.asarray(uv, dtype=float)
    xd = np.stack([(uv[..., 0] - intr.cx) / intr.fx, (uv[..., 1] - intr.cy) / intr.fy], axis=-1)
    xy = undistort_normalized(intr, xd)
    ray = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
    return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


def ray_to_pixel(intr: CameraIntrinsics, ray: ArrayLike) -> tuple[FloatArray, np.ndarray]:
    """Project optical-frame ray(s) (..., 3) to pixels: ``(uv (..., 2), in_front (...))``.

    Rays with z <= 0 are behind the camera: their ``uv`` is NaN and ``in_front`` False.
    """
    r = np.asarray(ray, dtype=float)
    z = r[..., 2]
    in_front = z > 1e-12
    safe_z = np.where(in_front, z, 1.0)
    xy = np.stack([r[..., 0] / safe_z, r[..., 1] / safe_z], axis=-1)
    xd = distort_normalized(intr, xy)
    uv = np.stack([intr.fx * xd[..., 0] + intr.cx, intr.fy * xd[..., 1] + intr.cy], axis=-1)
    uv = np.where(in_front[..., None], uv, np.nan)
    return uv, in_front


def pixel_to_pan_tilt(
    intr: CameraIntrinsics, uv: ArrayLike, head_pan: float, head_tilt: float
) -> tuple[FloatArray, FloatArray]:
    """(pan, tilt) radians, spec convention, of what pixel(s) ``uv`` (..., 2) show with the
    head read back at (head_pan, head_tilt) radians."""
    d = pixel_to_ray(intr, uv) @ optical_to_base(head_pan, head_tilt).T
    return bearing_pan_tilt(d)


def pan_tilt_to_pixel(
    intr: CameraIntrinsics, pan: ArrayLike, tilt: ArrayLike, head_pan: float, head_tilt: float
) -> tuple[FloatArray, FloatArray]:
    """Pixel(s) at which base-frame direction(s) (pan, tilt) appear with the head at
    (head_pan, head_tilt): ``(uv (..., 2), in_front (...))``. Inverse of :func:`pixel_to_pan_tilt`."""
    b = pan_tilt_bearing(pan, tilt)
    return ray_to_pixel(intr, b @ optical_to_base(head_pan, head_tilt))


def base_to_pixel(
    intr: CameraIntrinsics, directions: ArrayLike, head_pan: float, head_tilt: float
) -> tuple[FloatArray, FloatArray]:
    """Pixel(s) of base-frame direction vector(s) (..., 3), any length: ``(uv, in_front)``."""
    return ray_to_pixel(intr, np.asarray(directions, dtype=float) @ optical_to_base(head_pan, head_tilt))


def in_image(intr: CameraIntrinsics, uv: ArrayLike, margin: float = 0.0) -> np.ndarray:
    """True where pixel(s) lie at least ``margin`` pixels inside the image (NaN -> False)."""
    uv = np.asarray(uv, dtype=float)
    with np.errstate(invalid="ignore"):
        return (
            (uv[..., 0] >= margin - 0.5)
            & (uv[..., 0] <= intr.width - 0.5 - margin)
            & (uv[..., 1] >= margin - 0.5)
            & (uv[..., 1] <= intr.height - 0.5 - margin)
        )
