"""camera.json: read and write :class:`~fgloc.camera.intrinsics.CameraIntrinsics` (docs/camera-model.md, docs/file-format.md)."""

from __future__ import annotations

import os
from typing import Any

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.errors import FileFormatError
from fgloc.files.json_io import check, load_json, write_json_atomic

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
    """Read a camera.json file (pixels) checked against ``schemas/camera.schema.json``; errors are one line."""
    where = str(path)
    data = load_json(path, IntrinsicsFormatError)
    if isinstance(data, dict):  # format and version pick the schema, so they come first
        fmt, version = data.get("format"), data.get("version")
        if fmt != CAMERA_FORMAT:
            raise IntrinsicsFormatError(f"{where}: format: expected {CAMERA_FORMAT!r}, got {fmt!r}")
        if isinstance(version, bool) or version != CAMERA_FORMAT_VERSION:
            raise IntrinsicsFormatError(
                f"{where}: version: unsupported version {version!r} (this reader knows {CAMERA_FORMAT_VERSION})")
    check(data, "camera", where, IntrinsicsFormatError)
    width, height = data["image_size"]
    for key, limit in (("cx", width), ("cy", height)):
        if not -0.5 <= data[key] <= limit - 0.5:
            raise IntrinsicsFormatError(
                f"{where}: {key}: principal point must lie inside the image (0 .. {limit - 1}), got {data[key]!r}")
    rms = data.get("rms_px")
    return CameraIntrinsics(
        width=width, height=height, zoom=float(data["zoom"]),
        fx=float(data["fx"]), fy=float(data["fy"]), cx=float(data["cx"]), cy=float(data["cy"]),
        **{k: float(data["distortion"].get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")},
        rms_px=None if rms is None else float(rms), images=tuple(data.get("images", ())),
    )
