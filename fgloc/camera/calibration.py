"""Intrinsic calibration from checkerboard images (OpenCV), with per-image quality control.

Steps: find the inner corners of each image (``findChessboardCorners`` then
``cornerSubPix`` to ~0.05 px), ``calibrateCamera`` on all images where the
board was found, per-image RMS reprojection error, then repeatedly drop the
worst image while its RMS exceeds both ``max_image_rms`` and
``outlier_factor`` x the median RMS, and re-calibrate without it. The result is
a :class:`fgloc.camera.intrinsics.CameraIntrinsics` valid at the zoom the images were
taken at (zoom is an explicit part of the model, see docs/camera-model.md).
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
        if cols < 2 or rows < 2:
            raise CalibrationError(f"--board: need at least 2x2 inner corners, got {text!r}")
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


def _fit(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], flags: int):
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
    per_image = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        per_image.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - i.reshape(-1, 2)) ** 2, axis=1)))))
    return K, dist.ravel(), per_image


def calibrate(
    images: Sequence[tuple[str, np.ndarray]],
    board: BoardSpec,
    zoom: float = 0.0,
    max_image_rms: float = 0.5,
    outlier_factor: float = 3.0,
    fit_k3: bool = False,
    min_images: int = 5,
    progress: Callable[[int, int], None] | None = None,
) -> CalibrationResult:
    """Calibrate from ``(name, image)`` pairs taken at ``zoom`` (0 widest ... 1 tele).

    An image is rejected when its RMS reprojection error (px) exceeds both ``max_image_rms``
    and ``outlier_factor`` x the median; ``k3`` is fixed at 0 unless ``fit_k3``.
    ``progress(done, total)`` is called after the board search in each image (the slow part).
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
        if corners is None:
            reports[name] = ImageReport(name, False, None, False, "board not found")
        else:
            found.append((name, corners))
        if progress is not None:
            progress(done, len(images))
    if len(found) < min_images:
        raise CalibrationError(
            f"board {board.cols}x{board.rows} found in {len(found)} of {len(images)} images, need at least {min_images}"
        )
    assert size is not None
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    obj_pts = board.object_points()
    active = list(found)
    while True:
        K, dist, per_image = _fit([obj_pts] * len(active), [c for _, c in active], size, flags)
        worst = int(np.argmax(per_image))
        limit = max(max_image_rms, outlier_factor * float(np.median(per_image)))
        if per_image[worst] <= limit or len(active) <= min_images:
            break
        name = active[worst][0]
        reports[name] = ImageReport(name, True, per_image[worst], False,
                                    f"RMS {per_image[worst]:.3f} px > {limit:.3f} px")
        del active[worst]
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
    return CalibrationResult(intr, tuple(reports[n] for n, _ in images), overall)
