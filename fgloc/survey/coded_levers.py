"""The coded survey's levers (docs/blink-codes.md "Survey integration"): how they are chosen,
and the predicted fallback.

rig.json ``"coded"`` (optional) and ``fgloc survey --coded KEY=VALUE`` choose them
(:func:`coded_settings`; defaults: the survey as it was before the levers):

* ``retry``: ``"burst"`` | ``"continue"`` (a retry goes on recording L frames, sliding windows);
* ``separate``: ``"zoom"`` | ``"radio"`` (crowded motes paused by colour class first,
  :mod:`fgloc.survey.coded_separation`);
* ``fallback``: ``"blobs"`` | ``"predicted"`` (:func:`predicted_directions`, :func:`blobs_near`);
* ``video``: ``"frames"`` | ``"fields"`` (interlaced fields at 59.94 Hz);
* ``probe``: ``"off"`` | ``"on"`` (a view whose first L + 2 frames show no blob stops there);
* ``pairs``: ``"off"`` | ``"on"`` (refused blobs decoded as two LEDs, :mod:`fgloc.camera.blink_pairs`);
* ``levels``: the refinement zoom ladder, ascending fractions of the optical range.

Angles radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.files.rig_config import RigConfig
from fgloc.survey.coded_views import distinct_directions

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSettings, CodedSurvey
    from fgloc.survey.runner import SurveyRunner

RETRY_MODES = ("burst", "continue")
SEPARATE_MODES = ("zoom", "radio")
FALLBACK_MODES = ("blobs", "predicted")
VIDEO_MODES = ("frames", "fields")
PROBE_MODES = ("off", "on")
PAIRS_MODES = ("off", "on")
CHOICES = {"retry": RETRY_MODES, "separate": SEPARATE_MODES, "fallback": FALLBACK_MODES, "video": VIDEO_MODES,
           "probe": PROBE_MODES, "pairs": PAIRS_MODES}
PREDICTED_RADIUS = math.radians(3.0)  #: a blob this close to a mote's predicted direction may hide it


def coded_settings(rig: RigConfig, overrides: Mapping[str, str] | None = None) -> CodedSettings:
    """The rig's coded-survey levers: rig.json ``"coded": {"retry": ..., "separate": ...,
    "fallback": ..., "video": ..., "probe": ..., "pairs": ..., "levels": [zoom, ...]}`` (each optional; defaults of
    :class:`~fgloc.survey.coded.CodedSettings`), each overridden by ``overrides`` (the CLI's
    ``--coded KEY=VALUE``). One-line :class:`FglocError` naming the file or flag on a bad value."""
    from fgloc.survey.coded import CodedSettings

    raw = rig.raw.get("coded", {}) if isinstance(rig.raw, dict) else {}
    if not isinstance(raw, dict):
        raise FglocError(f"{rig.path}: coded: expected an object, got {raw!r}")
    out = CodedSettings()
    unknown_flags = sorted(set(overrides or {}) - set(CHOICES))
    if unknown_flags:
        raise FglocError(f"--coded: {unknown_flags[0]}: unknown lever (expected one of {', '.join(CHOICES)})")
    unknown_keys = sorted(set(raw) - set(CHOICES) - {"levels"})
    if unknown_keys:  # a misspelled lever would otherwise be silently left at its default
        raise FglocError(f"{rig.path}: coded.{unknown_keys[0]}: unknown lever "
                         f"(expected one of {', '.join(CHOICES)}, levels)")
    for key, allowed in CHOICES.items():
        flag = (overrides or {}).get(key)
        value: Any = flag if flag is not None else raw.get(key, getattr(out, key))
        if value not in allowed:
            where = f"--coded: {key}" if flag is not None else f"{rig.path}: coded.{key}"
            raise FglocError(f"{where}: expected one of {', '.join(allowed)}, got {value!r}")
        out = replace(out, **{key: value})
    levels = raw.get("levels", out.levels)
    if not (isinstance(levels, (list, tuple)) and levels and all(
            isinstance(z, (int, float)) and not isinstance(z, bool) and 0 < z <= 1 for z in levels)
            and list(levels) == sorted(set(levels))):
        raise FglocError(f"{rig.path}: coded.levels: expected ascending zooms in (0, 1] (fractions of the "
                         f"optical range), got {levels!r}")
    return replace(out, levels=tuple(float(z) for z in levels))


def predicted_directions(runner: SurveyRunner) -> dict[str, dict[str, tuple[float, float]]] | None:
    """Every mote's predicted direction per camera from the journaled views' readings alone
    (the same on a resume; :func:`~fgloc.survey.coded_separation.predict_directions`), None
    when they do not solve."""
    from fgloc.files.journal import journal_to_survey
    from fgloc.survey.coded_separation import predict_directions, wide_survey

    st = runner.state
    with runner._state_lock:
        base = journal_to_survey(st)
    return predict_directions(wide_survey(base, [r for _, r in sorted(st.views.items())]))


def blobs_near(coded: CodedSurvey, camera: str, at: tuple[float, float]) -> list[tuple[float, float]]:
    """The camera's unexplained blob directions within :data:`PREDICTED_RADIUS` of ``at``
    (thinned to looks a quarter field of view apart, as the fallback's looks)."""
    pts = coded.final_blobs.get(camera, np.zeros((0, 2)))
    if not len(pts):
        return []
    cos = pan_tilt_bearing(pts[:, 0], pts[:, 1]) @ pan_tilt_bearing(*at)
    k = coded.intrinsics_at(camera, coded.survey_zoom[camera])
    fov = 2 * math.atan(min(k.width / (2 * k.fx), k.height / (2 * k.fy)))
    return distinct_directions(pts[cos >= math.cos(PREDICTED_RADIUS)], 0.25 * fov)
