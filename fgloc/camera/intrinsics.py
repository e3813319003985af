"""Camera intrinsics (pinhole + OpenCV distortion) (their file, ``camera.json``, is read and written by :mod:`fgloc.files.camera_file`).

Pixel convention (OpenCV): ``u`` to the right, ``v`` down, the *centre* of the
top-left pixel is (0, 0). Focal lengths and principal point are in pixels.
Distortion follows OpenCV's five-coefficient model ``(k1, k2, p1, p2, k3)``
applied to normalised coordinates ``(x, y) = (X/Z, Y/Z)``::

    r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
    u  = fx xd + cx,  v = fy yd + cy

A model is valid at one zoom setting (``zoom``, fraction of the optical range,
0.0 = widest). The file format is documented in ``docs/camera-model.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole camera with OpenCV distortion, valid at one zoom setting.

    ``fx, fy, cx, cy`` in pixels; ``width, height`` in pixels; distortion
    coefficients dimensionless; ``zoom`` the zoom fraction (0.0 widest ... 1.0
    optical tele) at which the model was calibrated. ``rms_px`` is the
    calibration's overall RMS reprojection error (pixels) when known.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    zoom: float = 0.0
    rms_px: float | None = None
    images: tuple[str, ...] = field(default=(), compare=False)

    @classmethod
    def from_fov(
        cls, width: int, height: int, hfov_deg: float, zoom: float = 0.0,
        k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0, k3: float = 0.0,
    ) -> CameraIntrinsics:
        """Square-pixel camera with principal point at the image centre and a horizontal FOV in degrees."""
        fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(fx=fx, fy=fx, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height,
                   zoom=zoom, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)

    @property
    def camera_matrix(self) -> np.ndarray:
        """The 3x3 matrix K (pixels)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV distortion vector ``(k1, k2, p1, p2, k3)``."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy) in pixels."""
        return (self.cx, self.cy)

    def at_zoom(self, zoom: float, max_magnification: float = 10.0) -> CameraIntrinsics:
        """Idealised model at another zoom: focal lengths scale linearly from 1x (zoom 0) to
        ``max_magnification`` (zoom 1), relative to this model's own zoom. Distortion is kept.
        Used by the simulator; real cameras must be calibrated at each zoom used."""
        s = (1.0 + (max_magnification - 1.0) * zoom) / (1.0 + (max_magnification - 1.0) * self.zoom)
        return replace(self, fx=self.fx * s, fy=self.fy * s, zoom=zoom, rms_px=None, images=())
