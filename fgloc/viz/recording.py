"""Recordings: open a stream (saved to an .rrd), close it, and write a whole result in one call."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.model import Result, Survey
from fgloc.viz.blueprint import default_blueprint
from fgloc.viz.entities import log_result
from fgloc.viz.head_view import log_head_calibration
from fgloc.viz.iterations import IterationRecorder, log_subset_solutions
from fgloc.viz.style import VizOptions

APPLICATION_ID = "fgloc"


def open_recording(
    path: str | os.PathLike[str] | None = None,
    *,
    recording_id: str | None = None,
    blueprint: rrb.Blueprint | None = None,
) -> rr.RecordingStream:
    """A new recording stream; saved to ``path`` (with ``blueprint`` as default) when given.

    The world frame is declared right-handed, z up. Call :func:`close_recording`
    when done so the file gets its footer.
    """
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    if path is not None:
        try:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            rec.save(str(path), default_blueprint=blueprint)
        except (OSError, RuntimeError) as exc:  # rerun reports an unwritable file as RuntimeError
            reason = str(exc).split(" (os error")[0].split(", path:")[0]
            raise FglocError(f"{path}: cannot write the Rerun recording ({reason})") from None
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and close the stream (writes the .rrd footer)."""
    rec.flush()
    rec.disconnect()


def camera_covariances_or_none(survey: Survey | None, result: Result) -> dict[str, FloatArray] | None:
    """Camera pose covariances for drawing, or None when there is no survey or they are undefined."""
    if survey is None or not result.cameras:
        return None
    from fgloc.solve.camera_uncertainty import camera_covariances

    try:
        return camera_covariances(survey, result)
    except FglocError:
        return None


def write_rrd(
    path: str | os.PathLike[str],
    result: Result,
    survey: Survey | None = None,
    *,
    recorder: IterationRecorder | None = None,
    subsets: tuple[Sequence[str], FloatArray, np.ndarray, FloatArray | None] | None = None,
    camera_covariances: dict[str, FloatArray] | None = None,
    options: VizOptions = VizOptions(),
    recording_id: str | None = None,
    head_calibration: Mapping[str, Any] | None = None,
) -> Path:
    """Write a complete .rrd of a result (and optionally its survey, iterates, the
    subset-Newton baseline as ``(node_ids, positions, node_index, mean)`` and the result's
    ``head_calibration`` block, :mod:`fgloc.viz.head_view`) with the default blueprint.
    Returns the path."""
    path = Path(path)
    heads = list(head_calibration["cameras"]) if head_calibration else []
    rec = open_recording(path, recording_id=recording_id,
                         blueprint=default_blueprint(result, survey, options, head_cameras=heads))
    try:
        log_result(rec, result, survey, camera_covariances=camera_covariances, options=options)
        if head_calibration:
            log_head_calibration(rec, head_calibration)
        if recorder is not None:
            has_history = result.stats is not None and bool(result.stats.error_history)
            recorder.log(rec, errors=not has_history)
        if subsets is not None:
            log_subset_solutions(rec, *subsets)
    finally:
        close_recording(rec)
    return path
