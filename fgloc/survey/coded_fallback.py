"""The coded survey's sequential fallback: every node some camera has not decoded.

Split out of :mod:`fgloc.survey.coded`, whose :meth:`~fgloc.survey.coded.CodedSurvey.run_fallback`
calls :func:`run_fallback`. Angles radians.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

from fgloc.camera.led_search import nearest_first
from fgloc.survey.coded_levers import PREDICTED_RADIUS, banded, blobs_near, take_bands, wide_prediction
from fgloc.survey.coded_paired import batches

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.runner import SurveyRunner

logger = logging.getLogger("fgloc.survey.coded")  # the coded survey's log, as before the split


def sweep_key(search: tuple[str, Mapping[str, list[tuple[float, float]]]]) -> tuple[int, float, str]:
    """Order of the sequential searches: nodes with looks by the smallest pan among the first
    camera's looks, so that each camera sweeps its box once (most nodes are searched by one
    camera only; each search starts at its look nearest the head, :func:`nearest_look`), then
    the others by id. A function of the node's looks alone, so a resume keeps it."""
    node, looks = search
    pans = [min(looks[c])[0] for c in sorted(looks) if looks[c]]
    return (0, pans[0], node) if pans else (1, 0.0, node)


def nearest_look(cells: list[tuple[float, float]], head: tuple[float, float] | None) -> tuple[float, float]:
    """The cell of ``cells`` nearest to ``head`` (its last look; None: the smallest pan, where the sweep starts)."""
    return nearest_first(cells, head)[0] if head is not None else min(cells)


def run_fallback(coded: CodedSurvey, runner: SurveyRunner, pool: ThreadPoolExecutor, total: int, t0: float) -> None:
    """Finish every node some camera has not read. A camera whose views left no blob
    unexplained did not see a mote that confirmed its code: that is journaled ``not_found``
    without a search. The rest (and motes that never confirmed) are measured the
    sequential way, priced per node, in one sweep across the boxes (:func:`sweep_key`)."""
    st = runner.state
    clean = {c for c in coded.rig.camera_ids if coded.remaining.get(c, 1) == 0}
    prediction = wide_prediction(runner) if coded.settings.fallback in ("predicted", "round") else None
    predicted = None if prediction is None else take_bands(coded, prediction)
    starts = [set(r.get("silent", [])) for r in st.codes if r.get("action") == "start"]
    silent = set.intersection(*starts) if starts else set(coded.rig.node_ids)  # never confirmed a start
    searches: list[tuple[str, dict[str, list[tuple[float, float]]]]] = []  # (node, camera -> its looks)
    for node in coded.rig.node_ids:
        if node in st.done:
            continue
        looks: dict[str, list[tuple[float, float]]] = {}
        if node not in silent:
            for cam in coded.rig.camera_ids:
                at = (predicted or {}).get(cam, {}).get(node)
                if cam in clean or at is None or coded.blobs.get(cam) is None or st.camera_finished(
                        node, cam, coded.rig.repeats):
                    continue
                near = blobs_near(coded, cam, at, node)
                if near:
                    looks[cam] = near
                else:
                    reason = (f"not decoded by the camera, and no blob it left unexplained lies within "
                              f"{math.degrees(PREDICTED_RADIUS):g} deg of where the other cameras' readings "
                              f"place the mote (pan {math.degrees(at[0]):.2f}, tilt {math.degrees(at[1]):.2f} deg)"
                              + (" and near the epipolar plane of its reading" if banded(coded, cam, node) else ""))
                    runner.journal.not_found(node, cam, reason)
                    st.not_found[(node, cam)] = reason
                    runner.stats.not_found += 1
                    logger.info(f"{node}: not found by {cam}: {reason}")
            for cam in sorted(clean):
                if not st.camera_finished(node, cam, coded.rig.repeats):
                    reason = "not decoded in any view of the camera, which left no blob unexplained"
                    runner.journal.not_found(node, cam, reason)
                    st.not_found[(node, cam)] = reason
                    runner.stats.not_found += 1
                    logger.info(f"{node}: not found by {cam}: {reason}")
        if all(st.camera_finished(node, c, coded.rig.repeats) for c in coded.rig.camera_ids):
            if node in st.started and node not in st.led_failed:
                runner.switch_off(node)  # its search was killed after its last reading, the LED still on
            runner.journal.node_done(node)
            st.done.add(node)
            continue
        searches.append((node, looks))
    searches = search_unplaced_together(coded, runner, pool, searches, silent)
    for batch in batches(coded, runner, sorted(searches, key=sweep_key), silent, predicted):
        nodes = [node for node, _ in batch]
        coded.stats.fallback_nodes += len(batch)
        logger.info(f"{', '.join(nodes)}: not decoded by every camera; measured the sequential way"
                    + (", one per camera lit at once" if len(batch) > 1 else ""))
        coded.clock.begin()
        grids = {c: w.locator.cells for c, w in runner.workers.items()}
        try:
            if len(batch) == 1:
                node, looks = batch[0]
                runner.run_node(node, pool, check_misses=False,
                                start_at=aim_at_looks(coded, runner, looks, node in silent))
            else:  # coded_paired: each camera searches its own node at its own looks
                start_at = aim_at_looks(coded, runner, {c: v for _, looks in batch for c, v in looks.items()}, False)
                runner.run_together({c: node for node, looks in batch for c in looks}, pool, start_at)
        finally:
            node_time = coded.clock.end()
            for cam, worker in runner.workers.items():
                worker.locator.cells = grids[cam]
        if len(batch) == 1:
            runner.journal.field_time("fallback_node", dict(node_time.phases), node=nodes[0])
        else:
            runner.journal.field_time("fallback_pair", dict(node_time.phases), nodes=nodes)
        coded.fallback = coded.fallback + node_time
        if runner.on_progress is not None:
            runner.on_progress(coded.progress(runner, total, total, t0))


def aim_at_looks(coded: CodedSurvey, runner: SurveyRunner, looks: Mapping[str, list[tuple[float, float]]],
                 silent: bool) -> dict[str, tuple[float, float]]:
    """Point each camera's search at ``looks[camera]`` (else at every blob it left unexplained):
    a mote that blinks its code and was not decoded is in such a blob, or not in view. A
    ``silent`` mote (never confirmed its code) keeps the whole grid. Returns where each
    camera's search starts (its look nearest the head). The caller restores the grids."""
    start_at: dict[str, tuple[float, float]] = {}
    for cam, worker in runner.workers.items():
        blobs = looks.get(cam, coded.blobs.get(cam))
        if not silent and blobs is not None:
            worker.locator.cells = [worker.locator.clamp(p, t) for p, t in blobs]
        if not silent and blobs:  # from its look nearest the head, not the last reading
            start_at[cam] = nearest_look(worker.locator.cells, worker.locator.last_look)
    return start_at


def search_unplaced_together(coded: CodedSurvey, runner: SurveyRunner, pool: ThreadPoolExecutor,
                             searches: list[tuple[str, dict[str, list[tuple[float, float]]]]],
                             silent: set[str]) -> list[tuple[str, dict[str, list[tuple[float, float]]]]]:
    """Motes no camera placed (no looks: each camera would search every blob it left
    unexplained, the same looks for each) are searched together first: all of a group lit at
    once, each camera looks once. A camera that sees no light records every lit mote of the
    group not found; the others search them one by one as before. Groups are the motes that
    confirmed their code and need the same cameras, two or more. Returns the searches left."""
    st = runner.state
    groups: dict[tuple[str, ...], list[str]] = {}
    for node, looks in searches:
        if not looks and node not in silent:
            need = tuple(c for c in coded.rig.camera_ids if not st.camera_finished(node, c, coded.rig.repeats))
            groups.setdefault(need, []).append(node)
    for cameras, nodes in groups.items():
        if len(nodes) < 2 or not cameras:
            continue
        coded.clock.begin()
        grids = {c: w.locator.cells for c, w in runner.workers.items()}
        try:
            start_at = aim_at_looks(coded, runner, {}, False)
            lit, seen = runner.look_with_all_lit(nodes, pool, {c: start_at.get(c) for c in cameras})
        finally:
            group_time = coded.clock.end()
            for cam, worker in runner.workers.items():
                worker.locator.cells = grids[cam]
        absent = [c for c in cameras if c not in seen]
        logger.info(f"{len(lit)} motes no camera placed, lit at once: no light seen by "
                    f"{', '.join(absent) or 'no camera'}{'; searched one by one' if seen else ''}")
        for node in lit:
            for cam in absent:
                reason = (f"not in view anywhere in the search pattern (searched with the {len(lit)} motes "
                          "no camera placed lit at once)")
                runner.journal.not_found(node, cam, reason)
                st.not_found[(node, cam)] = reason
                runner.stats.not_found += 1
            if all(st.camera_finished(node, c, coded.rig.repeats) for c in coded.rig.camera_ids):
                runner.journal.node_done(node)
                st.done.add(node)
        runner.journal.field_time("fallback_group", dict(group_time.phases))
        coded.fallback = coded.fallback + group_time
    return [(node, looks) for node, looks in searches if node not in st.done]
