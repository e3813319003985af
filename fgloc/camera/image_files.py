"""Read image files for calibration, naming what is wrong with a file instead of raising.

OpenCV decodes a truncated JPEG or PNG with only a warning on stderr (the missing
part comes out grey) and raises its own exception for an image above its pixel
limit (``CV_IO_MAX_IMAGE_PIXELS``, 2^30 by default). :func:`read_gray` checks the
container's end marker first (JPEG ``FF D9``, PNG ``IEND``), so a cut-off file is
named, not half-used.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"


def container_problem(data: bytes) -> str | None:
    """Why ``data`` (a whole file) is a truncated JPEG or PNG, or None."""
    if data[:2] == b"\xff\xd8" and b"\xff\xd9" not in data[-64:]:
        return "corrupt JPEG: the end-of-image marker is missing (truncated file?)"
    if data[:8] == _PNG_MAGIC and _PNG_END not in data[-64:]:
        return "corrupt PNG: the IEND chunk is missing (truncated file?)"
    return None


def read_gray(path: str | os.PathLike[str]) -> tuple[np.ndarray | None, str]:
    """``(image, "")`` as 8-bit grey, or ``(None, problem)`` for a file that cannot be used."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        return None, f"cannot read: {exc.strerror or exc}"
    problem = container_problem(data)
    if problem is not None:
        return None, problem
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:  # e.g. above OpenCV's pixel limit
        lines = [ln for ln in str(exc).strip().splitlines() if ln.strip()]
        return None, f"OpenCV cannot decode it: {lines[-1] if lines else exc}"
    if image is None:
        return None, "not an image OpenCV can decode (corrupt, or an unsupported format)"
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    return image, ""
