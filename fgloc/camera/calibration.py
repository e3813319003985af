"""Intrinsic calibration from checkerboard images (OpenCV), with per-image quality control.

Steps: find the inner corners of each image (``findChessboardCorners`` then
``cornerSubPix`` to ~0.05 px), ``calibrateCamera`` on all images where the
board was found, per-image RMS reprojection error, then repeatedly drop the
worst image while its RMS exceeds both ``max_image_rms`` and
``outlier_factor`` x the median RMS, and re-calibrate without it. The result is
a :class:`fgloc.camera.intrinsics.CameraIntrinsics` valid at the zoom the images were
taken at (zoom is an explicit part of the model, see docs/camera-model.md).

Sanity: a view whose corners lie within :func:`duplicate_tolerance_px` (RMS) of an
earlier view's is the same board pose (the same image twice, or the board not
moved) and adds no information: it is named and not used. Calibration is refused
when fewer than ``min_images`` distinct views remain, or when the fit leaves the
board planes all (nearly) parallel or turned about one axis only
(:func:`tilt_spread_deg` below :data:`MIN_TILT_SPREAD_DEG`), or when OpenCV's
standard deviations of fx, fy, cx, cy exceed :data:`MAX_RELATIVE_STD` of the focal
length: such views do not determine the intrinsics.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.errors import FglocError


class CalibrationError(FglocError):
    """Calibration impossible from the images given."""


@dataclass(frozen=True)
class BoardSpec:
    """A checkerboard: ``cols x rows`` *inner* corners, ``square`` side (any length unit).

    Board frame: inner corner (i, j) (column i, row j) at ``(i * square, j * square, 0)``.
    """

    cols: int
    rows: int
    square: float

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame, (cols*rows, 3) float32, row-major (OpenCV order)."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)], axis=1) * self.square
        return pts.astype(np.float32)

    @classmethod
    def parse(cls, text: str, square: float) -> BoardSpec:
        """From ``"COLSxROWS"`` (inner corners) and the square size; raises CalibrationError."""
        try:
            cols, rows = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise CalibrationError(f"--board: expected COLSxROWS inner corners like 9x6, got {text!r}") from None
        if cols < 3 or rows < 3:
            raise CalibrationError(f"--board: need at least 3x3 inner corners, got {text!r}")
        if not (math.isfinite(square) and square > 0):
            raise CalibrationError(f"--square: must be > 0, got {square!r}")
        return cls(cols, rows, square)


@dataclass(frozen=True)
class ImageReport:
    """Per-image outcome: board ``found``, RMS reprojection error (px) in the final fit (or
    at rejection), ``used`` in the final fit, and why not."""

    name: str
    found: bool
    rms_px: float | None
    used: bool
    reason: str


@dataclass(frozen=True)
class CalibrationResult:
    """The fitted model, the per-image reports and the overall RMS (px) of the used images."""

    intrinsics: CameraIntrinsics
    reports: tuple[ImageReport, ...]
    rms_px: float


def find_corners(image: np.ndarray, board: BoardSpec) -> np.ndarray | None:
    """Sub-pixel inner corners (cols*rows, 2) float32 in OpenCV order, or None if not found."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, (board.cols, board.rows), flags=flags)
    if not ok:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
    return corners.reshape(-1, 2)


#: Largest standard deviation of fx, fy, cx, cy, relative to the focal length, that a
#: calibration may leave (OpenCV's estimate from the fit's Jacobian).
MAX_RELATIVE_STD = 0.01


#: Least spread of the board normals (degrees, see :func:`tilt_spread_deg`): boards all
#: parallel to each other, or all turned about one axis, leave the focal length undetermined
#: (Zhang 2000, degenerate configurations); fitting distortion then absorbs the error.
MIN_TILT_SPREAD_DEG = 3.0


def tilt_spread_deg(normals: np.ndarray) -> float:
    """How far the board normals (K, 3) spread in the *less* spread of the two directions
    across their mean: the square root of the second eigenvalue of their scatter, in degrees.
    Zero when all boards are parallel or all tilt about one common axis."""
    centred = normals - normals.mean(axis=0)
    eig = np.linalg.eigvalsh(centred.T @ centred / len(normals))
    return float(np.degrees(np.arcsin(min(1.0, math.sqrt(max(float(eig[-2]), 0.0))))))


def duplicate_tolerance_px(size: tuple[int, int]) -> float:
    """RMS corner distance (px) under which two views are the same board pose: 0.5 % of the
    image diagonal, at least 1 px (sub-pixel corner noise is ~0.05 px)."""
    return max(1.0, 0.005 * math.hypot(*size))


def _same_pose(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Corner sets (K, 2) within ``tol`` px RMS, in either listing order (OpenCV may reverse it)."""
    return any(float(np.sqrt(np.mean(np.sum((a - c) ** 2, axis=1)))) < tol for c in (b, b[::-1]))


def _fit(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], flags: int):
    try:
        rms, K, dist, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
            obj, img, size, None, None, flags=flags)
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV could not calibrate from these views: {str(exc).strip().splitlines()[-1]}"
                               ) from None
    per_image = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        per_image.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - i.reshape(-1, 2)) ** 2, axis=1)))))
    normals = np.array([cv2.Rodrigues(r)[0][:, 2] for r in rvecs])
    return K, dist.ravel(), per_image, std.ravel()[:4], normals


def calibrate(
    images: Sequence[tuple[str, np.ndarray]],
    board: BoardSpec,
    zoom: float = 0.0,
    max_image_rms: float = 0.5,
    outlier_factor: float = 3.0,
    fit_k3: bool = False,
    min_images: int = 5,
    progress: Callable[[int, int], None] | None = None,
    unreadable: Sequence[tuple[str, str]] = (),
) -> CalibrationResult:
    """Calibrate from ``(name, image)`` pairs taken at ``zoom`` (0 widest ... 1 tele).

    An image is rejected when its RMS reprojection error (px) exceeds both ``max_image_rms``
    and ``outlier_factor`` x the median; ``k3`` is fixed at 0 unless ``fit_k3``.
    ``progress(done, total)`` is called after the board search in each image (the slow part).
    ``unreadable`` lists ``(name, reason)`` of files the caller could not decode; they are
    reported and count as not found. Near-duplicate views are reported and not used
    (see the module docstring).
    """
    if not 0.0 <= zoom <= 1.0:
        raise CalibrationError(f"--zoom: must lie in [0, 1], got {zoom!r}")
    size: tuple[int, int] | None = None
    found: list[tuple[str, np.ndarray]] = []
    reports: dict[str, ImageReport] = {}
    for done, (name, image) in enumerate(images, 1):
        h, w = image.shape[:2]
        if size is None:
            size = (w, h)
        elif size != (w, h):
            raise CalibrationError(f"{name}: image size {w}x{h} differs from the first image's {size[0]}x{size[1]}")
        corners = find_corners(image, board)
        twin = None if corners is None else next(
            (n for n, c in found if _same_pose(corners, c, duplicate_tolerance_px(size))), None)
        if corners is None:
            reports[name] = ImageReport(name, False, None, False, "board not found")
        elif twin is not None:
            reports[name] = ImageReport(name, True, None, False, f"same board pose as {twin} (not used)")
        else:
            found.append((name, corners))
        if progress is not None:
            progress(done, len(images))
    for name, reason in unreadable:
        reports[name] = ImageReport(name, False, None, False, reason)
    duplicates = [r.name for r in reports.values() if r.found and not r.used]
    if len(found) < min_images:
        named = f"; near-duplicates not counted: {', '.join(duplicates[:5])}" if duplicates else ""
        bad = f"; unreadable: {', '.join(n for n, _ in unreadable)}" if unreadable else ""
        raise CalibrationError(
            f"board {board.cols}x{board.rows} found in {len(found)} distinct views of {len(images) + len(unreadable)} "
            f"images, need at least {min_images}{named}{bad}"
        )
    assert size is not None
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    obj_pts = board.object_points()
    active = list(found)
    while True:
        K, dist, per_image, std, normals = _fit([obj_pts] * len(active), [c for _, c in active], size, flags)
        worst = int(np.argmax(per_image))
        limit = max(max_image_rms, outlier_factor * float(np.median(per_image)))
        if per_image[worst] <= limit or len(active) <= min_images:
            break
        name = active[worst][0]
        reports[name] = ImageReport(name, True, per_image[worst], False,
                                    f"RMS {per_image[worst]:.3f} px > {limit:.3f} px")
        del active[worst]
    spread = tilt_spread_deg(normals)
    if spread < MIN_TILT_SPREAD_DEG:
        raise CalibrationError(
            f"the {len(active)} views do not determine the intrinsics: the board planes are (nearly) parallel or "
            f"turn about one axis only (tilt spread {spread:.2g} deg < {MIN_TILT_SPREAD_DEG:g} deg); "
            "tilt the board in different directions (Zhang's method needs it)")
    focal = float(min(K[0, 0], K[1, 1]))
    worst_std = float(np.max(std)) if np.all(np.isfinite(std)) else math.inf
    if not (focal > 0 and worst_std <= MAX_RELATIVE_STD * focal):
        raise CalibrationError(
            f"the {len(active)} views do not determine the intrinsics (fx, fy, cx, cy uncertain by up to "
            f"{worst_std:.3g} px, fx {K[0, 0]:.4g} px): tilt the board in different directions and fill the image")
    for (name, _), rms in zip(active, per_image):
        reports[name] = ImageReport(name, True, rms, True, "used")
    all_sq = [r * r for r in per_image]
    overall = float(math.sqrt(np.mean(all_sq)))
    k1, k2, p1, p2, k3 = (float(v) for v in dist[:5])
    intr = CameraIntrinsics(
        fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
        width=size[0], height=size[1], k1=k1, k2=k2, p1=p1, p2=p2, k3=k3,
        zoom=zoom, rms_px=overall, images=tuple(n for n, _ in active),
    )
    names = [n for n, _ in images] + [n for n, _ in unreadable]
    return CalibrationResult(intr, tuple(reports[n] for n in names), overall)
