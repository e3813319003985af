"""The fallback's one-camera searches in pairs (lever ``searches``): one node per camera lit at once.

After the round, nearly every mote the fallback searches is searched by one camera: the
other cameras have read it (at 1000 motes x 2 cameras, seeds 1-3: 13, 17 and 12 searches,
all of them by one camera; docs/blink-codes.md "A head already there only grabs, and
searches in pairs"). One at a time, the other camera waits while one looks. With
``searches "paired"`` (the default) each camera's one-camera searches, in the fallback's sweep order (:func:`~fgloc.survey.coded_fallback.sweep_key`),
are zipped into batches of one node per camera, lit together and searched in parallel
(:meth:`fgloc.survey.runner.SurveyRunner.run_together`): each camera looks only at its own
node's looks, and masks the other lit nodes' light where it read them
(:attr:`~fgloc.camera.led_search.LedLocator.ignore`; on-off detection blinks only the
camera's own node, so the others cancel).

Two nodes A (searched by camera a alone) and B (camera b alone, b != a) share a batch only when

* neither is silent (never confirmed its code) nor started before (a resume searches such a
  node alone, as before);
* every camera but a has finished A, and every camera but b has finished B;
* a has read B, and b has read A: a light the camera cannot place is never lit beside its node;
* a's readings of B lie at least :data:`PREDICTED_RADIUS` + :data:`CLEARANCE_PX` (pixels of
  a's search intrinsics) from A's predicted direction in a, and the same for b: wherever A lies
  within the radius the fallback searches (:mod:`fgloc.survey.coded_levers`), the spot finder's
  centroid window around it (:data:`~fgloc.camera.led_search.SPOT_RADIUS_PX`) never reaches
  B's masked disk (:data:`~fgloc.camera.led_search.IGNORE_RADIUS_PX`).

A node that fits no batch is searched alone, as before. ``searches "one"``: every node
alone (the default of journals written before this lever). Angles radians.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from fgloc.camera.led_search import IGNORE_RADIUS_PX, SPOT_RADIUS_PX
from fgloc.core.geometry import angle_between, pan_tilt_bearing
from fgloc.survey.coded_levers import PREDICTED_RADIUS, SEARCHES_MODES

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.runner import SurveyRunner

__all__ = ["SEARCHES_MODES", "batches", "clear_of", "one_camera"]

#: a paired node's predicted disk keeps this far (pixels at the search zoom) from the other lit node's
#: reading: the masked disk and the spot finder's centroid window never meet, with 2 px to spare
CLEARANCE_PX = IGNORE_RADIUS_PX + SPOT_RADIUS_PX + 2.0

Search = tuple[str, dict[str, list[tuple[float, float]]]]  #: (node, camera -> its looks)


def one_camera(coded: CodedSurvey, runner: SurveyRunner, search: Search, silent: set[str]) -> str | None:
    """The camera that alone searches ``search``'s node, if it may share a batch (module docstring)."""
    node, looks = search
    st = runner.state
    need = [c for c in coded.rig.camera_ids if not st.camera_finished(node, c, coded.rig.repeats)]
    if node in silent or node in st.started or len(need) != 1 or list(looks) != need:
        return None
    return need[0]


def clear_of(runner: SurveyRunner, camera: str, predicted: tuple[float, float], other: str) -> bool:
    """Whether ``camera`` has read ``other`` and every such reading lies at least
    PREDICTED_RADIUS + CLEARANCE_PX from the ``predicted`` (pan, tilt) of its own node."""
    readings = runner.state.observations_of(other, camera)
    if not readings:
        return False
    k = runner.workers[camera].locator.pixels.intrinsics
    bearings = pan_tilt_bearing([o.pan for o in readings], [o.tilt for o in readings])
    return bool(np.all(angle_between(bearings, pan_tilt_bearing(*predicted))
                       >= PREDICTED_RADIUS + CLEARANCE_PX / max(k.fx, k.fy)))


def batches(coded: CodedSurvey, runner: SurveyRunner, searches: list[Search], silent: set[str],
            predicted: Mapping[str, Mapping[str, tuple[float, float]]] | None) -> list[list[Search]]:
    """``searches`` (in sweep order) as batches lit together: each camera's one-camera searches
    zipped in order, a pair kept where both are clear of the other (module docstring), else
    each alone. Batches in the order of their first search."""
    if coded.settings.searches != "paired" or predicted is None:
        return [[s] for s in searches]
    queues: dict[str, list[Search]] = {c: [] for c in coded.rig.camera_ids}
    out: list[list[Search]] = []
    for search in searches:
        camera = one_camera(coded, runner, search, silent)
        if camera is None or search[0] not in predicted.get(camera, {}):
            out.append([search])
        else:
            queues[camera].append(search)
    for k in range(max((len(q) for q in queues.values()), default=0)):
        batch: list[tuple[str, Search]] = []
        for camera, queue in queues.items():
            if k >= len(queue):
                continue
            search = queue[k]
            if all(clear_of(runner, camera, predicted[camera][search[0]], other[0])
                   and clear_of(runner, c, predicted[c][other[0]], search[0]) for c, other in batch):
                batch.append((camera, search))
            else:
                out.append([search])
        if batch:
            out.append([s for _, s in batch])
    order = {search[0]: k for k, search in enumerate(searches)}
    return sorted(out, key=lambda b: order[b[0][0]])
