"""Radio separation for the coded survey: which motes crowd which blobs, and their colour classes.

After every camera's wide pass (:mod:`fgloc.survey.coded`, ``separate: "radio"``), the
blobs no reading explains (ambiguous, duplicate, ...) hide motes that blink too close
together at the wide zoom. Instead of zooming in, the survey splits them in time: the
base station pauses every mote but one colour class (pause by bitmap,
:class:`~fgloc.drivers.tinyos.blink.BlinkPause`), each camera records again, at the wide
zoom, the views holding that class's crowded motes, and so on for each class.

**Which motes are crowded** is not in the blob (its codes were not read). It comes from
the geometry the wide pass already measured (:func:`predict_directions`):

1. the wide-pass readings alone are solved jointly (:func:`fgloc.solve.joint.solve_survey`:
   camera poses, gauge frame);
2. a mote camera ``c`` did not read is placed where another camera's reading of it meets
   the ground plane z = 0 (planar surveys; the solve's position when it has one);
3. its direction from ``c`` then says in which of ``c``'s unexplained blobs it lies
   (:func:`crowded_motes`: within ``radius_px`` of the blob, pixels of the wide zoom).

Motes predicted near each other (``conflict_px``) in some camera's blob conflict; the
conflict graph is coloured (:func:`fgloc.survey.view_planner.colour_conflicts`, global:
a pause darkens a mote for every camera). A mote no camera read cannot be placed: it is
in no class, stays paused during the rounds, and is left to the zoom refinement and the
sequential fallback (never guessed). The plan is a function of the journaled wide views
only, so a resumed survey re-plans the same rounds.

After the rounds a wide blob counts as explained only when the rounds read every crowded
mote predicted at it and no mote the camera has still not read is predicted within the
fallback's radius of it (:func:`sort_wide_blobs`): a mote one camera read is placed by one
bearing and can be predicted a degree off, outside every class, and is then searched by the
fallback at that blob instead of being journaled not found.

Angles radians; pixels OpenCV convention; positions gauge frame (baseline units).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pan_tilt_to_pixel
from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing, world_to_base
from fgloc.core.model import NodeMode, Observation, Survey
from fgloc.survey.coded_epipolar import EpipolarBand, across_scale, one_camera_bands
from fgloc.survey.coded_rounds import RoundCandidates, round_candidates
from fgloc.survey.view_planner import colour_conflicts

if TYPE_CHECKING:
    from fgloc.survey.coded import Blob, CodedSurvey
    from fgloc.survey.runner import SurveyRunner

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SeparationPlan:
    """Colour classes of the crowded motes and, per camera, the motes it must read in rounds."""

    colour: dict[str, int]  #: node -> colour class (crowded motes only)
    crowded: dict[str, dict[str, tuple[float, float]]]  #: camera -> node -> predicted (pan, tilt)
    unplaced: dict[str, set[str]]  #: camera -> motes it did not read whose direction is unknown
    #: camera -> node -> predicted (pan, tilt) of every placed node (short rounds' candidates)
    predicted: Mapping[str, Mapping[str, tuple[float, float]]] = field(default_factory=dict)
    #: camera -> motes it did not read in the wide pass (silent motes excluded), placed or not
    unread: Mapping[str, set[str]] = field(default_factory=dict)

    @property
    def classes(self) -> int:
        return max(self.colour.values(), default=-1) + 1


def wide_survey(base: Survey, records: Sequence[Mapping[str, Any]]) -> Survey:
    """``base`` (ids, gauge, sigma) with only the readings of ``records`` (journaled view records)."""
    obs = [Observation(str(r["camera"]), str(rd["node"]), float(rd["pan"]), float(rd["tilt"]), rd.get("sigma"))
           for r in records for rd in r["readings"]]
    return Survey(base.mode, base.gauge, base.sigma, list(base.camera_ids), list(base.node_ids), obs)


@dataclass(frozen=True)
class Prediction:
    """The wide-pass geometry of :func:`predict`."""

    #: camera -> node -> predicted (pan, tilt) of every node some camera read
    directions: dict[str, dict[str, tuple[float, float]]]
    #: camera -> node read by one other camera only -> where it can lie (:mod:`fgloc.survey.coded_epipolar`)
    bands: dict[str, dict[str, EpipolarBand]]
    #: the bands' measured across scale (radians; :func:`~fgloc.survey.coded_epipolar.across_scale`), None: unmeasured
    across_scale: float | None


def predict_directions(survey: Survey) -> dict[str, dict[str, tuple[float, float]]] | None:
    """Per camera, the predicted (pan, tilt) of every node some camera read (see the module
    docstring); None when the readings do not solve (too few shared nodes) or the survey is not
    planar (a single bearing then places no node)."""
    got = predict(survey, bands=False)
    return None if got is None else got.directions


def predict(survey: Survey, bands: bool = True) -> Prediction | None:
    """:func:`predict_directions`, with (``bands``) the epipolar band of every node one camera
    read, seen from each other camera, and the bands' scale measured on the nodes two cameras
    read (without: no bands, no scale)."""
    from fgloc.solve.joint import solve_survey

    if survey.mode is not NodeMode.PLANAR:
        return None
    try:
        result = solve_survey(survey)
    except Exception as exc:  # noqa: BLE001 - separation is an optimisation; zoom refinement still runs
        logger.warning(f"radio separation: the wide-pass readings did not solve ({' '.join(str(exc).split())[:160]}); "
                       "crowded motes are refined by zoom")
        return None
    where: dict[str, np.ndarray] = {n: np.asarray(e.position, float) for n, e in result.nodes.items()}
    for o in survey.observations:  # nodes one camera read: its bearing meets the ground plane
        if o.node in where or o.camera not in result.cameras:
            continue
        pose = result.cameras[o.camera]
        d = np.asarray(pose.rotation, float) @ pan_tilt_bearing(o.pan, o.tilt)
        p = np.asarray(pose.position, float)
        if d[2] < -1e-9 and p[2] > 0:
            where[o.node] = p - (p[2] / d[2]) * d
    out: dict[str, dict[str, tuple[float, float]]] = {}
    names = sorted(where)
    pts = np.array([where[n] for n in names]).reshape(-1, 3)
    for cam, pose in result.cameras.items():
        pan, tilt = bearing_pan_tilt(world_to_base(pose.rotation, pose.position, pts))
        out[cam] = {n: (float(p), float(t)) for n, p, t in zip(names, np.atleast_1d(pan), np.atleast_1d(tilt))}
    if not bands:
        return Prediction(out, {}, None)
    readings: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for o in survey.observations:
        if o.camera in result.cameras:
            readings.setdefault((o.node, o.camera), []).append((o.pan, o.tilt))
    return Prediction(out, one_camera_bands(result.cameras, readings, where),
                      across_scale(result.cameras, readings, where))


def crowded_motes(intr: CameraIntrinsics, blob_views: Sequence[tuple[tuple[float, float], tuple[float, float]]],
                  predicted: Mapping[str, tuple[float, float]], radius_px: float) -> dict[str, tuple[float, float]]:
    """The motes of ``predicted`` (node -> (pan, tilt)) that lie within ``radius_px`` of an
    unexplained blob: ``blob_views`` holds each blob's pixel (u, v) and its view's head
    (pan, tilt), all at the wide zoom ``intr``."""
    if not predicted or not blob_views:
        return {}
    names = list(predicted)
    pt = np.array([predicted[n] for n in names])
    near = np.zeros(len(names), bool)
    for (u, v), (hp, ht) in blob_views:
        uv, front = pan_tilt_to_pixel(intr, pt[:, 0], pt[:, 1], hp, ht)
        near |= np.asarray(front, bool) & (np.hypot(uv[:, 0] - u, uv[:, 1] - v) <= radius_px)
    return {n: predicted[n] for n, k in zip(names, near) if k}


def plan_separation(intr: Mapping[str, CameraIntrinsics], blobs: Mapping[str, list[tuple[tuple[float, float],
                    tuple[float, float]]]], predicted: Mapping[str, Mapping[str, tuple[float, float]]],
                    unread: Mapping[str, set[str]], radius_px: float, conflict_px: float) -> SeparationPlan:
    """Colour classes for the crowded motes: per camera ``c``, the motes it did not read
    (``unread[c]``) predicted within ``radius_px`` of one of its unexplained blobs
    (``blobs[c]``: (u, v) and view head angles); two such motes predicted within
    ``conflict_px`` of each other in ``c`` conflict (an edge); one global colouring."""
    crowded: dict[str, dict[str, tuple[float, float]]] = {}
    unplaced: dict[str, set[str]] = {}
    for cam, todo in unread.items():
        pred = predicted.get(cam, {})
        crowded[cam] = crowded_motes(intr[cam], blobs.get(cam, []), {n: pred[n] for n in sorted(todo) if n in pred},
                                     radius_px)
        unplaced[cam] = {n for n in todo if n not in pred}
    nodes = sorted({n for c in crowded.values() for n in c})
    index = {n: k for k, n in enumerate(nodes)}
    edges: list[tuple[int, int]] = []
    for cam, motes in crowded.items():
        names = sorted(motes)
        if len(names) < 2:
            continue
        pt = np.array([motes[n] for n in names])
        dpan = np.remainder(pt[:, None, 0] - pt[None, :, 0] + math.pi, 2 * math.pi) - math.pi
        dx = dpan * np.cos(0.5 * (pt[:, None, 1] + pt[None, :, 1])) * intr[cam].fx
        dy = (pt[:, None, 1] - pt[None, :, 1]) * intr[cam].fy
        i, j = np.nonzero(np.triu(np.hypot(dx, dy) < conflict_px, k=1))
        edges += [(index[names[a]], index[names[b]]) for a, b in zip(i.tolist(), j.tolist())]
    colour = colour_conflicts(len(nodes), np.array(edges, dtype=int).reshape(-1, 2))
    # crowded motes in no conflict (their partner unplaced, or predicted apart) read in the first class
    return SeparationPlan({n: max(int(colour[index[n]]), 0) for n in nodes}, crowded, unplaced,
                          {c: dict(p) for c, p in predicted.items()}, {c: set(v) for c, v in unread.items()})


# ----- the rounds, run by the coded survey ------------------------------------------------------------------
RADIUS_PX = 6.0  #: a mote predicted this close (wide-zoom px) to an unexplained blob is crowded there
CONFLICT_PX = 8.0  #: two crowded motes predicted this close (wide-zoom px) must not blink in one round
PAUSE_REPEATS = 3  #: each pause update is broadcast this many times (no report confirms it)


def _records(state: Any, camera: str | None, prefix: str) -> list[dict[str, Any]]:
    """Journaled view records (all attempts) whose view id starts with ``prefix``."""
    return [r for (c, v, _), r in sorted(state.views.items()) if (camera is None or c == camera)
            and str(v).startswith(prefix)]


def run_separation(coded: CodedSurvey, runner: SurveyRunner, pool: ThreadPoolExecutor,
                   pump: Callable[[list[Future[None]]], None]) -> None:
    """Radio separation between the wide pass and the zoom refinement (module docstring):
    plan the classes from the journaled wide views, then per class pause every other mote,
    let each camera record the views holding its crowded motes of that class (at the wide
    zoom; one barrier per round), resume every mote, and refine by zoom what is left."""
    from fgloc.files.journal import journal_to_survey
    from fgloc.survey.coded_views import into_search_box
    from fgloc.survey.view_planner import plan_views

    cams = coded.rig.camera_ids
    st = runner.state
    coded.next_stage()  # the first pause waits for every camera's wide pass
    failed = {c: any(r is None for r in coded.wide_records[c]) for c in cams}
    plan: SeparationPlan | None = None
    if not any(failed.values()):
        with runner._state_lock:
            base = journal_to_survey(st)
        wide = _records(st, None, "w")
        predicted = predict_directions(wide_survey(base, wide))
        if predicted is not None:
            silent = set().union(*(set(r.get("silent", [])) for r in st.codes if r.get("action") == "start"))
            unread = {c: set(coded.rig.node_ids) - silent - {rd["node"] for r in _records(st, c, "w")
                                                             for rd in r["readings"]} for c in cams}
            blobs = {c: [(uv, head) for uv, head, _ in coded.unexplained(coded.wide_records[c])] for c in cams}
            intr = {c: coded.intrinsics_at(c, coded.survey_zoom[c]) for c in cams}
            plan = plan_separation(intr, blobs, predicted, unread, RADIUS_PX, CONFLICT_PX)
    before = coded.stages.total + coded.radio_s
    if plan is not None and plan.classes and coded.settings.round_order == "view":
        from fgloc.survey.coded_view_major import run_view_major

        logger.info(f"radio separation: {len(plan.colour)} crowded motes in {plan.classes} colour classes, "
                    "view-major")
        coded.stats.classes = plan.classes
        run_view_major(coded, runner, pool, pump, plan)
        coded.pause(set())  # every mote blinks again for the refinement
    elif plan is not None and plan.classes:
        logger.info(f"radio separation: {len(plan.colour)} crowded motes in {plan.classes} colour classes")
        coded.stats.classes = plan.classes
        for k in range(plan.classes):
            lit = sorted(n for n, col in plan.colour.items() if col == k)
            coded.pause(set(coded.addresses.values()) - {coded.addresses[n] for n in lit})
            futures = []
            for c in cams:
                mine = [plan.crowded[c][n] for n in sorted(plan.crowded[c]) if plan.colour[n] == k]
                if not mine:
                    continue
                s = coded.rig.search_for(c)
                views = [into_search_box(p, t, s.pan_min, s.pan_max, s.tilt_min, s.tilt_max) for p, t in plan_views(
                    coded.intrinsics_at(c, coded.survey_zoom[c]), np.array(mine), coded.settings.margin_px,
                    start=coded.here[c], tilt_limits=(s.tilt_min, s.tilt_max))]
                cands = round_candidates(lit, plan.predicted.get(c, {})) if coded.settings.rounds == "short" else None
                futures.append(pool.submit(_round, coded, runner, c, k, views, lit, cands))
            pump(futures)
            coded.next_stage()
        coded.pause(set())  # every mote blinks again for the refinement
    coded.stats.rounds_s = coded.stages.total + coded.radio_s - before
    futures = [pool.submit(_refine_after, coded, runner, c, plan, failed[c]) for c in cams]
    pump(futures)


def _round(coded: CodedSurvey, runner: SurveyRunner, camera: str, k: int, views: list[tuple[float, float]],
           lit: list[str], candidates: RoundCandidates | None) -> None:
    """One camera's views of round ``k`` (class-major; view ids ``s<k>-<j>``)."""
    zoom0 = coded.survey_zoom[camera]
    for j, target in enumerate(views):
        coded._visit(runner, camera, f"s{k}-{j:03d}", target, zoom0, coded.here[camera], {"round": k, "lit": lit},
                     candidates)
        coded.here[camera] = target
    coded.stats.views += len(views)
    coded.stats.round_views += len(views)


def _refine_after(coded: CodedSurvey, runner: SurveyRunner, camera: str, plan: SeparationPlan | None,
                  failed: bool) -> None:
    """Zoom refinement after the rounds: the wide pass's unexplained blobs the rounds did not
    explain (:func:`sort_wide_blobs`), plus what the rounds' own recordings left unexplained.
    Blobs the rounds explained are still searched by the fallback when the camera has unread
    motes nobody could place (one of them may hide there), and so are those an unread placed
    mote may hide in."""
    wide = coded.unexplained(coded.wide_records[camera])
    if plan is None:
        coded.run_refine(runner, camera, wide, failed)
        return
    st = runner.state
    rounds = _records(st, camera, "s")
    read = {rd["node"] for r in _records(st, camera, "w") + rounds for rd in r["readings"]}
    left, explained, suspect = sort_wide_blobs(coded.intrinsics_at(camera, coded.survey_zoom[camera]), wide,
                                               coded.blob_directions(camera, wide), plan, camera, read)
    if suspect:
        logger.info(f"{camera}: {len(suspect)} wide-pass blobs whose crowded motes the rounds read are left to the "
                    "fallback: a mote the camera has not read is predicted near them")
    last = {(r["view"]): r for r in rounds}  # each round view's last recording
    coded.run_refine(runner, camera, left + coded.unexplained(list(last.values())), failed,
                     (explained if plan.unplaced[camera] else []) + suspect)


def sort_wide_blobs(intr: CameraIntrinsics, blobs: Sequence[Blob], directions: np.ndarray, plan: SeparationPlan,
                    camera: str, read: set[str]) -> tuple[list[Blob], list[Blob], list[Blob]]:
    """Split ``camera``'s wide-pass unexplained ``blobs`` (pixel and head at the wide zoom
    ``intr``; ``directions`` their (pan, tilt)) into (left to the zoom refinement, explained by
    the rounds, suspect). A blob is explained when some crowded mote of the plan is predicted
    within :data:`RADIUS_PX` of it, the camera has ``read`` (wide pass and rounds) every such
    mote, and no mote the camera has still not read is predicted within
    :data:`~fgloc.survey.coded_levers.PREDICTED_RADIUS` of it; suspect when only that last
    test fails; else left. The crowded motes are only those *predicted* near the blob: a mote
    one camera read is placed where that bearing meets the ground, which can be a degree off
    (8.7 px at a 502 px focal length), so a mote merged into the blob may have been predicted
    outside :data:`RADIUS_PX`, left out of every class (paused through the rounds) and read by
    none. A suspect blob goes to the fallback, which looks for each unread mote at the
    unexplained blobs within the same radius of its predicted direction
    (:func:`~fgloc.survey.coded_levers.blobs_near`): never dropped, or the camera would count
    as having no blob left and the mote would be journaled not found without a search."""
    from fgloc.survey.coded_levers import PREDICTED_RADIUS

    pred = plan.predicted.get(camera, {})
    todo = sorted(n for n in plan.unread.get(camera, set()) - read if n in pred)
    unread_at = pan_tilt_bearing(*np.array([pred[n] for n in todo], float).T) if todo else np.zeros((0, 3))
    left: list[Blob] = []
    explained: list[Blob] = []
    suspect: list[Blob] = []
    for blob, d in zip(blobs, np.asarray(directions, float).reshape(-1, 2)):
        near = crowded_motes(intr, [(blob[0], blob[1])], plan.crowded[camera], RADIUS_PX)
        if not near or not set(near) <= read:
            left.append(blob)
        elif len(unread_at) and float(np.max(unread_at @ pan_tilt_bearing(*d))) >= math.cos(PREDICTED_RADIUS):
            suspect.append(blob)
        else:
            explained.append(blob)
    return left, explained, suspect
