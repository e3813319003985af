"""The fallback round (lever ``fallback: "round"``): the motes left to the fallback blink alone.

After the wide pass and the zoom ladder, a camera may still not have read a mote that
another camera read. The predicted fallback (:mod:`fgloc.survey.coded_fallback`) places
it from that reading and searches it the sequential way, one LED cycle per node, at every
blob the camera left unexplained within :data:`~fgloc.survey.coded_levers.PREDICTED_RADIUS`
of that direction. In a crowded field most such motes are occluded from the camera: at
1000 motes x 2 cameras, 63 of the 77 nodes searched that way were not visible to the camera
that searched them, and the searches took 92 s of a 147 s survey
(docs/blink-codes.md, "The fallback round").

The round asks all of them at once, by code:

1. **Who.** Per camera, the motes it did not read (silent ones excepted). A mote placed from
   the journaled views (:func:`~fgloc.survey.coded_separation.predict`; round
   views excluded, so a resume re-plans the same round) would be searched at the camera's
   unexplained blobs within the radius of its predicted direction
   (:func:`~fgloc.survey.coded_levers.blobs_near`), and journaled not found without a search
   when there are none. The round covers the first kind (lever ``covers "searched"``, the
   default); with ``covers "placed"`` it also covers the second, in case a mote hides in a
   blob read as its neighbour (it would blink there alone). Measured at 1000 motes, three
   scenes: those rounds covered 219 such motes and read none of them; without them the
   survey took 2.7–4.9 s less in frames (three scenes) and -2.7 to +2.4 s in fields (five)
   (docs/blink-codes.md, "The round covers what the fallback would search").
   A mote no camera read would be searched at every blob the camera left: the round then
   covers those blobs. A camera whose views failed, or that left no blob unexplained, takes
   no part.
2. **Whether.** The round runs only when its price on the survey clock (one pause update,
   then each camera's views on its lane; the longest lane) is below that of the sequential
   searches it may save, priced by their LED commands, slews and settles alone, less the
   looks at lamps the round leaves lit (:func:`round_pays`, :func:`darkened_lamps`).
3. **Pause.** One pause-by-bitmap update pauses every mote but the *lit* ones: every mote
   (silent ones excepted) that some camera has not read.
4. **Views.** Each camera records, at the survey zoom, views covering the predicted
   directions of its covered motes of step 1 with the radius inside the image (and its blobs, when
   a mote of step 1 is not placed) (view ids ``f<k>``, journal
   ``lit``), decoded blind like a wide view. With its neighbours dark, a mote that merged
   into a crowd is alone; an occluded one shows nothing.
5. **What is left.** The camera's unexplained blobs inside a round view are replaced by
   the round views' own (:func:`blobs_after_round`), less those at a mote the camera read
   at the survey zoom (:func:`fgloc.survey.coded_ladder.unread`; merged blobs are kept; a
   reading at a ladder zoom does not count, since at the wide zoom a neighbour a few tenths
   of a degree away merges with it): the fallback then searches a mote the round did not
   read only at a blob the round left unexplained (near it, if placed: a static lamp, a
   mote that missed the pause, lit motes merged), and journals it ``not_found`` without a
   search when there is none.

The codes stop after the round, as before the fallback. Angles radians; pixels OpenCV
convention; times survey-clock seconds.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import nearest_first
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.survey.clock import Frames, PositionRead, Radio, Settle, Slew, Wait, parallel, price
from fgloc.survey.coded_levers import PREDICTED_RADIUS, blobs_near, take_bands
from fgloc.survey.coded_views import distinct_directions
from fgloc.survey.view_planner import coverage, plan_views

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.runner import SurveyRunner

logger = logging.getLogger(__name__)

ROUND_PREFIX = "f"  #: view ids of the fallback round: ``f000``, ``f001``, ...


def round_views(intr: CameraIntrinsics, predicted: np.ndarray, margin_px: float, start: tuple[float, float],
                tilt_limits: tuple[float, float]) -> list[tuple[float, float]]:
    """Head (pan, tilt) of views covering every ``predicted`` (M, 2) direction with the
    fallback's radius, plus ``margin_px``, inside the image (``intr`` at the survey zoom, whole frames)."""
    return plan_views(intr, np.asarray(predicted, float).reshape(-1, 2), margin_px + radius_px(intr),
                      start=start, tilt_limits=tilt_limits)


def radius_px(intr: CameraIntrinsics) -> float:
    """:data:`~fgloc.survey.coded_levers.PREDICTED_RADIUS` in pixels of ``intr`` (its longer focal length)."""
    return PREDICTED_RADIUS * max(intr.fx, intr.fy)


def blobs_after_round(intr: CameraIntrinsics, before: np.ndarray, heads: Sequence[tuple[float, float]],
                      margin_px: float, after: np.ndarray) -> np.ndarray:
    """A camera's unexplained blob directions once its round views (read-back ``heads`` at the
    survey zoom ``intr``, whole frames) are recorded: those of ``before`` (M, 2) that no round
    view sees ``margin_px`` inside its image, then the round views' own ``after`` (K, 2). Inside
    a round view a lit mote is decoded or leaves a blob there, so the older blobs say nothing more."""
    before = np.asarray(before, float).reshape(-1, 2)
    if len(before) and len(heads):
        seen = coverage(intr, before, np.asarray(heads, float).reshape(-1, 2), margin_px).any(axis=0)
        before = before[~seen]
    return np.concatenate([before, np.asarray(after, float).reshape(-1, 2)])


def round_pays(coded: CodedSurvey, views: Mapping[str, list[tuple[float, float]]],
               looks: Mapping[str, Mapping[str, list[tuple[float, float]]]], pause_packets: int,
               readings: Mapping[str, Mapping[str, np.ndarray]] | None = None,
               lit: Collection[str] = ()) -> bool:
    """Whether the round (one pause update of ``pause_packets`` bitmap packets, then each
    camera's ``views`` from where its head is) is priced below the sequential searches it may
    save: those of ``looks`` (camera -> node -> look directions) less those still left after it,
    the looks at blobs the zoom ladder took for static lamps (``CodedSurvey.final_lamps``: lit
    in the round too) that the round does not darken (:func:`darkened_lamps`, from the
    camera's ``readings``, camera -> node -> unit bearing, and the ``lit`` nodes). Searches are
    priced as the fallback runs them (its sweep order, each camera from its look nearest the
    head, every look visited) by their LED commands (on and off), LED waits, slews, settles and
    the frames each look grabs (one; two with on-off detection) only; centring, position reads
    and zooms are left out, so a round that runs costs less than the searches it saves."""
    from fgloc.survey.coded_separation import PAUSE_REPEATS

    first = coded.timing[coded.rig.camera_ids[0]]
    lanes = []
    for c, targets in views.items():
        ops: list[Any] = []
        here = coded.here[c]
        for target in targets:
            ops += [Slew.between(here, target), Settle(),
                    PositionRead(), Frames(coded.frames)]
            here = target
        lanes.append(price(ops, coded.lane_timing[c]))
    round_s = price([Radio(broadcast=PAUSE_REPEATS * pause_packets)], first).total + parallel(lanes).total
    searches_s = _searches_s(coded, looks)
    lamps: dict[str, list[np.ndarray]] = {}
    for c in looks:
        directions = coded.final_lamps.get(c, np.zeros((0, 2)))
        dark = darkened_lamps(directions, coded.final_lamp_radii.get(c, np.zeros(len(directions))),
                              (readings or {}).get(c, {}), lit)
        lamps[c] = [pan_tilt_bearing(float(p), float(t)) for (p, t), gone in zip(directions, dark) if not gone]
    # a static lamp is lit in the round too: the searches' looks at lamps stay
    staying = {c: {n: kept for n, v in by_node.items() if (kept := [d for d in v if _at_any(d, lamps[c])])}
               for c, by_node in looks.items()}
    searches_s -= _searches_s(coded, staying)
    logger.info(f"fallback round: priced {round_s:.1f} s against the {searches_s:.1f} s of sequential searches "
                f"it may save (LED, slews, settles and the looks' frames alone)")
    return round_s < searches_s


def darkened_lamps(lamps: np.ndarray, radii: np.ndarray, readings: Mapping[str, np.ndarray],
                   lit: Collection[str]) -> list[bool]:
    """Which of the ``lamps`` ((K, 2) pan, tilt) the round darkens: a never-dark blob with at
    least two of the camera's ``readings`` (node -> unit bearing) within its radius (``radii``,
    (K,) radians: the decoder's separation at the zoom that handed it) is motes merged so that
    one is always on, not a lamp, and with at most one of them ``lit`` in the round it goes dark
    there (the rest are paused). A blob with fewer readings in it is taken for a static lamp,
    lit in the round too. At 1000 motes (a scene without static lights) every blob the ladder
    took for a lamp lay within 0.16 deg of two or more visible motes (docs/blink-codes.md,
    "Crowds the ladder took for lamps")."""
    nodes = list(readings)
    bearings = np.array([readings[n] for n in nodes], float).reshape(-1, 3)
    out = []
    for (pan, tilt), radius in zip(np.asarray(lamps, float).reshape(-1, 2), np.asarray(radii, float).reshape(-1)):
        inside = bearings @ pan_tilt_bearing(float(pan), float(tilt)) >= math.cos(float(radius))
        members = [n for n, yes in zip(nodes, inside) if yes]
        out.append(len(members) >= 2 and sum(n in lit for n in members) <= 1)
    return out


def _at_any(direction: tuple[float, float], bearings: Sequence[np.ndarray]) -> bool:
    """Whether (pan, tilt) ``direction`` is one of ``bearings`` (unit vectors; looks are blob directions)."""
    d = pan_tilt_bearing(*direction)
    return any(float(b @ d) > math.cos(1e-6) for b in bearings)


def _searches_s(coded: CodedSurvey, looks: Mapping[str, Mapping[str, list[tuple[float, float]]]]) -> float:
    """The sequential searches of ``looks`` priced as :func:`round_pays` says."""
    from fgloc.survey.coded_fallback import nearest_look, sweep_key

    first = coded.timing[coded.rig.camera_ids[0]]
    grabs = 2 if coded.rig.search.detection == "on-off" else 1  # what each look grabs to see the LED
    head: dict[str, tuple[float, float] | None] = {c: None for c in looks}
    nodes = {n for by_node in looks.values() for n in by_node}
    searches = sorted(((n, {c: looks[c][n] for c in looks if n in looks[c]}) for n in nodes), key=sweep_key)
    total = 0.0
    for _node, node_looks in searches:
        node_lanes = []
        for c, cells in node_looks.items():
            ops: list[Any] = []
            # every look with its move and settle: the price leaves centring out, so it cannot know
            # whether the head still rests at the look (then the search only grabs, LedLocator.rests_at)
            at = head[c] or nearest_look(cells, None)
            for target in nearest_first(cells, nearest_look(cells, head[c])):
                ops += [Slew.between(at, target), Settle(), Frames(grabs)]
                at = head[c] = target
            node_lanes.append(price(ops, coded.timing[c]))
        total += price([Radio(unicast=2), Wait(coded.rig.search.led_wait_s)], first).total + parallel(node_lanes).total
    return total


def run_fallback_round(coded: CodedSurvey, runner: SurveyRunner, pool: ThreadPoolExecutor,
                       pump: Callable[[list[Future[None]]], None], codes_running: bool) -> None:
    """Steps 1-5 of the module docstring, before the codes stop. ``codes_running``: False on a
    resume after the journaled stop (the round was recorded before it: its views are replayed
    from the journal, nothing is paused or recorded)."""
    from fgloc.drivers.tinyos.blink import pause_packets
    from fgloc.files.journal import journal_to_survey
    from fgloc.survey.coded_separation import predict, wide_survey
    from fgloc.survey.coded_views import into_search_box

    st, cams, rig = runner.state, coded.rig.camera_ids, coded.rig
    if any(coded.blobs.get(c) is None for c in cams):
        return  # a view failed: its blobs are unknown, the fallback searches that camera's whole way
    with runner._state_lock:
        base = journal_to_survey(st)
        records = [r for (_c, v, _a), r in sorted(st.views.items()) if not str(v).startswith(ROUND_PREFIX)]
    prediction = predict(wide_survey(base, records))
    if prediction is None:
        return
    predicted = take_bands(coded, prediction)
    silent = set().union(*(set(r.get("silent", [])) for r in st.codes if r.get("action") == "start"))
    readings: dict[str, dict[str, np.ndarray]] = {c: {} for c in cams}  # camera -> node -> bearing of its reading
    for r in records:
        for rd in r["readings"]:
            readings[r["camera"]].setdefault(str(rd["node"]), pan_tilt_bearing(float(rd["pan"]), float(rd["tilt"])))
    read = {c: set(readings[c]) for c in cams}
    lit = sorted(n for n in rig.node_ids if n not in silent and any(n not in read[c] for c in cams))
    looks: dict[str, dict[str, list[tuple[float, float]]]] = {}  # camera -> node -> the fallback's looks
    views = {}
    for c in cams:
        if coded.remaining.get(c, 1) == 0:
            continue  # no blob left: the fallback journals its unread motes not found without a search
        mine = [n for n in lit if n not in read[c]]
        placed = [n for n in mine if n in predicted.get(c, {})]
        # as the fallback looks: near a placed mote's predicted direction, else at every blob left
        looks[c] = {n: blobs_near(coded, c, predicted[c][n], n) if n in predicted.get(c, {}) else list(coded.blobs[c] or [])
                    for n in mine}
        looks[c] = {n: v for n, v in looks[c].items() if v}
        covered = placed if coded.settings.covers == "placed" else [n for n in placed if n in looks[c]]
        pts = [predicted[c][n] for n in covered] + ([tuple(b) for b in coded.final_blobs[c]] if len(placed) < len(mine)
                                                    else [])
        if pts:
            s = rig.search_for(c)
            views[c] = [into_search_box(p, t, s.pan_min, s.pan_max, s.tilt_min, s.tilt_max) for p, t in round_views(
                rig.cameras[cams.index(c)].intrinsics, np.array(pts), coded.settings.margin_px, coded.here[c],
                (s.tilt_min, s.tilt_max))]
    if not any(looks.values()):
        return
    paused = {coded.addresses[n] for n in rig.node_ids} - {coded.addresses[n] for n in lit}
    packets = pause_packets(paused, range(coded.first, max(coded.addresses.values()) + 1))
    if not round_pays(coded, views, looks, len(packets), readings, set(lit)):
        return
    recorded = all((c, f"{ROUND_PREFIX}{k:03d}", 0) in st.views for c, vs in views.items() for k in range(len(vs)))
    if not codes_running and not recorded:
        return  # stopped before the round was recorded: nothing lit to record
    logger.info(f"fallback round: {len(lit)} motes lit, {sum(len(v) for v in looks.values())} searches replaced by "
                + ", ".join(f"{c} {len(v)} views" for c, v in views.items()))
    coded.next_stage()  # the pause waits for every camera's ladder
    if codes_running:
        coded.pause(paused)
    futures = [pool.submit(_record_round, coded, runner, c, views[c], lit) for c in views]
    pump(futures)
    coded.stats.fallback_round_views += sum(len(v) for v in views.values())


def _record_round(coded: CodedSurvey, runner: SurveyRunner, camera: str, views: list[tuple[float, float]],
                  lit: list[str]) -> None:
    """One camera's round views at the survey zoom (zooming back first, or on the way to the first
    view on a head that zooms while moving, if the ladder left it zoomed in), then its unexplained
    blobs replaced (:func:`blobs_after_round`)."""
    from fgloc.survey.clock import Zoom
    from fgloc.survey.coded_ladder import unread

    zoom0, worker = coded.survey_zoom[camera], runner.workers[camera]
    dzoom = 0.0  # the zoom back run during the move to the first round view (a head that zooms while moving)
    if camera in coded.owed_zoom and worker.before_next is not None:
        if views and coded.zooms_while_moving(runner, camera):
            dzoom = zoom0 - coded.owed_zoom[camera]
        else:
            coded.lanes[camera].append(Zoom(zoom0 - coded.owed_zoom[camera]))
        worker.before_next = None  # the round's first move sets the survey zoom itself
    records: list[dict[str, Any]] = []
    for k, target in enumerate(views):
        rec = coded._visit(runner, camera, f"{ROUND_PREFIX}{k:03d}", target, zoom0, coded.here[camera], {"lit": lit},
                           dzoom=dzoom if k == 0 else 0.0)
        coded.here[camera] = target
        if rec is None:
            return  # the camera failed: its blobs stay as they were, searched by the fallback
        records.append(rec)
    coded.stats.views += len(views)
    intr = coded.rig.cameras[coded.rig.camera_ids.index(camera)].intrinsics
    found = coded.unexplained(records)
    with runner._state_lock:  # the camera's readings at the survey zoom: wide pass, radio rounds, this round
        read = [pan_tilt_bearing(float(rd["pan"]), float(rd["tilt"])) for (c, _v, _a), r in runner.state.views.items()
                if c == camera and float(r.get("zoom", zoom0)) == zoom0 for rd in r["readings"]]
    # a blob at a mote the camera read at this zoom is that mote (coded_ladder.unread), unless refused as merged
    kept = unread(found, np.array(read).reshape(-1, 3), lambda z: coded.intrinsics_at(camera, z),
                  [(camera, b) in coded._merged for b in found])
    after = coded.blob_directions(camera, [found[k] for k in kept])
    heads = [(float(r["head"][0]), float(r["head"][1])) for r in records]
    coded.final_blobs[camera] = blobs_after_round(intr, coded.final_blobs[camera], heads, coded.settings.margin_px,
                                                  after)
    fov = min(runner.workers[camera].locator.pixels.field_of_view())  # the fallback's looks, as run_refine thins them
    coded.blobs[camera] = distinct_directions(coded.final_blobs[camera], 0.25 * fov)
