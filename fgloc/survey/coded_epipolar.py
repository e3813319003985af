"""Where a mote one camera read can lie in another camera: near an epipolar plane (lever ``looks``).

The fallback places a mote that camera A read and camera B did not where A's bearing meets
the ground plane (:func:`~fgloc.survey.coded_separation.predict`), and with
``looks "disk"`` B looks at every blob it left unexplained within
:data:`~fgloc.survey.coded_levers.PREDICTED_RADIUS` (3°) of that direction. The placement is
poor along A's ray (the range of a far mote hangs on A's tilt: at 1000 motes 5.1–5.3° off
seen from B at the 99th percentile) but good across it: the mote lies on A's ray, so seen from B
it lies near the plane through both cameras' centres and that ray (the *epipolar plane*). A
blob far from that plane cannot hide the mote.

With ``looks "epipolar"`` (:func:`within_band`) B keeps, of those blobs, the ones within

    across(node) = scale * max(gain, 1) + offset

of the plane, where

* ``gain`` = range from A / range from B at the predicted point: an error of A's bearing
  moves the plane by that much more, seen from B (for a mote nearer A, B's own reading
  error dominates, hence the floor of 1);
* ``scale`` (:func:`across_scale`) is measured on the survey's own data: for every mote both
  cameras read, the angle of B's reading from the plane of each of A's readings, divided by
  ``max(gain, 1)``; the largest over all such pairs times :data:`SAFETY`. At 1000 motes
  (three scenes) the largest was 0.37–0.42°, the 99th percentile 0.30°;
* ``offset``: half the decoder's separation at the survey zoom (a mote merged into a blob
  lies up to that far from the blob's centroid).

With fewer than :data:`MIN_PAIRS` motes read by both cameras there is no scale, and the disk
alone holds. Angles radians; directions (pan, tilt) in the searching camera's base frame;
positions in the survey's normalized frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose

LOOKS_MODES = ("disk", "epipolar")
#: fewer motes read by two cameras than this measure no scale: the disk alone holds
MIN_PAIRS = 20
#: the measured largest offset is widened by this factor
SAFETY = 1.25


@dataclass(frozen=True)
class EpipolarBand:
    """Where a mote one camera read can lie, seen from another camera.

    ``normal``: unit normal (searching camera's base frame) of the plane through both
    cameras' centres and the predicted point; ``gain``: range from the reading camera over
    range from the searching camera at the predicted point."""

    normal: np.ndarray
    gain: float


def band(reader_position: np.ndarray, searcher_position: np.ndarray, searcher_rotation: np.ndarray,
         point: np.ndarray) -> EpipolarBand | None:
    """The band of a mote at ``point`` (world) read from ``reader_position``, seen from the
    camera at ``searcher_position`` with base-to-world ``searcher_rotation``; None when the
    point lies on the baseline (no plane)."""
    a, b, p = (np.asarray(x, float) for x in (reader_position, searcher_position, point))
    normal = np.cross(a - b, p - a)
    size, range_b = float(np.linalg.norm(normal)), float(np.linalg.norm(p - b))
    if size < 1e-12 or range_b < 1e-12:
        return None
    return EpipolarBand(np.asarray(searcher_rotation, float).T @ (normal / size), float(np.linalg.norm(p - a)) / range_b)


def across_angles(directions: np.ndarray, band_: EpipolarBand) -> np.ndarray:
    """(M,) angles of (M, 2) (pan, tilt) ``directions`` from the band's plane."""
    d = np.asarray(directions, float).reshape(-1, 2)
    cos = pan_tilt_bearing(d[:, 0], d[:, 1]) @ band_.normal
    return np.arcsin(np.clip(np.abs(np.atleast_1d(cos)), 0.0, 1.0))


def within_band(directions: np.ndarray, band_: EpipolarBand, scale: float, offset: float) -> np.ndarray:
    """(M,) whether each (pan, tilt) of ``directions`` lies within ``scale * max(gain, 1) +
    offset`` of the band's plane."""
    return across_angles(directions, band_) <= scale * max(band_.gain, 1.0) + offset


def across_scale(poses: Mapping[str, CameraPose], readings: Mapping[tuple[str, str], Sequence[tuple[float, float]]],
                 points: Mapping[str, np.ndarray]) -> float | None:
    """:data:`SAFETY` times the largest ``across / max(gain, 1)`` over the motes two cameras
    read: for each such mote (``points``: its solved position) and ordered camera pair (A, B),
    the angle of B's first reading from the plane through both centres and each of A's
    reading rays (``readings``: (node, camera) -> (pan, tilt) list). None with fewer than
    :data:`MIN_PAIRS` such motes."""
    worst, motes = 0.0, set()
    for (node, a), rays in readings.items():
        if node not in points or a not in poses:
            continue
        for b, pose_b in poses.items():
            if b == a or (node, b) not in readings:
                continue
            motes.add(node)
            pose_a = poses[a]
            seen_b = np.array([readings[(node, b)][0]], float)
            range_b = max(float(np.linalg.norm(points[node] - pose_b.position)), 1e-12)
            gain = float(np.linalg.norm(points[node] - pose_a.position)) / range_b
            for pan, tilt in rays:
                ray = pose_a.position + np.asarray(pose_a.rotation, float) @ pan_tilt_bearing(pan, tilt)
                got = band(pose_a.position, pose_b.position, pose_b.rotation, ray)
                if got is not None:
                    worst = max(worst, float(across_angles(seen_b, got)[0]) / max(gain, 1.0))
    return SAFETY * worst if len(motes) >= MIN_PAIRS else None


def one_camera_bands(poses: Mapping[str, CameraPose],
                     readings: Mapping[tuple[str, str], Sequence[tuple[float, float]]],
                     points: Mapping[str, np.ndarray]) -> dict[str, dict[str, EpipolarBand]]:
    """Camera -> node -> band, for every node (``points``: its placed position) that exactly one
    camera read (``readings``: (node, camera) -> (pan, tilt) list), seen from each other camera."""
    read_by: dict[str, list[str]] = {}
    for node, cam in readings:
        read_by.setdefault(node, []).append(cam)
    out: dict[str, dict[str, EpipolarBand]] = {c: {} for c in poses}
    for node, cams in sorted(read_by.items()):
        if len(cams) != 1 or node not in points or cams[0] not in poses:
            continue
        for cam, seen_from in poses.items():
            if cam != cams[0] and (b := band(poses[cams[0]].position, seen_from.position, seen_from.rotation,
                                             points[node])):
                out[cam][node] = b
    return out


def half_separation(separation_px: float, focal_px: float) -> float:
    """The angle half the decoder's separation spans at a focal length (pixels): how far a
    merged mote lies from its blob's centroid at most."""
    return 0.5 * separation_px / focal_px if focal_px > 0 else math.pi
