"""Short radio-separation rounds: a round view labelled against the round's candidates.

With ``rounds "short"`` (:class:`~fgloc.survey.coded_settings.CodedSettings`) a round view
of :mod:`fgloc.survey.coded_separation` records ``L + 2`` samples (:func:`round_frames`)
instead of ``3L + 2``, and its blobs are labelled by
:func:`fgloc.camera.blink_candidates.decode_candidates` (the rule is that module's docstring)
against the round's **candidates**: every mote of the lit class that has a predicted
direction in this camera (:func:`round_candidates`; not only the camera's crowded ones,
so a lit mote the camera already read is labelled, and dropped as read, instead of being
left unexplained), each predicted at the pixel its direction projects to at the view's
read-back head within :data:`ROUND_RADIUS_PX`. Every other mote is paused, so any other
lit blob is a mote that missed the pause or a static light: rule 4 of the candidate
decoder refuses it, and it stays unexplained (zoom refinement, as any refused blob). A
retry continues the recording by ``L`` (``2L + 2`` samples, decoded together).

The journal's view record carries ``candidates`` (the node ids labelled against, sorted);
a resumed survey re-plans the same candidates from the journaled wide views.
Angles radians; pixels OpenCV convention (the view's zoom, one field with fields video).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.camera.blink_candidates import Candidate, CandidateDecode, decode_candidates
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pan_tilt_to_pixel

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey

#: a candidate's range around its predicted pixel (px of the round view): the wide-pass
#: prediction is a joint solve of the readings (a few px at the wide zoom); the class has no
#: two members predicted within ``CONFLICT_PX`` (8 px) in a camera that found them crowded
ROUND_RADIUS_PX = 12.0
#: refusals a continued recording cannot cure: no candidate was predicted near the blob
NO_CANDIDATE = "no candidate predicted here"

RoundCandidates = list[tuple[str, tuple[float, float]]]  #: (node, predicted (pan, tilt)) per candidate


def round_frames(coded: CodedSurvey) -> int:
    """Samples a short round view records first: ``L + 2``."""
    return coded.book.length + 2


def round_candidates(lit: Sequence[str], predicted: Mapping[str, tuple[float, float]]) -> RoundCandidates:
    """The round's candidates in one camera: the ``lit`` nodes with a ``predicted`` (pan, tilt)
    there, sorted by node id."""
    return [(n, (float(predicted[n][0]), float(predicted[n][1]))) for n in sorted(lit) if n in predicted]


def decode_round(coded: CodedSurvey, frames: Sequence[tuple[float, np.ndarray]], intr: CameraIntrinsics,
                 head: tuple[float, float], candidates: RoundCandidates) -> CandidateDecode:
    """Label the blobs of ``frames`` (recorded at read-back ``head`` (pan, tilt) with ``intr``)
    against ``candidates``; candidates predicted behind the camera are left out (no blob can
    be theirs; their words still count as book words for rule 4)."""
    cands = []
    if candidates:
        pt = np.array([d for _, d in candidates], float)
        uv, front = pan_tilt_to_pixel(intr, pt[:, 0], pt[:, 1], head[0], head[1])
        for (node, _), (u, v), ok in zip(candidates, np.asarray(uv, float), np.asarray(front, bool)):
            if ok and np.isfinite(u) and np.isfinite(v):
                cands.append(Candidate(coded.addresses[node] - coded.first, float(u), float(v), ROUND_RADIUS_PX))
    return decode_candidates(frames, coded.camera.frame_period_s, coded.book, cands, intr, head[0], head[1])


def retry_wanted(record: Mapping[str, Any]) -> bool:
    """A short round view's record whose refusals a continued recording may cure: those of
    :func:`~fgloc.survey.coded_views.needs_second_recording` except blobs near no candidate."""
    from fgloc.survey.coded_views import needs_second_recording

    return needs_second_recording({"refused": [r for r in record.get("refused", [])
                                               if not str(r.get("reason", "")).startswith(NO_CANDIDATE)]})
