"""Frame sources: cv2.VideoCapture on a real (written) video file, synthetic sources, error lines."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fgloc.drivers.frames import (
    CallableFrameSource,
    FrameError,
    FrameSource,
    VideoCaptureSource,
    _redact,
    open_frame_source,
    synthetic_frames,
)


def test_video_file_through_videocapture(tmp_path) -> None:
    path = str(tmp_path / "clip.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(6):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    with VideoCaptureSource(path, flush_frames=0) as src:
        assert isinstance(src, FrameSource)
        first = src.read()
        assert first.shape == (48, 64, 3) and first.dtype == np.uint8
        assert abs(int(first.mean()) - 0) <= 3
        second = src.read()
        assert abs(int(second.mean()) - 40) <= 3
        for _ in range(4):
            src.read()
        with pytest.raises(FrameError, match="no frame"):
            src.read()


def test_missing_source_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(FrameError, match="cannot open"):
        open_frame_source(str(tmp_path / "none.avi"))
    assert open_frame_source(None) is None


def test_credentials_never_in_labels() -> None:
    assert _redact("rtsp://admin:secret@10.0.0.9:554/stream1") == "rtsp://10.0.0.9:554/stream1"
    assert _redact(0) == "device 0"


def test_synthetic_sources() -> None:
    img = synthetic_frames(10, 12, spot=(5, 6)).read()
    assert img.shape == (10, 12) and img[5, 6] == 255 and img.sum() == 9 * 255
    with pytest.raises(FrameError):
        CallableFrameSource(lambda: np.zeros((2, 2), np.float64)).read()
