"""Camera intrinsics (pinhole + OpenCV distortion) and their JSON file ``camera.json``.

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
import os
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fgloc.files import FileFormatError, write_json_atomic
from fgloc.json_fields import JsonFields

CAMERA_FORMAT = "fgloc-camera"
CAMERA_FORMAT_VERSION = 1


class IntrinsicsFormatError(FileFormatError):
    """A camera.json file that does not follow docs/camera-model.md."""


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
        cls, width: int, height: int, hfov_deg: float, zoom: float = 0.0, **distortion: float
    ) -> CameraIntrinsics:
        """Square-pixel camera with principal point at the image centre and a horizontal FOV in degrees."""
        fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(fx=fx, fy=fx, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height,
                   zoom=zoom, **distortion)

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


def intrinsics_to_json(intr: CameraIntrinsics) -> dict:
    """The model as a JSON-ready dict (docs/camera-model.md)."""
    data: dict[str, Any] = {
        "format": CAMERA_FORMAT,
        "version": CAMERA_FORMAT_VERSION,
        "image_size": [int(intr.width), int(intr.height)],
        "zoom": float(intr.zoom),
        "fx": float(intr.fx),
        "fy": float(intr.fy),
        "cx": float(intr.cx),
        "cy": float(intr.cy),
        "distortion": {k: float(getattr(intr, k)) for k in ("k1", "k2", "p1", "p2", "k3")},
    }
    if intr.rms_px is not None:
        data["rms_px"] = float(intr.rms_px)
    if intr.images:
        data["images"] = list(intr.images)
    return data


def write_intrinsics(intr: CameraIntrinsics, path: str | os.PathLike[str]) -> None:
    """Atomically write a camera.json file."""
    write_json_atomic(intrinsics_to_json(intr), path)


def read_intrinsics(path: str | os.PathLike[str]) -> CameraIntrinsics:
    """Read and validate a camera.json file; errors name file, field and value in one line."""
    r, data = JsonFields.load(path, IntrinsicsFormatError)
    fmt = data.get("format")
    if fmt != CAMERA_FORMAT:
        raise r.fail("format", f"expected {CAMERA_FORMAT!r}, got {fmt!r}")
    version = data.get("version")
    if isinstance(version, bool) or version != CAMERA_FORMAT_VERSION:
        raise r.fail("version", f"unsupported version {version!r} (this reader knows {CAMERA_FORMAT_VERSION})")
    size = r.array(r.get(data, "image_size", ""), "image_size")
    if len(size) != 2 or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size):
        raise r.fail("image_size", f"expected [width, height] positive integers, got {size!r}")
    zoom = r.number(r.get(data, "zoom", ""), "zoom")
    if not 0.0 <= zoom <= 1.0:
        raise r.fail("zoom", f"must lie in [0, 1], got {zoom!r}")
    values = {k: r.number(r.get(data, k, ""), k, positive=k in ("fx", "fy")) for k in ("fx", "fy", "cx", "cy")}
    for key, limit in (("cx", size[0]), ("cy", size[1])):
        if not -0.5 <= values[key] <= limit - 0.5:
            raise r.fail(key, f"principal point must lie inside the image (0 .. {limit - 1}), got {values[key]!r}")
    dist_obj = r.obj(r.get(data, "distortion", ""), "distortion")
    dist = {k: r.number(dist_obj.get(k, 0.0), f"distortion.{k}") for k in ("k1", "k2", "p1", "p2", "k3")}
    rms = data.get("rms_px")
    rms_px = None if rms is None else r.number(rms, "rms_px")
    images = data.get("images", [])
    if not isinstance(images, list) or not all(isinstance(i, str) for i in images):
        raise r.fail("images", "expected an array of file names")
    return CameraIntrinsics(width=size[0], height=size[1], zoom=zoom, rms_px=rms_px, images=tuple(images),
                            **values, **dist)
