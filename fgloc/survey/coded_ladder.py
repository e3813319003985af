"""Which blobs a refinement rung of the coded survey hands to the next rung (lever ``ladder``).

A rung of the zoom ladder (:meth:`fgloc.survey.coded.CodedSurvey.run_refine`) records tiles
over the blobs it chases (those the coarser views left unexplained) and decodes everything in
them. With ``ladder "climb"`` (the survey before this lever) every blob the tiles leave
unexplained (:func:`~fgloc.survey.coded_views.unexplained_blob`) is chased at the next rung,
wherever it lies in a tile. Measured on the EVI-D100-sized rig (docs/blink-codes.md,
"Where the ladder's time went"), most of those are not what the rung chased: a tile is
several times larger than the cluster it was planned for, and the motes and static lamps at
its edges, already read or chased at the survey zoom, come out refused there (too few clean
bits near the border, a lamp that never goes dark) and pull the ladder up to its last rung;
and about half of the blobs the wide pass leaves unexplained lie at a mote the same camera
read in another view.

``ladder "focus"``: a blob within :data:`EXPLAINED_PX` of a reading of the camera is that mote
(:func:`unread`, before each rung and for the fallback); a view is recorded a second time only
for a blob no reading explains (:func:`retry_helps`); and (:func:`focused`) a rung carries a
blob on only when it lies where the rung looked:
within :data:`FOCUS_PX` pixels (of the chased blob's own, coarser, recording) of a chased blob.
Any other blob lies in a direction a coarser view already decoded or chases itself (every
direction is at least 8 px inside some wide view, :mod:`fgloc.survey.view_planner`), unless
no coarser recording showed light there (:func:`unseen`: a faint mote or a crowd the wide
zoom's detector did not report), which the survey hands to the fallback. A blob
that never goes dark where the blob it refines never went dark either (a zoom step of at
least 2x split nothing and made nothing blink: a static lamp) is not chased further but
handed to the fallback (:mod:`fgloc.survey.coded_fallback`), which searches it the
sequential way if a mote may hide there (two motes merged into one never-dark blob separate
there: one LED is lit at a time). The lever only chooses which tiles and second recordings are
made; decoding and labelling are unchanged (a mote may be read in another recording).

Angles radians, pixels OpenCV convention.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pan_tilt_to_pixel, pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing

Blob = tuple[tuple[float, float], tuple[float, float], float]  #: (u, v) px, head (pan, tilt), zoom of a refused blob
LADDER_MODES = ("climb", "focus")
EXPLAIN_MODES = ("readings", "views", "crowds")
RETRIES_AT_MODES = ("all", "first_rung", "wide")
#: a blob of a rung's tile is the chased blob's (a member of its cluster) within this many pixels
#: of the chased blob's own recording: twice the 6 px the tiles reach around it
FOCUS_PX = 12.0
#: a refused blob this close (pixels of its own recording) to a reading of the same camera is that mote
EXPLAINED_PX = 1.5
#: two LEDs closer than this (pixels of one recording) make one blob there (the decoder's separation)
SEPARATION_PX = 6.0
#: ``explain "crowds"``: a wide-pass blob is resolved only where another recording read this many
#: motes or more in its clean neighbourhood (a crowd read apart). With one reading enough, two
#: motes with a single read neighbour within 1 deg went unread at 100 motes
CROWD_READINGS = 2
_NEVER_DARK = "never dark"


def never_dark(refused: dict[str, object]) -> bool:
    """A refused blob that stayed lit in every frame (a static lamp, or motes merged so that one is always on)."""
    return refused.get("kind") == "rejected" and str(refused.get("reason", "")).startswith(_NEVER_DARK)


def direction(blob: Blob, intrinsics_at: Callable[[float], CameraIntrinsics]) -> tuple[float, float]:
    """(pan, tilt) of ``blob`` seen through the intrinsics of its zoom."""
    (u, v), head, zoom = blob
    p, t = pixel_to_pan_tilt(intrinsics_at(zoom), np.array([u, v]), *head)
    return float(p), float(t)


def view_order(view: str) -> tuple[int, int, int]:
    """Where view id ``view`` falls in a camera's survey: the wide pass (``w<k>``), the radio
    rounds (``s...``, all at one place), then rung n's tiles (``r<n>-<k>``), then the fallback
    round (``f<k>``), in that order."""
    if view.startswith("w"):
        return 0, 0, int(view[1:])
    if view.startswith("r"):
        rung, k = view[1:].split("-")
        return 2, int(rung), int(k)
    if view.startswith("f"):
        return 3, 0, int(view[1:])
    return 1, 0, 0


def may_record_again(view: str, retries_at: str) -> bool:
    """Whether view id ``view`` may be recorded a second time (lever ``retries_at``): ``"all"``
    every view; ``"first_rung"`` the wide pass, the radio rounds and the first refinement rung's
    tiles only; ``"wide"`` the wide pass and the radio rounds only. A blob a view not recorded
    again leaves unexplained goes up the ladder or to the fallback instead. At 1000 motes 80 % of
    the second recordings at 6×, every one at 10× and 29 of 31 in the fallback round read
    nothing, and without those at 3× too the survey took 5.7 % less field time
    (docs/blink-codes.md, "Second recordings only up to the first rung")."""
    if retries_at == "all":
        return True
    kind, rung, _k = view_order(view)
    return kind < 2 or (retries_at == "first_rung" and kind == 2 and rung <= 1)


def _readings_before(views: Mapping[tuple[str, str, int], Mapping[str, Any]], camera: str, rung: int,
                     view: str | None, attempt: int) -> list[Mapping[str, Any]]:
    """The readings :func:`read_before` and :func:`codes_read_before` take, in journal order."""
    bound = (2, rung + 1, 0) if view is None else view_order(view)
    out: list[Mapping[str, Any]] = []
    for (cam, vid, att), rec in views.items():
        if cam != camera:
            continue
        order = view_order(vid)
        if order < bound or (vid == view and att <= attempt):
            out += rec.get("readings", [])
    return out


def read_before(views: Mapping[tuple[str, str, int], Mapping[str, Any]], camera: str, rung: int,
                view: str | None = None, attempt: int = 0) -> np.ndarray:
    """(M, 3) unit bearings of ``camera``'s readings in its journaled ``views`` (keyed (camera,
    view id, attempt)) of the wide pass, the radio rounds and refinement rungs up to ``rung``:
    exactly the views done before rung ``rung + 1`` is planned, so a resume decides alike. With
    ``view``: the views before it (:func:`view_order`) and its own recordings up to ``attempt``."""
    out = [pan_tilt_bearing(float(r["pan"]), float(r["tilt"])) for r in _readings_before(views, camera, rung, view, attempt)]
    return np.array(out, dtype=float).reshape(-1, 3)


def codes_read_before(views: Mapping[tuple[str, str, int], Mapping[str, Any]], camera: str, view: str,
                      attempt: int) -> dict[int, np.ndarray]:
    """Book code -> unit bearing (``camera``'s head frame) of ``camera``'s readings in the
    journaled views before ``view`` and its recordings before ``attempt`` (as :func:`read_before`,
    so a resume decodes alike): where the light-curve fit may take a mote to be elsewhere
    (:func:`fgloc.camera.blink_decoder.decode_view`, ``elsewhere``)."""
    return {int(r["code"]): pan_tilt_bearing(float(r["pan"]), float(r["tilt"]))
            for r in _readings_before(views, camera, 0, view, attempt - 1) if "code" in r}


def retry_helps(record: Mapping[str, Any], read: np.ndarray, intrinsics_at: Callable[[float], CameraIntrinsics],
                survey_zoom: float) -> bool:
    """Whether a second recording of ``record`` (which :func:`~fgloc.survey.coded_views.needs_second_recording`
    asks for) may read a mote not read yet: some blob it leaves unexplained
    (:func:`~fgloc.survey.coded_views.unexplained_blob`: curable refusals, and merged or
    never-dark blobs a longer recording may also resolve) lies at no bearing of ``read`` (the
    camera's readings so far, :func:`read_before` with its view), or has no pixel. A view
    whose unexplained blobs are all motes this camera already read is not recorded again."""
    from fgloc.survey.coded_views import unexplained_blob

    head = (float(record["head"][0]), float(record["head"][1]))
    zoom = float(record.get("zoom", survey_zoom))
    blobs: list[Blob] = []
    for r in record.get("refused", []):
        if not unexplained_blob(r):
            continue
        if "u" not in r:
            return True
        blobs.append(((float(r["u"]), float(r["v"])), head, zoom))
    return bool(unread(blobs, read, intrinsics_at))


def unread(found: Sequence[Blob], read: np.ndarray, intrinsics_at: Callable[[float], CameraIntrinsics],
           merged: Sequence[bool] | None = None) -> list[int]:
    """Indices of ``found`` no reading explains: no bearing of ``read`` ((M, 3), :func:`read_before`)
    within :data:`EXPLAINED_PX` pixels of the blob in its own recording. A blob at a read mote is
    that mote refused in one view (cut by the border, a noisy bit, a duplicate decode) and read in
    another: at the same zoom a second mote merged with it would have spoilt that reading too.
    Not so a blob refused as merged LEDs (``merged[k]``, kind ``ambiguous``): its other mote may
    be the one not read (a mote 2.6 px from a mote read at a higher zoom: the merged blob's
    centroid lies 1.3 px from that reading), so it is always kept."""
    keep = []
    for k, blob in enumerate(found):
        intr = intrinsics_at(blob[2])
        if merged is not None and merged[k]:
            keep.append(k)
            continue
        if len(read) and float(np.max(read @ pan_tilt_bearing(*direction(blob, intrinsics_at)))) >= math.cos(
                EXPLAINED_PX / max(intr.fx, intr.fy)):
            continue
        keep.append(k)
    return keep


def resolved_elsewhere(found: Sequence[Blob], views: Mapping[tuple[str, str, int], Mapping[str, Any]], camera: str,
                       rung: int, intrinsics_at: Callable[[float], CameraIntrinsics], survey_zoom: float,
                       min_readings: int = 1) -> list[bool]:
    """Which blobs of ``found`` another recording resolved (lever ``explain "views"``): a
    journaled recording of ``camera`` in the views before refinement rung ``rung + 1`` (as
    :func:`read_before`), from another head or zoom, at the blob's zoom or closer, that has
    the whole neighbourhood of the blob (:data:`SEPARATION_PX` of the blob's own recording)
    inside its image, ``min_readings`` readings or more in it, and no refused blob of any kind
    in it (a border cut counts). Every LED that could have merged into the blob lies in that
    neighbourhood, and the same camera sees the same motes from another view: there each was
    read, or it would have left a refused blob there. Measured at 1000 motes: two LEDs merged in
    one tile, read apart in the tile beside it (docs/blink-codes.md, "Blobs another view
    resolved"). ``explain "crowds"`` asks the wide pass's blobs for :data:`CROWD_READINGS`
    (docs/blink-codes.md, "Crowds another wide view read apart")."""
    bound = (2, rung + 1, 0)
    others = []  # (head, zoom, intrinsics, readings' pixels, refused blobs' pixels) of each candidate recording
    for (cam, vid, _att), rec in views.items():
        if cam == camera and view_order(vid) < bound:
            zoom = float(rec.get("zoom", survey_zoom))
            others.append(((float(rec["head"][0]), float(rec["head"][1])), zoom, intrinsics_at(zoom),
                           _pixels(rec.get("readings", [])), _pixels(rec.get("refused", []))))
    out = []
    for (uv, head, zoom) in found:
        own = intrinsics_at(zoom)
        own_f = max(own.fx, own.fy)
        pan, tilt = pixel_to_pan_tilt(own, np.array(uv, dtype=float), *head)
        resolved = False
        for at, z, intr, read_px, refused_px in others:
            if (at, z) == (head, zoom) or max(intr.fx, intr.fy) < own_f * (1 - 1e-9):
                continue
            radius = SEPARATION_PX * max(intr.fx, intr.fy) / own_f
            px, front = pan_tilt_to_pixel(intr, float(pan), float(tilt), *at)
            if not front or not (radius <= px[0] <= intr.width - radius and radius <= px[1] <= intr.height - radius):
                continue
            if _count_within(read_px, px, radius) >= min_readings and not _any_within(refused_px, px, radius):
                resolved = True
                break
        out.append(resolved)
    return out


def _pixels(items: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """(M, 2) pixels of the journaled readings or refused blobs that have one."""
    return np.array([(float(i["u"]), float(i["v"])) for i in items if "u" in i], dtype=float).reshape(-1, 2)


def _count_within(pixels: np.ndarray, centre: np.ndarray, radius: float) -> int:
    return int(np.count_nonzero(np.hypot(*(pixels - np.asarray(centre, float)).T) <= radius)) if len(pixels) else 0


def _any_within(pixels: np.ndarray, centre: np.ndarray, radius: float) -> bool:
    return _count_within(pixels, centre, radius) > 0


def light_before(views: Mapping[tuple[str, str, int], Mapping[str, Any]], camera: str, rung: int,
                 intrinsics_at: Callable[[float], CameraIntrinsics], survey_zoom: float) -> tuple[np.ndarray, np.ndarray]:
    """Where ``camera``'s journaled recordings before refinement rung ``rung`` (the wide pass,
    the radio rounds, the rungs below) showed light: (M, 3) unit bearings of their readings and
    refused blobs, and (M,) the cosine of the angle each one covers in its own recording: a
    reading its own LED (:data:`EXPLAINED_PX`), a refused blob every LED merged into it
    (:data:`SEPARATION_PX`)."""
    bound = (2, rung, 0)
    dirs, cos = [np.zeros((0, 3))], [np.zeros(0)]
    for (cam, vid, _att), rec in views.items():
        if cam != camera or not view_order(vid) < bound:
            continue
        intr = intrinsics_at(float(rec.get("zoom", survey_zoom)))
        for px, items in ((EXPLAINED_PX, rec.get("readings", [])), (SEPARATION_PX, rec.get("refused", []))):
            uv = np.array([(float(i["u"]), float(i["v"])) for i in items if "u" in i]).reshape(-1, 2)
            if len(uv):
                pan, tilt = pixel_to_pan_tilt(intr, uv, float(rec["head"][0]), float(rec["head"][1]))
                dirs.append(pan_tilt_bearing(pan, tilt).reshape(-1, 3))
                cos.append(np.full(len(uv), math.cos(px / max(intr.fx, intr.fy))))
    return np.concatenate(dirs), np.concatenate(cos)


def unseen(found: Sequence[Blob], seen: tuple[np.ndarray, np.ndarray],
           intrinsics_at: Callable[[float], CameraIntrinsics]) -> list[Blob]:
    """The blobs of ``found`` no coarser recording showed light at (``seen``,
    :func:`light_before`): a faint mote the wide zoom did not detect, or a crowd its detector
    took for no LED, turning up in a tile planned for other blobs. :func:`focused` drops such a
    blob when it lies away from what the rung chased (it assumes a coarser view decided that
    direction); the survey hands it to the fallback instead (the predicted fallback and its
    round search it only where a mote is still unread near it: a glint draws no search)."""
    out = []
    for blob in found:
        if not bool(np.any(seen[0] @ pan_tilt_bearing(*direction(blob, intrinsics_at)) >= seen[1])):
            out.append(blob)
    return out


def focused(chased: Sequence[Blob], chased_dark: Sequence[bool], found: Sequence[Blob], found_dark: Sequence[bool],
            intrinsics_at: Callable[[float], CameraIntrinsics]) -> tuple[list[Blob], list[Blob]]:
    """Split ``found`` (the blobs a rung's tiles left unexplained) into (carried on to the next
    rung, handed to the fallback); the rest are dropped (module docstring). ``chased``: the blobs
    the rung's tiles were planned over; ``*_dark``: which of them never went dark
    (:func:`never_dark`); ``intrinsics_at(zoom)``: the camera's intrinsics at a zoom."""
    if not chased or not found:
        return [], []
    centres = np.array([pan_tilt_bearing(*direction(b, intrinsics_at)) for b in chased])
    # the angle FOCUS_PX spans in each chased blob's own recording (its focal length at its zoom)
    reach = np.array([math.cos(FOCUS_PX / max(intrinsics_at(b[2]).fx, intrinsics_at(b[2]).fy)) for b in chased])
    dark = np.asarray(chased_dark, dtype=bool)
    carried: list[Blob] = []
    handed: list[Blob] = []
    for blob, lamp in zip(found, found_dark):
        near = centres @ pan_tilt_bearing(*direction(blob, intrinsics_at)) >= reach
        if not near.any():
            continue  # a coarser view decoded this direction or chases it itself
        (handed if lamp and bool(dark[near].any()) else carried).append(blob)
    return carried, handed
