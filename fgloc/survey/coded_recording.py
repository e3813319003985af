"""One recording of one view of the coded survey: grab, probe, decode, and its journal record.

:func:`record_view` records ``3L + 2`` frames (fields) of a view (or, with the probe,
``L + 2`` first and stops there when they show no blob; or, continuing an earlier
recording, ``L`` more decoded with it in sliding windows; or, a short radio round's view,
``L + 2`` labelled against the round's candidates, :mod:`fgloc.survey.coded_rounds`), decodes them
(:func:`fgloc.camera.blink_decoder.decode_view` / :func:`~fgloc.camera.blink_decoder.decode_windows`,
pairs with :mod:`fgloc.camera.blink_pairs` when the lever is on) and turns each decoded LED
into a reading (:func:`fgloc.survey.coded_views.coded_observation`). The caller
(:meth:`fgloc.survey.coded.CodedSurvey._visit`) journals the record and prices the frames.
Angles radians; pixels OpenCV convention; times survey-clock seconds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.camera.blink_candidates import CandidateDecode
from fgloc.camera.blink_decoder import (
    ViewDecode,
    decode_view,
    decode_windows,
    supplement_decode,
    unsampled_positions,
)
from fgloc.camera.blink_pairs import PairConfig
from fgloc.survey.coded_ladder import codes_read_before
from fgloc.survey.coded_rounds import RoundCandidates, decode_round, round_frames
from fgloc.survey.coded_views import coded_observation, empty_view, reading_centroid, unexplained_blob
from fgloc.survey.runner import SurveyRunner

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey

Frame = tuple[float, np.ndarray]
logger = logging.getLogger(__name__)


def grab_frames(coded: CodedSurvey, runner: SurveyRunner, camera: str, count: int, t_start: float, key: str) -> list[Frame]:
    """``count`` consecutive frames (fields) from ``t_start`` on the survey clock: the simulated
    rigs' ``record_blinks`` (seeded by ``key``), on hardware grabs stamped by the host clock."""
    if coded.recorder is not None:
        out: list[Frame] = (coded.recorder(camera, count, t_start, key, fields=True) if coded.fields
                            else coded.recorder(camera, count, t_start, key))
        return out
    frames = []
    for _ in range(count):
        img = runner.workers[camera].call(lambda h: h.grab_frame())
        frames.append((time.monotonic(), np.asarray(img)))
    return frames


def record_view(coded: CodedSurvey, runner: SurveyRunner, camera: str, vid: str, attempt: int, target: tuple[float, float],
            head: tuple[float, float], zoom: float, t_start: float,
            before: list[Frame] | None = None,
            candidates: RoundCandidates | None = None) -> tuple[dict[str, Any], list[Frame]]:
    """Record and decode one recording of a view; returns its journal record and the view's
    frames so far. ``before``: this process's frames of the view's earlier recordings, which
    this one continues (L more frames from where they ended, decoded with them in sliding
    windows); None: a new burst of 3L + 2. ``candidates``: a short round view
    (:mod:`fgloc.survey.coded_rounds`): a burst of L + 2 (no probe), every recording so far
    labelled against them."""
    key = f"{vid}/{attempt}"
    short = candidates is not None
    count = coded.book.length if before else (round_frames(coded) if short else coded.frames)
    if before:  # the recording goes on: the next frame period after the last one
        t_start = coded._continue_at[(camera, vid)]
    intr = coded.intrinsics_at(camera, zoom)
    probed = False
    pairs = {"on": PairConfig(), "groups": PairConfig(max_group=3)}.get(coded.settings.pairs)
    elsewhere = codes_read_before(runner.state.views, camera, vid, attempt)
    dec: ViewDecode | CandidateDecode | None = None
    early: dict[int, int] = {}  # code -> frames of the first window whose decode added its reading
    if not before and not short and coded.settings.probe == "on":
        # the first L + 2 frames show every blinking mote on and off (each word has both bits in
        # any L samples): a view where they show no blob at all is empty, and the recording stops
        count = coded.book.length + 2
        frames = grab_frames(coded, runner, camera, count, t_start, key)
        probed = True
        if not empty_view(frames, coded.camera.frame_period_s, coded.settings.view_decoder()):  # on to 3L + 2
            if coded.settings.length == "adaptive":
                frames, dec, count, early = record_adaptive(coded, runner, camera, head, zoom, t_start, frames, key,
                                                            pairs, elsewhere)
            else:
                frames += grab_frames(coded, runner, camera, coded.frames - count,
                                      t_start + count * coded.camera.frame_period_s, key + "+")
                count = coded.frames
    elif not before and not short and coded.settings.length == "adaptive":
        frames, dec, count, early = record_adaptive(coded, runner, camera, head, zoom, t_start, [], key, pairs,
                                                    elsewhere)
    else:
        frames = grab_frames(coded, runner, camera, count, t_start, key)
    coded._continue_at[(camera, vid)] = t_start + count * coded.camera.frame_period_s
    stopped = dec is not None and count < coded.frames  # decoded by record_adaptive
    if dec is None and short:
        frames = (before or []) + frames
        dec = decode_round(coded, frames, intr, head, candidates or [])
    elif dec is None and before:
        frames = before + frames
        dec = decode_windows(frames, coded.camera.frame_period_s, coded.book, intr, head[0], head[1],
                             coded.frames, coded.book.length, coded.settings.view_decoder(), pairs=pairs,
                             elsewhere=elsewhere)
    elif dec is None:
        dec = decode_view(frames, coded.camera.frame_period_s, coded.book, intr, head[0], head[1],
                          coded.settings.view_decoder(), pairs=pairs, elsewhere=elsewhere)
    check_steady_loss(coded, camera, vid, frames)
    readings, refused = [], [{"kind": r.kind, "u": r.u, "v": r.v, "reason": r.reason} for r in dec.refused]
    st = runner.state
    taken: set[str] = set()
    stack = np.stack([np.asarray(f) for _, f in frames]) if dec.readings else np.zeros((0, 0, 0))
    for rd in dec.readings:
        node = coded.node_of_code.get(rd.index)
        if node is None:
            refused.append({"kind": "unassigned", "u": rd.u, "v": rd.v,
                            "reason": f"code {rd.index} is run by no mote of this survey"})
            continue
        have = len(st.observations_of(node, camera))
        if node in taken or have >= coded.rig.repeats:
            continue
        taken.add(node)
        uv = reading_centroid(stack, rd.u, rd.v, rd.partner, early.get(rd.index))
        obs = coded_observation(camera, vid, node, have, rd, intr, head, uv, coded.rig.sigma,
                                coded.rig.head_repeatability)
        readings.append({"node": node, "index": obs.index, "pan": obs.pan, "tilt": obs.tilt, "code": rd.index,
                         "u": uv[0], "v": uv[1]} | ({} if rd.partner is None else {"partner": rd.partner})
                        | ({} if obs.view_sigma is None else {"sigma": obs.sigma, "view_sigma": obs.view_sigma}))
    return {"camera": camera, "view": vid, "attempt": attempt, "target": list(target), "head": list(head),
            "zoom": zoom, "frames": count, "erased": dec.erased, "clock_s": t_start, "readings": readings,
            "refused": refused} | ({"continued": True} if before else {}) | ({"stopped": True} if stopped else {}) | (
                {"probe": coded.book.length + 2} if probed else {}) | (
                {"candidates": [n for n, _ in candidates or []]} if short else {}), frames


def record_adaptive(coded: CodedSurvey, runner: SurveyRunner, camera: str, head: tuple[float, float], zoom: float,
                    t_start: float, frames: list[Frame], key: str, pairs: PairConfig | None,
                    elsewhere: Mapping[int, np.ndarray] | None = None
                    ) -> tuple[list[Frame], ViewDecode, int, dict[int, int]]:
    """Lever ``length: adaptive``: record (on from ``frames``, the probe's L + 2, if any) to
    2L + 2 frame periods and decode them; stop there when the decode leaves no blob unexplained
    (:func:`~fgloc.survey.coded_views.unexplained_blob`: every blob read, or at the image
    border), else go on to 3L + 2 as one recording and decode it whole. Returns (frames,
    decode, frame periods recorded, code -> frames of the first 2L + 2 periods for each reading
    their decode added). Not the second recording's looser rule (a blob at a mote
    the camera has read): in a crowded far field that mote may be a neighbour, and a wide view
    so stopped lost 14 visible pairs of 1885 at 1000 motes. The simulated rigs render the
    recording a fixed length would (same keys and counts) and hand out its first 2L + 2
    periods, so a view that goes on shows the frames it would have. With ``first_window "kept"``
    the readings of the first 2L + 2 periods' decode that the whole decode lacks are added
    (:func:`~fgloc.camera.blink_decoder.supplement_decode`: codes it neither read nor refused as
    duplicate, more than 2 px from its readings): light late in the recording (a neighbour's
    in a crowd, a glint) spoils some blobs the first periods read, so an added reading's
    centroid is taken over those periods too (:func:`~fgloc.survey.coded_views.reading_centroid`).
    (Merging the two decodes
    by the sliding windows' rules instead, which refuse a code read in both more than 1 px
    apart, was slower in the two 1000-mote scenes tried: docs/blink-codes.md.)"""
    length, period = coded.book.length, coded.camera.frame_period_s
    short_count = 2 * length + 2
    have = length + 2 if frames else 0
    tail_key = key + ("+" if frames else "")
    later: list[Frame] = []
    if coded.recorder is not None:
        rest = grab_frames(coded, runner, camera, coded.frames - have, t_start + have * period, tail_key)
        cut = t_start + (short_count - 0.5) * period
        frames = frames + [f for f in rest if f[0] < cut]
        later = [f for f in rest if f[0] >= cut]
    else:
        frames = frames + grab_frames(coded, runner, camera, short_count - have, t_start + have * period, tail_key)
    intr = coded.intrinsics_at(camera, zoom)
    dec = decode_view(frames, period, coded.book, intr, head[0], head[1], coded.settings.view_decoder(), pairs=pairs,
                      elsewhere=elsewhere)
    refused = [{"kind": r.kind, "u": r.u, "v": r.v, "reason": r.reason} for r in dec.refused]
    if not any(unexplained_blob(r) for r in refused):
        return frames, dec, short_count, {}
    if coded.recorder is None:
        later = grab_frames(coded, runner, camera, coded.frames - short_count, t_start + short_count * period,
                            key + "++")
    first_frames = len(frames)
    frames = frames + later
    whole = decode_view(frames, period, coded.book, intr, head[0], head[1], coded.settings.view_decoder(), pairs=pairs,
                        elsewhere=elsewhere)
    early: dict[int, int] = {}
    if coded.settings.first_window == "kept":  # the first 2L + 2 read motes the whole recording may refuse
        read = {r.index for r in whole.readings}
        whole = supplement_decode(whole, dec)
        early = {r.index: first_frames for r in whole.readings if r.index not in read}
    return frames, whole, coded.frames, early


def check_steady_loss(coded: CodedSurvey, camera: str, vid: str, frames: list[Frame]) -> None:
    """Count, and warn once per camera, a recording of at least ``2L`` frame periods that left
    half the bit positions or more without a sample (:func:`unsampled_positions`): frames are
    lost at a steady rate, as by a camera fallen from 60 to 30 Hz, and an even-length word is
    then never read (docs/blink-codes.md, "Video faults"). Random drops leave none."""
    length, period = coded.book.length, coded.camera.frame_period_s
    if len(frames) < 2 or frames[-1][0] - frames[0][0] < (2 * length - 1.5) * period:
        return
    idx = np.rint((np.array([t for t, _ in frames]) - frames[0][0]) / period).astype(np.int64)
    gap = unsampled_positions(idx, length)
    if 2 * gap < length:
        return
    coded.stats.rate_fall_views += 1
    if camera not in coded.stats.rate_fall_cameras:
        coded.stats.rate_fall_cameras.append(camera)
        logger.warning(f"{camera} view {vid}: {gap} of the {length} bit positions got no frame: frames are lost at a "
                       f"steady rate (a camera at half its frame rate?); its motes cannot be read and go to retries "
                       f"and the fallback. Check the camera's video rate")
