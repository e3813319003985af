"""The coded survey's levers (docs/blink-codes.md "Survey integration"): how they are chosen,
remembered by the journal, and the predicted fallback.

rig.json ``"coded"`` (optional) and ``fgloc survey --coded KEY=VALUE`` choose them
(:func:`coded_settings`; a new survey's defaults are :class:`~fgloc.survey.coded_settings.CodedSettings`'s,
the measured fastest free of mislabels and misses: continue, round (fallback), probe on, pairs groups, short
view-major rounds, ladder focus, decode fit, length adaptive, explain crowds, looks epipolar, searches paired,
covers searched, first window kept, zoom moves together, retries in the wide pass only, zoom ladder 3x, 6x then 10x):

* ``retry``: ``"burst"`` | ``"continue"`` (a retry goes on recording L frames, sliding windows);
* ``separate``: ``"zoom"`` | ``"radio"`` (crowded motes paused by colour class first,
  :mod:`fgloc.survey.coded_separation`);
* ``fallback``: ``"blobs"`` | ``"predicted"`` (:func:`predicted_directions`, :func:`blobs_near`) | ``"round"``
  (first the motes it would search blink alone, :mod:`fgloc.survey.coded_fallback_round`);
* ``video``: ``"frames"`` | ``"fields"`` (interlaced fields at 59.94 Hz);
* ``probe``: ``"off"`` | ``"on"`` (a view whose first L + 2 frames show no blob stops there);
* ``pairs``: ``"off"`` | ``"on"`` (refused blobs decoded as two LEDs, :mod:`fgloc.camera.blink_pairs`)
  | ``"groups"`` (and a refused pair as three, :mod:`fgloc.camera.blink_groups`);
* ``rounds``: ``"short"`` | ``"full"`` (radio rounds record L + 2 samples labelled against the
  round's candidates, :mod:`fgloc.survey.coded_rounds`);
* ``round_order``: ``"view"`` | ``"class"`` (radio rounds class by class with a barrier each,
  or view by view cycling the classes, :mod:`fgloc.survey.coded_view_major`);
* ``ladder``: ``"climb"`` | ``"focus"`` (a refinement rung hands on only unread blobs near what it
  chased, lamps to the fallback, :mod:`fgloc.survey.coded_ladder`);
* ``decode``: ``"levels"`` | ``"fit"`` (a blob the level decoder refuses gets the light-curve
  fit, :mod:`fgloc.camera.blink_word_fit`);
* ``length``: ``"fixed"`` | ``"adaptive"`` (a first recording stops at 2L + 2 samples when it leaves
  no blob unexplained, :func:`fgloc.survey.coded_recording.record_adaptive`);
* ``explain``: ``"readings"`` | ``"views"`` (ladder focus: a blob whose neighbourhood another
  recording of the camera read cleanly is explained too, :func:`~fgloc.survey.coded_ladder.resolved_elsewhere`)
  | ``"crowds"`` (and a wide-pass blob where another recording read a crowd apart, cleanly);
* ``looks``: ``"disk"`` | ``"epipolar"`` (the fallback searches a mote another camera read only at
  blobs near the epipolar plane of that reading, :mod:`fgloc.survey.coded_epipolar`);
* ``searches``: ``"one"`` | ``"paired"`` (the fallback's one-camera searches of different cameras
  lit and searched together, one node per camera, :mod:`fgloc.survey.coded_paired`);
* ``covers``: ``"placed"`` | ``"searched"`` (fallback round: a camera's round views cover only the
  motes the fallback would search, :mod:`fgloc.survey.coded_fallback_round`);
* ``first_window``: ``"dropped"`` | ``"kept"`` (``length "adaptive"``: a recording that goes on to
  3L + 2 keeps the readings of its first 2L + 2 frames the whole decode lacks,
  :func:`fgloc.survey.coded_recording.record_adaptive`);
* ``zoom_moves``: ``"apart"`` | ``"together"`` (a zoom to a new rung, or back to the survey zoom,
  runs during the move to the rung's first view on a head that can: the EVI-D100's two VISCA
  sockets, :meth:`fgloc.survey.coded.CodedSurvey.zooms_while_moving`);
* ``retries_at``: ``"all"`` | ``"first_rung"`` (only the wide pass, the radio rounds and the first
  refinement rung's tiles are recorded a second time, :func:`fgloc.survey.coded_ladder.may_record_again`)
  | ``"wide"`` (only the wide pass and the radio rounds);
* ``levels``: the refinement zoom ladder, ascending fractions of the optical range (default
  ``[2/9, 5/9, 1]``: 3x, 6x, then 10x; ``[2/9, 1]`` before stop 39, which journals recorded).

**Resume rule.** A coded survey's journal header records the levers it started with
(:func:`settings_record`, header ``coded``). A resume runs with the recorded levers; a rig.json
value or ``--coded`` flag that names a lever with another value is refused in one line (the
flag or file, the lever, both values), never mixed in. A journal without recorded levers
(written before they were recorded, or started as a sequential survey) resumes with
:data:`LEGACY` (the defaults before this rule) overridden by rig.json and the flags, exactly as
it resumed before. A lever added after a journal was written (``rounds``, ``round_order``, ``ladder``, ``decode``, ``length``, ``explain``, ``looks``, ``searches``, ``covers``, ``first_window``, ``zoom_moves``, ``retries_at``, ``tiling``) and
so missing from its recorded levers resumes with its :data:`LEGACY` value, the only one the
survey that wrote it knew; a journal without a recorded ladder climbs :data:`LEGACY_LEVELS`.

Angles radians.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.files.journal import JournalState
from fgloc.files.rig_config import RigConfig
from fgloc.survey.coded_epipolar import LOOKS_MODES, half_separation, within_band
from fgloc.survey.coded_ladder import EXPLAIN_MODES, LADDER_MODES, RETRIES_AT_MODES, SEPARATION_PX
from fgloc.survey.coded_settings import CodedSettings
from fgloc.survey.coded_views import distinct_directions

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.coded_separation import Prediction
    from fgloc.survey.runner import SurveyRunner

logger = logging.getLogger(__name__)

RETRY_MODES = ("burst", "continue")
SEPARATE_MODES = ("zoom", "radio")
FALLBACK_MODES = ("blobs", "predicted", "round")
VIDEO_MODES = ("frames", "fields")
PROBE_MODES = ("off", "on")
PAIRS_MODES = ("off", "on", "groups")
ROUNDS_MODES = ("full", "short")
ROUND_ORDERS = ("class", "view")
DECODE_MODES = ("levels", "fit")
LENGTH_MODES = ("fixed", "adaptive")
SEARCHES_MODES = ("one", "paired")
COVERS_MODES = ("placed", "searched")
FIRST_WINDOW_MODES = ("dropped", "kept")
ZOOM_MOVES_MODES = ("apart", "together")
TILING_MODES = ("greedy", "minimal")
CHOICES = {"retry": RETRY_MODES, "separate": SEPARATE_MODES, "fallback": FALLBACK_MODES, "video": VIDEO_MODES,
           "probe": PROBE_MODES, "pairs": PAIRS_MODES, "rounds": ROUNDS_MODES, "round_order": ROUND_ORDERS,
           "ladder": LADDER_MODES, "decode": DECODE_MODES, "length": LENGTH_MODES, "explain": EXPLAIN_MODES,
           "looks": LOOKS_MODES, "searches": SEARCHES_MODES, "covers": COVERS_MODES,
           "first_window": FIRST_WINDOW_MODES, "zoom_moves": ZOOM_MOVES_MODES, "retries_at": RETRIES_AT_MODES,
           "tiling": TILING_MODES}
#: the defaults before the journal recorded the levers: a journal without recorded levers resumes with these,
#: and a lever a journal's header does not record (added after it was written) resumes with its value here
LEGACY: dict[str, Any] = {"retry": "burst", "separate": "zoom", "fallback": "blobs", "video": "frames", "probe": "off",
                          "pairs": "off", "rounds": "full", "round_order": "class", "ladder": "climb",
                          "decode": "levels", "length": "fixed", "explain": "readings",
                          "looks": "disk", "searches": "one", "covers": "placed",
                          "first_window": "dropped", "zoom_moves": "apart", "retries_at": "all",
                          "tiling": "greedy"}
#: the zoom ladder of journals that recorded none (the default before ``(2/9, 1)``)
LEGACY_LEVELS: tuple[float, ...] = (1 / 9, 3 / 9, 1.0)
PREDICTED_RADIUS = math.radians(3.0)  #: a blob this close to a mote's predicted direction may hide it


def _show(value: Any) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def settings_record(settings: CodedSettings) -> dict[str, Any]:
    """The levers of ``settings`` as the journal header records them (JSON values)."""
    return {key: getattr(settings, key) for key in CHOICES} | {"levels": [float(z) for z in settings.levels]}


def coded_settings(rig: RigConfig, overrides: Mapping[str, str] | None = None,
                   journal: JournalState | None = None, journal_path: str | os.PathLike[str] = "journal") -> CodedSettings:
    """The coded-survey levers: rig.json ``"coded": {"retry": ..., "separate": ..., "fallback": ...,
    "video": ..., "probe": ..., "pairs": ..., "rounds": ..., "round_order": ..., "levels": [zoom, ...]}`` (each optional), each
    overridden by ``overrides`` (the CLI's ``--coded KEY=VALUE``), over the base levers:
    :class:`~fgloc.survey.coded_settings.CodedSettings`'s defaults for a new survey (``journal`` None);
    for a resumed ``journal`` its header's recorded levers (a file or flag value that differs:
    one-line :class:`FglocError`), or :data:`LEGACY` when it recorded none (module docstring,
    "Resume rule"). One-line :class:`FglocError` naming the file or flag on a bad value."""

    raw = rig.raw.get("coded", {}) if isinstance(rig.raw, dict) else {}
    if not isinstance(raw, dict):
        raise FglocError(f"{rig.path}: coded: expected an object, got {raw!r}")
    unknown_flags = sorted(set(overrides or {}) - set(CHOICES))
    if unknown_flags:
        raise FglocError(f"--coded: {unknown_flags[0]}: unknown lever (expected one of {', '.join(CHOICES)})")
    unknown_keys = sorted(set(raw) - set(CHOICES) - {"levels"})
    if unknown_keys:  # a misspelled lever would otherwise be silently left at its default
        raise FglocError(f"{rig.path}: coded.{unknown_keys[0]}: unknown lever "
                         f"(expected one of {', '.join(CHOICES)}, levels)")
    explicit: dict[str, tuple[str, Any]] = {}  # lever -> (where it was set, value)
    for key, allowed in CHOICES.items():
        flag = (overrides or {}).get(key)
        if flag is None and key not in raw:
            continue
        where = f"--coded: {key}" if flag is not None else f"{rig.path}: coded.{key}"
        value: Any = flag if flag is not None else raw[key]
        if value not in allowed:
            raise FglocError(f"{where}: expected one of {', '.join(allowed)}, got {value!r}")
        explicit[key] = (where, value)
    if "levels" in raw:
        levels = raw["levels"]
        if not (isinstance(levels, (list, tuple)) and levels and all(
                isinstance(z, (int, float)) and not isinstance(z, bool) and 0 < z <= 1 for z in levels)
                and list(levels) == sorted(set(levels))):
            raise FglocError(f"{rig.path}: coded.levels: expected ascending zooms in (0, 1] (fractions of the "
                             f"optical range), got {levels!r}")
        explicit["levels"] = (f"{rig.path}: coded.levels", tuple(float(z) for z in levels))
    recorded = None if journal is None else journal.header.coded
    if recorded is not None:  # the levers the survey started with, whatever the defaults are now
        base = replace(CodedSettings(), **{k: recorded.get(k, LEGACY[k]) for k in CHOICES})
        base = replace(base, levels=tuple(float(z) for z in recorded.get("levels", LEGACY_LEVELS)))
        for key, (where, value) in explicit.items():
            if value != getattr(base, key):
                raise FglocError(f"{where}: {journal_path} was started with {key} {_show(getattr(base, key))}, "
                                 f"got {_show(value)} (a resume runs with the journal's levers: drop or "
                                 "match it, or survey into a new directory)")
        return base
    base = replace(CodedSettings(), **LEGACY, levels=LEGACY_LEVELS) if journal is not None else CodedSettings()
    return replace(base, **{key: value for key, (_, value) in explicit.items()})


def wide_prediction(runner: SurveyRunner) -> Prediction | None:
    """Every mote's predicted direction per camera, and the epipolar bands of the motes one
    camera read, from the journaled views' readings alone (the same on a resume;
    :func:`~fgloc.survey.coded_separation.predict`), None when they do not solve."""
    from fgloc.files.journal import journal_to_survey
    from fgloc.survey.coded_separation import predict, wide_survey

    st = runner.state
    with runner._state_lock:
        base = journal_to_survey(st)
    return predict(wide_survey(base, [r for _, r in sorted(st.views.items())]))


def take_bands(coded: CodedSurvey, prediction: Prediction) -> dict[str, dict[str, tuple[float, float]]]:
    """Keep ``prediction``'s epipolar bands and scale on ``coded`` for :func:`blobs_near`;
    returns its directions."""
    coded.bands, coded.across_scale = prediction.bands, prediction.across_scale
    if coded.settings.looks == "epipolar":
        scale = "unmeasured (too few motes read by two cameras): the disk alone" if prediction.across_scale is None \
            else f"{math.degrees(prediction.across_scale):.2f} deg x max(gain, 1), measured on the motes two cameras read"
        logger.info(f"fallback looks: near the epipolar plane of each mote one camera read; band {scale}")
    return prediction.directions


def banded(coded: CodedSurvey, camera: str, node: str) -> bool:
    """Whether ``camera`` looks for ``node`` only inside its epipolar band (:func:`blobs_near`):
    ``looks "epipolar"``, one other camera read it, and the band's scale was measured."""
    return (coded.settings.looks == "epipolar" and coded.across_scale is not None
            and node in coded.bands.get(camera, {}))


def blobs_near(coded: CodedSurvey, camera: str, at: tuple[float, float], node: str | None = None
               ) -> list[tuple[float, float]]:
    """The camera's unexplained blob directions within :data:`PREDICTED_RADIUS` of ``at``
    (thinned to looks a quarter field of view apart, as the fallback's looks); with ``looks
    "epipolar"``, of a ``node`` one other camera read, only those within its epipolar band
    (:func:`~fgloc.survey.coded_epipolar.within_band`, ``CodedSurvey.bands``)."""
    pts = coded.final_blobs.get(camera, np.zeros((0, 2)))
    if not len(pts):
        return []
    cos = pan_tilt_bearing(pts[:, 0], pts[:, 1]) @ pan_tilt_bearing(*at)
    k = coded.intrinsics_at(camera, coded.survey_zoom[camera])
    fov = 2 * math.atan(min(k.width / (2 * k.fx), k.height / (2 * k.fy)))
    keep = cos >= math.cos(PREDICTED_RADIUS)
    if node is not None and banded(coded, camera, node) and coded.across_scale is not None:
        # the decoder's pixels: in fields a row spans twice the angle of a column, and a mote
        # merged into a blob may lie half the separation off its centroid along either axis
        keep &= within_band(pts, coded.bands[camera][node], coded.across_scale,
                            half_separation(SEPARATION_PX, min(k.fx, k.fy)))
    return distinct_directions(pts[keep], 0.25 * fov)
