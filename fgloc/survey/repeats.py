"""The repeat phase of a survey: spend ``repeat_budget`` readings where the Cramér–Rao bound gains most.

After the node loop (every node done), the runner calls :func:`run_repeats`:

1. The *base survey* is the journal's readings with ``index < rig.repeats`` (the node loop's),
   in canonical order. It is solved (:func:`fgloc.solve.joint.solve_survey`) and
   :func:`fgloc.plan.repeat.plan_repeats` (objective ``mean``: the summed node trace) picks the
   ``repeat_budget`` most informative (camera, node) readings, in greedy order.
2. The k-th time a pair appears in that plan is the reading with index ``rig.repeats + k``
   (0-based k) of that pair. A planned reading is done when the journal holds its key.
3. The remaining readings are measured node by node (in order of first appearance in the
   plan): the node's LED is lit, every camera with readings of it left measures them in
   parallel (the same :meth:`~fgloc.survey.runner.CameraWorker.measure` as the node loop),
   each reading journaled the moment it is taken as an ordinary ``observation`` record.

Resume: the plan depends only on the base readings, which the repeat phase never adds to,
so a resumed run re-derives the same plan and measures exactly the readings that have no
record: none is lost or duplicated wherever the process was killed. A reading the camera
cannot take is journaled as ``repeat_failed`` (``node``, ``camera``, ``index``, ``reason``;
replay ignores it, so a resume tries it again) and logged. If the base survey cannot be
solved, the phase is skipped with a warning (the survey itself is complete).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fgloc.core.model import Survey
from fgloc.files.journal import JournalObservation, JournalState, journal_to_survey
from fgloc.plan.repeat import plan_repeats
from fgloc.solve.joint import solve_survey

if TYPE_CHECKING:
    from fgloc.survey.runner import SurveyRunner

logger = logging.getLogger(__name__)

REPEAT_OBJECTIVE = "mean"


@dataclass(frozen=True)
class PlannedReading:
    """One reading of the repeat plan: its journal key and the predicted gain (baseline units^2)."""

    node: str
    camera: str
    index: int
    gain: float


def base_survey(state: JournalState, repeats: int) -> Survey:
    """The survey of the node loop alone: readings with ``index < repeats``, canonical order."""
    survey = journal_to_survey(state)
    keep = [o for o in state.ordered_observations() if o.index < repeats]
    return Survey(mode=survey.mode, gauge=survey.gauge, sigma=survey.sigma, camera_ids=survey.camera_ids,
                  node_ids=survey.node_ids, observations=[o.to_observation() for o in keep], truth=survey.truth)


def repeat_plan(state: JournalState, repeats: int, budget: int) -> list[PlannedReading]:
    """The whole repeat plan (done or not), derived from the base readings only (deterministic)."""
    survey = base_survey(state, repeats)
    result = solve_survey(survey)
    plan = plan_repeats(survey, result, budget, REPEAT_OBJECTIVE)
    seen: dict[tuple[str, str], int] = {}
    out = []
    for r in plan.readings:
        k = seen.get((r.camera, r.node), 0)
        seen[(r.camera, r.node)] = k + 1
        out.append(PlannedReading(r.node, r.camera, repeats + k, r.gain))
    return out


def remaining(plan: list[PlannedReading], state: JournalState) -> list[PlannedReading]:
    """The planned readings that have no record in the journal yet, in plan order."""
    return [p for p in plan if (p.node, p.camera, p.index) not in state.observations]


def run_repeats(runner: SurveyRunner, pool: ThreadPoolExecutor) -> int:
    """Measure the repeat plan's readings that are not journaled yet; returns how many were taken."""
    rig, st = runner.rig, runner.state
    if rig.repeat_budget <= 0:
        return 0
    t0 = time.perf_counter()
    try:
        plan = repeat_plan(st, rig.repeats, rig.repeat_budget)
    except Exception as exc:  # noqa: BLE001 - the survey is complete; repeats are an extra
        message = " ".join(str(exc).split())
        logger.warning(f"repeat phase skipped: the survey could not be solved: {message[:200]}")
        return 0
    todo = remaining(plan, st)
    logger.info(f"repeat phase: {len(plan)} readings planned in {time.perf_counter() - t0:.1f} s, "
                f"{len(todo)} to take")
    by_node: dict[str, dict[str, list[int]]] = {}
    for p in todo:
        by_node.setdefault(p.node, {}).setdefault(p.camera, []).append(p.index)
    planned = {(p.node, p.camera, p.index) for p in plan}
    taken = [key for key in st.observations if key in planned]  # in journal order
    if taken and taken[-1][0] not in by_node:
        # killed after that node's last repeat, before its LED went off: a real mote is still lit
        runner.switch_off(taken[-1][0])
    before = runner.stats.observations
    for node, cams in by_node.items():
        _measure_node(runner, pool, node, cams)
    return runner.stats.observations - before


def _measure_node(runner: SurveyRunner, pool: ThreadPoolExecutor, node: str, cams: dict[str, list[int]]) -> None:
    """Light ``node`` and let each camera in ``cams`` take its readings (indices) of it."""
    rig = runner.rig
    if not runner._set_led(node, True):
        for cam, indices in cams.items():
            _failed(runner, node, cam, indices, f"LED: no acknowledgement after {rig.retry.led_attempts} attempts")
        return
    if rig.search.led_wait_s > 0:
        time.sleep(rig.search.led_wait_s)
    blink = (lambda grab: runner._blink([node], grab)) if rig.search.detection == "on-off" else None

    def recorder(cam: str) -> Callable[[int, float, float], None]:
        return lambda index, pan, tilt: runner._record_observation(JournalObservation(node, cam, index, pan, tilt))

    jobs = {cam: pool.submit(runner.workers[cam].measure, node, sorted(indices), runner._start_for(cam),
                             recorder(cam), blink)
            for cam, indices in cams.items()}
    for cam, future in jobs.items():
        reason = future.result()
        if reason is not None:
            taken = {o.index for o in runner.state.observations_of(node, cam)}
            _failed(runner, node, cam, [k for k in cams[cam] if k not in taken], reason)
    runner.switch_off(node)


def _failed(runner: SurveyRunner, node: str, cam: str, indices: list[int], reason: str) -> None:
    for index in indices:
        runner.journal.append({"type": "repeat_failed", "node": node, "camera": cam, "index": index,
                               "reason": reason})
    logger.warning(f"{node}: repeat by {cam} not taken: {reason}")
