"""camera.json: read and write :class:`~fgloc.camera.intrinsics.CameraIntrinsics` (docs/camera-model.md)."""

from __future__ import annotations

import os
from typing import Any

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.errors import FileFormatError
from fgloc.files.json_io import JsonFields, write_json_atomic

CAMERA_FORMAT = "fgloc-camera"
CAMERA_FORMAT_VERSION = 1


class IntrinsicsFormatError(FileFormatError):
    """A camera.json file that does not follow docs/camera-model.md."""


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
