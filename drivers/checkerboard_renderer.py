"""Render checkerboard images through a known camera model (truth for calibration tests).

Board frame: the board lies in its own z = 0 plane; inner corner (i, j) (i along
columns, j along rows) is at ``(i * square, j * square, 0)``; the printed board
has ``(cols + 1) x (rows + 1)`` squares, the square at the first inner corner's
upper-left is black, and a white margin of one square surrounds it. The pose
``(rvec, tvec)`` maps board to camera (OpenCV's ``projectPoints`` convention).

Rendering inverse-maps every pixel: undistort it to a ray (Newton, exact),
intersect the ray with the board plane, and shade by the square parity. Edges
are anti-aliased without bias: each parity function ``sin(pi x / square)`` is
divided by its pixel-space gradient to give a signed distance in pixels to the
nearest edge, ramped over one pixel, so edges and corners are symmetric about
their true positions. A slight Gaussian blur and seeded noise follow.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgloc.camera.calibration import BoardSpec
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_ray


def project_corners(intr: CameraIntrinsics, board: BoardSpec, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """True pixel positions (N, 2) of the inner corners (cv2.projectPoints)."""
    uv, _ = cv2.projectPoints(board.object_points().astype(np.float64), np.asarray(rvec, float),
                              np.asarray(tvec, float), intr.camera_matrix, intr.dist_coeffs)
    return uv.reshape(-1, 2)


_RAY_CACHE: dict[CameraIntrinsics, np.ndarray] = {}


def _rays(intr: CameraIntrinsics) -> np.ndarray:
    rays = _RAY_CACHE.get(intr)
    if rays is None:
        jj, ii = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
        rays = pixel_to_ray(intr, np.stack([jj, ii], axis=-1))
        _RAY_CACHE.clear()
        _RAY_CACHE[intr] = rays
    return rays


def render_checkerboard(
    intr: CameraIntrinsics,
    board: BoardSpec,
    rvec: np.ndarray,
    tvec: np.ndarray,
    rng: np.random.Generator | None = None,
    noise: float = 2.0,
    blur_sigma: float = 0.7,
) -> np.ndarray:
    """A uint8 (H, W) image of ``board`` at pose (rvec, tvec) through ``intr``."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, float))
    t = np.asarray(tvec, float).reshape(3)
    rays_b = _rays(intr) @ R  # R^T r: ray directions in the board frame
    origin_b = -R.T @ t  # camera centre in the board frame
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -origin_b[2] / rays_b[..., 2]
    hit = np.isfinite(lam) & (lam > 0)
    x = np.where(hit, origin_b[0] + lam * rays_b[..., 0], -1e9)
    y = np.where(hit, origin_b[1] + lam * rays_b[..., 1], -1e9)
    s = board.square

    def signed_px(f: np.ndarray) -> np.ndarray:
        """f divided by its pixel-space gradient: signed distance (pixels) to the zero line of f."""
        gy, gx = np.gradient(f)
        return f / np.maximum(np.hypot(gx, gy), 1e-12)

    # Parity fields, with coordinates clamped into the printed squares (to the centres of the
    # outermost squares) so that the outer boundary does not look like a checker edge.
    xc = np.clip(x, -0.5 * s, (board.cols - 0.5) * s)
    yc = np.clip(y, -0.5 * s, (board.rows - 0.5) * s)
    ramp_a = np.clip(signed_px(np.sin(np.pi * xc / s)), -0.5, 0.5) * 2.0  # -1 .. 1 across one pixel
    ramp_b = np.clip(signed_px(np.sin(np.pi * yc / s)), -0.5, 0.5) * 2.0
    # Square [-s, 0] x [-s, 0] (upper-left of the first inner corner) is black: a < 0, b < 0 there.
    black = 0.5 + 0.5 * ramp_a * ramp_b
    # Coverage of the printed squares, anti-aliased the same way.
    in_x = np.clip(0.5 + signed_px(np.minimum(x + s, board.cols * s - x)), 0.0, 1.0)
    in_y = np.clip(0.5 + signed_px(np.minimum(y + s, board.rows * s - y)), 0.0, 1.0)
    img = 1.0 - black * in_x * in_y  # 0 black, 1 white
    on_paper = (x > -2 * s) & (x < (board.cols + 1) * s) & (y > -2 * s) & (y < (board.rows + 1) * s)
    img = np.where(on_paper, img, 0.35)
    img = 30.0 + 190.0 * img
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    if rng is not None and noise > 0:
        img = img + rng.normal(0.0, noise, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def board_poses(
    board: BoardSpec,
    count: int,
    rng: np.random.Generator,
    distance: float = 0.6,
    max_tilt_deg: float = 35.0,
    intrinsics: CameraIntrinsics | None = None,
    margin_px: float = 25.0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` varied board poses (rvec, tvec) in front of the camera, board centre near the
    optical axis at roughly ``distance`` (board units), tilted up to ``max_tilt_deg``. With
    ``intrinsics``, only poses whose whole printed board lies ``margin_px`` inside the image."""
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    s = board.square
    centre = np.array([(board.cols - 1) * s / 2.0, (board.rows - 1) * s / 2.0, 0.0])
    outline = np.array([[-2 * s, -2 * s, 0], [(board.cols + 1) * s, -2 * s, 0],
                        [(board.cols + 1) * s, (board.rows + 1) * s, 0], [-2 * s, (board.rows + 1) * s, 0]])
    for _ in range(1000 * count):
        if len(poses) == count:
            break
        ang = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, size=2))
        roll = np.radians(rng.uniform(-20.0, 20.0))
        R = _rot(ang[0], ang[1], roll)
        offset = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), 0.0]) * distance
        cam_centre = np.array([0.0, 0.0, distance * rng.uniform(0.85, 1.25)]) + offset
        t = cam_centre - R @ centre
        rvec = cv2.Rodrigues(R)[0].reshape(3)
        if intrinsics is not None:
            uv, _ = cv2.projectPoints(outline, rvec, t, intrinsics.camera_matrix, intrinsics.dist_coeffs)
            uv = uv.reshape(-1, 2)
            if (uv.min() < margin_px or uv[:, 0].max() > intrinsics.width - margin_px
                    or uv[:, 1].max() > intrinsics.height - margin_px):
                continue
        poses.append((rvec, t))
    return poses


def _rot(ax: float, ay: float, az: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx
