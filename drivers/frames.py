"""Frame sources: a tiny interface over ``cv2.VideoCapture`` (capture card or stream URL).

A :class:`FrameSource` has ``read() -> ndarray`` (uint8, (H, W) grayscale or
(H, W, 3) BGR, the newest frame) and ``close()``. Heads take any object with
``read()`` (or a zero-argument callable) for ``grab_frame``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from fgloc.core.errors import FglocError


class FrameError(FglocError):
    """A frame source could not be opened or stopped delivering frames."""


@runtime_checkable
class FrameSource(Protocol):
    def read(self) -> np.ndarray:
        """The newest frame, uint8 (H, W) or (H, W, 3) BGR."""

    def close(self) -> None:
        """Release the device or stream."""


class VideoCaptureSource:
    """Frames from ``cv2.VideoCapture``: a device index (``0``, ``"1"``) or a URL/file path.

    Capture cards buffer a few frames; ``read`` discards ``flush_frames`` stale
    frames first so the image matches the head's current position. The source
    text may contain credentials (``rtsp://user:pw@host``); it is never echoed in
    errors, only its scheme and host.
    """

    def __init__(self, source: int | str, flush_frames: int = 2, open_timeout_s: float = 5.0) -> None:
        import cv2

        if isinstance(source, str) and source.strip().isdigit():
            source = int(source)
        self._label = _redact(source)
        self.flush_frames = flush_frames
        self._cap = cv2.VideoCapture(source)
        if not self._cap.isOpened():
            raise FrameError(f"video {self._label}: cannot open")
        self._lock = threading.Lock()

    def read(self) -> np.ndarray:
        with self._lock:
            for _ in range(self.flush_frames):
                self._cap.grab()
            ok, frame = self._cap.read()
        if not ok or frame is None:
            raise FrameError(f"video {self._label}: no frame (device unplugged or stream ended)")
        return frame

    def close(self) -> None:
        self._cap.release()

    def __enter__(self) -> VideoCaptureSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CallableFrameSource:
    """Wraps a zero-argument callable (a renderer bound to a simulated head, a test pattern)."""

    def __init__(self, render: Callable[[], np.ndarray]) -> None:
        self._render = render

    def read(self) -> np.ndarray:
        frame = np.asarray(self._render())
        if frame.dtype != np.uint8 or frame.ndim not in (2, 3):
            raise FrameError(f"synthetic frame source gave {frame.dtype} array of shape {frame.shape}")
        return frame

    def close(self) -> None:
        pass


def synthetic_frames(height: int = 480, width: int = 640, spot: tuple[int, int] | None = None) -> CallableFrameSource:
    """A dark frame with an optional bright 3x3 spot at (row, col); for tests and dry runs."""

    def render() -> np.ndarray:
        img = np.zeros((height, width), np.uint8)
        if spot is not None:
            r, c = spot
            img[max(r - 1, 0):r + 2, max(c - 1, 0):c + 2] = 255
        return img

    return CallableFrameSource(render)


def open_frame_source(source: str | int | None) -> FrameSource | None:
    """``None`` -> None; a digit string or int -> capture device; anything else -> URL/file."""
    if source is None or source == "":
        return None
    return VideoCaptureSource(source)


def _redact(source: int | str) -> str:
    if isinstance(source, int):
        return f"device {source}"
    from urllib.parse import urlsplit

    parts = urlsplit(source)
    if parts.scheme and parts.hostname:
        port = f":{parts.port}" if parts.port else ""
        return f"{parts.scheme}://{parts.hostname}{port}{parts.path}"
    return source
