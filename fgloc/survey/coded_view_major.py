"""View-major radio-separation rounds: each camera visits its round views once.

Class-major rounds (:func:`fgloc.survey.coded_separation.run_separation`, ``round_order
"class"``) light one colour class at a time; every camera records the views holding its
crowded motes of that class, a barrier, the next class: a camera whose crowded motes of
several classes share a view slews back, settles and reads its position once per class.
View-major (``round_order "view"``) plans each camera's round views once, around **all**
its crowded motes (:func:`round_views`), and stays at each view while the base station
cycles the classes that view needs.

**Jobs.** A job is (camera, view, class): view ``j`` of the camera needs class ``k`` when
one of the camera's crowded motes of class ``k`` is first covered (``margin_px`` inside
the image, in plan order) by view ``j``.

**Schedule** (:func:`fgloc.survey.view_planner.view_major_schedule`, a pure function of the jobs, so a resume
re-plans it exactly). Pauses are global, so the cameras must agree on the lit class. The
schedule is a list of slots; each slot lights one class, and every camera whose *current*
view (its first view with a job left) needs that class records it in that slot; the
others wait. The class of a slot is the one that serves the most cameras, ties to the
class lit already (no pause update), then to the lowest class. A camera's view is done
when its last class was recorded; it then moves on to its next view. Invariants
(tested): every job is recorded exactly once, in a slot lighting its class, by a camera
at the view of the job, and each camera visits its views in plan order, each once; a
pause update is sent exactly when the lit class changes.

**Price** (the camera lanes, as :meth:`fgloc.survey.coded.CodedSurvey._visit` prices
them): a camera slews, settles and reads its position once per view, as soon as its
previous view is done (while the others may still record); a recording after a pause
update is a new burst of frames without a move. A pause update waits for every
recording of the class lit before it (each lane waits until the last of them ended:
:class:`~fgloc.survey.clock.Wait`, phase ``round_wait``), and is radio time, in series as
in class-major rounds. View ids ``s<class>-v<view>``: unique and deterministic.
Angles radians; lane times seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from fgloc.survey.clock import PositionRead, Settle, Slew, Wait, price
from fgloc.survey.coded_rounds import round_candidates
from fgloc.survey.coded_views import into_search_box
from fgloc.survey.view_planner import coverage, plan_views, view_major_schedule

if TYPE_CHECKING:
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.coded_separation import SeparationPlan
    from fgloc.survey.runner import SurveyRunner


def round_views(coded: CodedSurvey, plan: SeparationPlan, camera: str) -> tuple[list[tuple[float, float]], list[set[int]]]:
    """The camera's round views (head pan, tilt; one plan over all its crowded motes, from
    where its wide pass ended) and the classes each needs (module docstring, "Jobs")."""
    mine = sorted(plan.crowded.get(camera, {}))
    if not mine:
        return [], []
    s = coded.rig.search_for(camera)
    intr = coded.intrinsics_at(camera, coded.survey_zoom[camera])
    pts = np.array([plan.crowded[camera][n] for n in mine], float)
    views = [into_search_box(p, t, s.pan_min, s.pan_max, s.tilt_min, s.tilt_max) for p, t in plan_views(
        intr, pts, coded.settings.margin_px, start=coded.here[camera], tilt_limits=(s.tilt_min, s.tilt_max))]
    needs: list[set[int]] = [set() for _ in views]
    if views:
        cov = coverage(intr, pts, np.array(views), coded.settings.margin_px)
        near = coverage(intr, pts, np.array(views), 0.0)  # a view moved into the box may cover less
        for m, n in enumerate(mine):
            hit = np.flatnonzero(cov[:, m]) if cov[:, m].any() else np.flatnonzero(near[:, m])
            if len(hit):
                needs[int(hit[0])].add(plan.colour[n])
    keep = [j for j, need in enumerate(needs) if need]  # a view whose motes all fell to earlier views: none
    return [views[j] for j in keep], [needs[j] for j in keep]


def run_view_major(coded: CodedSurvey, runner: SurveyRunner, pool: ThreadPoolExecutor,
                   pump: Callable[[list[Future[None]]], None], plan: SeparationPlan) -> None:
    """Run the view-major rounds of ``plan`` (module docstring); the caller resumes every mote
    afterwards. Ends with a barrier (the refinement starts after every camera's rounds)."""
    cams = coded.rig.camera_ids
    planned = {c: round_views(coded, plan, c) for c in cams}
    views = {c: v for c, (v, _) in planned.items()}
    slots = view_major_schedule({c: n for c, (_, n) in planned.items()})
    members = {k: sorted(n for n, col in plan.colour.items() if col == k) for k in range(plan.classes)}
    zoom = {c: coded.survey_zoom[c] for c in cams}

    def lane_time(c: str) -> float:
        return price(coded.lanes[c], coded.lane_timing[c]).total

    def move(c: str, target: tuple[float, float]) -> None:  # priced now; the head moves on its first recording
        here = coded.here[c]
        coded.lanes[c] += [Slew.between(here, target), Settle(),
                           PositionRead()]
        coded.here[c] = target
        coded._head_at[c] = None

    recorded_end = {c: lane_time(c) for c in cams}  # lane time the camera's last recording ended
    for c in cams:
        if views[c]:
            move(c, views[c][0])
    # the classes each camera's view has left: the view is done (the camera moves on) at 0
    remaining = {c: [sum(1 for s in slots if s.views.get(c) == j) for j in range(len(views[c]))] for c in cams}
    lit: int | None = None
    lit_from = 0.0  # lane time from which the lit class blinks alone
    for slot in slots:
        if slot.lit != lit:
            lit, lit_from = slot.lit, max(recorded_end.values())
            coded.pause(set(coded.addresses.values()) - {coded.addresses[n] for n in members[lit]})
        futures: list[Future[None]] = []
        for c, j in sorted(slot.views.items()):
            wait = lit_from - lane_time(c)
            if wait > 1e-12:
                coded.lanes[c].append(Wait(wait, "round_wait"))
            cands = (round_candidates(members[lit], plan.predicted.get(c, {})) if coded.settings.rounds == "short"
                     else None)
            futures.append(pool.submit(_job, coded, runner, c, f"s{lit}-v{j:03d}", views[c][j], zoom[c], lit,
                                       members[lit], cands))
        pump(futures)
        for c, j in slot.views.items():
            recorded_end[c] = lane_time(c)
            remaining[c][j] -= 1
            if not remaining[c][j] and j + 1 < len(views[c]):
                move(c, views[c][j + 1])
        coded.stats.views += len(slot.views)
        coded.stats.round_views += len(slot.views)
    coded.next_stage()


def _job(coded: CodedSurvey, runner: SurveyRunner, camera: str, vid: str, target: tuple[float, float], zoom: float,
         k: int, lit: list[str], candidates: list[tuple[str, tuple[float, float]]] | None) -> None:
    """One job: the camera, already priced at ``target``, records class ``k`` there."""
    coded._visit(runner, camera, vid, target, zoom, None, {"round": k, "lit": lit}, candidates,
                 coded._head_at.get(camera))
