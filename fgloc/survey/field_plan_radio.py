"""Radio separation in the field plan: who conflicts, the colour rounds, and their price.

Split from :mod:`fgloc.survey.field_plans` (which re-exports every name here). Instead of
zooming, crowded motes are separated in time (:func:`radio_separation`): the conflict
graph (two motes too close in some camera's wide view) is coloured; per colour class one
pause-by-bitmap update (``drivers/tinyos/blink.py`` ``BlinkPause``) darkens the other
classes' conflicting motes and each camera re-records, at the wide zoom, the views holding
its conflicting motes of that class (:func:`radio_round_time`). Motes beside a static light
still go to zoom refinement. :func:`coded_view_ops` (the clock operations of recording a
list of views) lives here because both the rounds and the coded survey's wide and
refinement passes use it.

**Short rounds** (``round_frames`` of :func:`radio_round_time`): in a round only one colour
class is lit and its members' IDs and predicted directions are known, so a round view can
record ``K'`` samples (as few as ``L + 2``) and label each blob against its candidates
(:func:`fgloc.camera.blink_candidates.decode_candidates`) instead of ``3L + 2`` decoded
blind; retries continue the recording as before.

Angles radians, times seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.drivers.tinyos.blink import PAUSE_MAX_BYTES
from fgloc.survey.clock import (
    ZERO,
    FieldTime,
    Frames,
    Op,
    PositionRead,
    Radio,
    RigTiming,
    Settle,
    Slew,
    Wait,
    parallel,
    price,
)
from fgloc.survey.field_plan_cover import cover_colour
from fgloc.survey.view_planner import (
    RadioRound,
    colour_conflicts,
    conflict_pairs,
    nearest_first,
    neighbour_px,
    plan_radio_rounds,
    plan_round_stations,
    view_major_schedule,
)


def coded_view_ops(views: Sequence[tuple[float, float]], frames_per_view: int, retry_fraction: float,
                   start: tuple[float, float] = (0.0, 0.0), extend_frames: int = 0,
                   retry_frames: int | None = None) -> list[Op]:
    """Clock operations of one camera visiting ``views`` in order and recording each.

    Each view records ``frames_per_view + extend_frames`` frames in one burst (the
    extension: more sliding windows of the same recording). ``retry_fraction`` of the
    views (rounded) are retried without moving: by default a new burst of
    ``frames_per_view`` frames; with ``retry_frames`` the recording just goes on for
    that many frames (continuous, :class:`Frames` ``continuous``)."""
    ops: list[Op] = []
    pan, tilt = start
    for p, t in views:
        ops += [Slew.between((pan, tilt), (p, t)), Settle(), PositionRead(),
                Frames(frames_per_view + extend_frames)]
        pan, tilt = p, t
    extra = round(retry_fraction * len(views))
    retry = Frames(frames_per_view, "frames") if retry_frames is None else Frames(retry_frames, "frames", True)
    ops += [retry] * extra
    return ops


def radio_round_time(
    rounds: dict[str, list[RadioRound]], start: dict[str, tuple[float, float]], frames_per_view: int,
    timing: RigTiming, pause_broadcasts: int = 3, retry_fraction: float = 0.0, retry_frames: int | None = None,
    extend_frames: int = 0, round_frames: int | None = None, order: str = "class",
) -> tuple[FieldTime, dict[str, tuple[float, float]], int]:
    """Price radio separation (class-major, the default ``order``): for each colour class in turn, one pause update
    (``pause_broadcasts`` broadcasts: the bitmap packets times their repeats) pauses every
    other class's conflicting motes and resumes this class's; then every camera, at the
    wide zoom, slews to its round's views (:class:`RadioRound`) and records each
    (:func:`coded_view_ops`, phase 'separate'); the next round starts when the slowest
    camera is done (barrier: a pause must not darken a mote another camera is still
    recording). Rounds no camera records in are skipped. Retries: ``retry_fraction`` of
    each camera's round views, rounded on the running count so the camera's total is
    ``round(retry_fraction x its round views)``. ``round_frames`` (short rounds, off by
    default): each round view records ``round_frames`` samples instead of ``frames_per_view
    + extend_frames`` (the class's candidates are known, :mod:`fgloc.camera.blink_candidates`);
    its retries are priced as given (``retry_frames``: the recording goes on).
    ``order="view"`` (view-major): each camera stays on a view while the classes it needs
    there take turns (:func:`view_major_round_time`); the rounds should then share their
    views across classes (:func:`fgloc.survey.view_planner.plan_round_stations`).
    Returns the field time, each camera's head position after its last round, and the
    number of pause updates sent."""
    if order == "view":
        return view_major_round_time(rounds, start, frames_per_view, timing, pause_broadcasts, retry_fraction,
                                     retry_frames, extend_frames, round_frames)
    if order != "class":
        raise ValueError(f"round order must be 'class' or 'view' ({order!r})")
    total = ZERO
    here = dict(start)
    seen = dict.fromkeys(rounds, 0)
    updates = 0
    for r in range(max((len(rs) for rs in rounds.values()), default=0)):
        lanes = []
        for cam, rs in rounds.items():
            if r >= len(rs) or not rs[r].views:
                continue
            vs = rs[r].views
            before = round(retry_fraction * seen[cam])
            seen[cam] += len(vs)
            ops = (coded_view_ops(vs, frames_per_view, 0.0, here[cam], extend_frames) if round_frames is None
                   else coded_view_ops(vs, round_frames, 0.0, here[cam]))
            burst = frames_per_view if round_frames is None else round_frames
            retry = Frames(burst) if retry_frames is None else Frames(retry_frames, "frames", True)
            ops += [retry] * (round(retry_fraction * seen[cam]) - before)
            lanes.append(price([replace(o, phase="separate") for o in ops], timing))
            here[cam] = vs[-1]
        if lanes:
            total = total + price([Radio(broadcast=pause_broadcasts)], timing) + parallel(lanes)
            updates += 1
    return total, here, updates


@dataclass(frozen=True)
class RoundSlot:
    """One slot of view-major rounds: the lit colour class, the cameras that move to a new
    station during it, and the station each recording camera records this class at."""

    colour: int
    moves: dict[str, tuple[float, float]]  #: camera -> the station it moves to in this slot
    records: dict[str, tuple[float, float]]  #: camera -> the station it records at (this slot's class)


def view_major_slots(rounds: dict[str, list[RadioRound]], start: dict[str, tuple[float, float]]) -> list[RoundSlot]:
    """Schedule view-major rounds: the jobs are each camera's (view, class) pairs of ``rounds``;
    a camera visits its distinct views (*stations*) in nearest-first order from ``start`` and
    stays on each until every class it needs there has been recorded. The slots are those of
    :func:`fgloc.survey.view_planner.view_major_schedule` (the integrated survey's schedule);
    a camera moves to its next station in the slot after its last recording at the current one
    (moving needs no particular class), and to its first station in the first slot."""
    stations: dict[str, list[tuple[float, float]]] = {}
    needs: dict[str, list[set[int]]] = {}
    for cam, rs in rounds.items():
        need: dict[tuple[float, float], set[int]] = {}
        for rr in rs:
            for v in rr.views:
                need.setdefault(v, set()).add(rr.colour)
        if need:
            stations[cam] = nearest_first(list(need), start[cam])
            needs[cam] = [need[v] for v in stations[cam]]
    schedule = view_major_schedule(needs)
    moves: list[dict[str, tuple[float, float]]] = [{} for _ in schedule]
    if schedule:
        moves[0] = {cam: vs[0] for cam, vs in stations.items()}
    left = {cam: [len(n) for n in needs[cam]] for cam in needs}
    for s, slot in enumerate(schedule):
        for cam, j in slot.views.items():
            left[cam][j] -= 1
            if not left[cam][j] and j + 1 < len(stations[cam]) and s + 1 < len(schedule):
                moves[s + 1][cam] = stations[cam][j + 1]
    return [RoundSlot(slot.lit, moves[s], {cam: stations[cam][j] for cam, j in slot.views.items()})
            for s, slot in enumerate(schedule)]


def view_major_round_time(
    rounds: dict[str, list[RadioRound]], start: dict[str, tuple[float, float]], frames_per_view: int,
    timing: RigTiming, pause_broadcasts: int = 3, retry_fraction: float = 0.0, retry_frames: int | None = None,
    extend_frames: int = 0, round_frames: int | None = None,
) -> tuple[FieldTime, dict[str, tuple[float, float]], int]:
    """Price radio separation in view-major order (the slots of :func:`view_major_slots`).

    A slot lasts its slowest camera (barrier, as the class-major rounds). A camera that moves
    slews, settles and reads its position; a change of class costs one pause update
    (``pause_broadcasts``) and, for a recording camera that does not move, one frame period
    before its burst (the first sample may straddle the LEDs' switch; a camera that moves
    settles longer than that). Recording and retries as :func:`radio_round_time`
    (``round_frames``, ``retry_fraction`` rounded on the camera's running count of round
    views). Returns the field time, each camera's head position at the end, and the number
    of pause updates."""
    here = dict(start)
    seen = dict.fromkeys(rounds, 0)
    burst = frames_per_view + extend_frames if round_frames is None else round_frames
    retry = Frames(burst) if retry_frames is None else Frames(retry_frames, "frames", True)
    total, lit, updates = ZERO, -1, 0
    for slot in view_major_slots(rounds, start):
        change = slot.colour != lit
        lanes = []
        for cam in rounds:
            ops: list[Op] = []
            if cam in slot.moves:
                to = slot.moves[cam]
                ops += [Slew.between(here[cam], to), Settle(),
                        PositionRead()]
                here[cam] = to
            if cam in slot.records:
                if change and cam not in slot.moves:
                    ops.append(Wait(timing.camera.frame_period_s))
                before = round(retry_fraction * seen[cam])
                seen[cam] += 1
                ops += [Frames(burst), *[retry] * (round(retry_fraction * seen[cam]) - before)]
            if ops:
                lanes.append(price([replace(o, phase="separate") for o in ops], timing))
        if change:
            total = total + price([Radio(broadcast=pause_broadcasts)], timing)
            updates += 1
        total = total + parallel(lanes)
        lit = slot.colour
    return total, here, updates


@dataclass
class RadioSeparation:
    """Plan of a radio separation (:func:`radio_separation`)."""

    colour: np.ndarray  #: (N,) colour class per mote, -1: in no conflict of a radio camera
    rounds: dict[str, list[RadioRound]]  #: per radio camera, one round per colour class
    leftover: dict[str, np.ndarray]  #: per camera, crowded motes radio cannot separate (zoom refinement)
    pause_broadcasts: int  #: broadcasts per pause update (bitmap packets x repeats)

    @property
    def classes(self) -> int:
        return int(self.colour.max()) + 1 if self.colour.size else 0


def radio_separation(
    intr: CameraIntrinsics, pan_tilt: dict[str, np.ndarray], views: dict[str, list[tuple[float, float]]],
    separation_px: float, radio_cameras: Sequence[str], field_rows: bool = False,
    needed: dict[str, np.ndarray | None] | None = None, lamps: dict[str, np.ndarray] | None = None,
    addresses: Sequence[int] | None = None, repeats: int = 3, margin_px: float = 12.0,
    partner: dict[str, np.ndarray] | None = None, partner_ok: dict[str, np.ndarray] | None = None,
    stations: bool = False,
) -> RadioSeparation:
    """Separate crowded motes in time instead of by zoom.

    For each camera of ``radio_cameras`` (``pan_tilt[camera]``: (N, 2) directions of the
    same N motes for every camera; ``views[camera]``: its wide views), two motes closer
    than ``separation_px`` at the wide zoom conflict (:func:`conflict_pairs`; with
    ``needed[camera]`` only pairs with a mote needed from that camera, and, as a round
    lights one class and pauses every other mote, only pairs of motes some radio camera
    needs from a crowd: a mote every camera read is paused through the rounds and
    conflicts with nobody; cover rounds, ``partner``, keep every pair). The union of
    these conflicts is coloured (:func:`colour_conflicts`), and each camera re-records,
    per colour class, the wide views that cover its conflicting motes of that class
    (:func:`plan_radio_rounds`). A mote within ``separation_px`` of a static light
    (``lamps[camera]``, (M, 2) directions) cannot be separated by pausing motes: it is
    left to zoom refinement (``leftover``), as are all crowded motes of cameras not in
    ``radio_cameras``. ``addresses`` (default 1..N) price the pause update: the bitmap
    packets covering the address range of the conflicting motes and of the paused crowded ones (``pause_packets`` of
    ``drivers/tinyos/blink.py``, 192 addresses each), each sent ``repeats`` times.
    ``stations``: each camera's round views are shared across the classes
    (:func:`fgloc.survey.view_planner.plan_round_stations`), for the view-major order."""
    cams = list(pan_tilt)
    n = len(next(iter(pan_tilt.values())))
    needed = needed or {}
    lamps = lamps or {}
    # a round lights one class and pauses every other mote (as the coded survey does), so a mote
    # no radio camera needs from a crowd is never lit in a round: its conflicts do not count
    lit, crowd = np.zeros(n, bool), np.zeros(n, bool)
    for c in radio_cameras:
        need_c = np.ones(n, bool) if needed.get(c) is None else np.asarray(needed[c], bool)
        crowd_c = neighbour_px(np.asarray(pan_tilt[c], float), intr, field_rows) < separation_px
        lit |= need_c & crowd_c
        crowd |= crowd_c
    pairs: list[np.ndarray] = []
    cam_pairs: dict[str, np.ndarray] = {}
    mine: dict[str, np.ndarray] = {}
    leftover: dict[str, np.ndarray] = {}
    for c in cams:
        pt = np.asarray(pan_tilt[c], dtype=float)
        crowded = neighbour_px(pt, intr, field_rows) < separation_px
        need = np.ones(n, bool) if needed.get(c) is None else np.asarray(needed[c], bool)
        lamp_close = np.zeros(n, bool)
        if c in lamps and len(lamps[c]):
            both = np.vstack([pt, np.asarray(lamps[c], float)])
            pl = conflict_pairs(both, intr, separation_px, field_rows)
            pl = pl[(pl[:, 0] < n) & (pl[:, 1] >= n)]
            lamp_close[pl[:, 0]] = True
        if c not in radio_cameras:
            leftover[c] = crowded & need
            continue
        pc = conflict_pairs(pt, intr, separation_px, field_rows)
        pc = pc[need[pc[:, 0]] | need[pc[:, 1]]]
        if partner is None:  # cover rounds light a read partner on purpose (field_plan_cover)
            pc = pc[lit[pc[:, 0]] & lit[pc[:, 1]]]
        lit_by_lamp = lamp_close[pc[:, 0]] | lamp_close[pc[:, 1]]
        zoom = np.zeros(n, bool)  # a pair with a mote beside a lamp: pausing motes does not help
        zoom[pc[lit_by_lamp].ravel()] = True
        pc = pc[~lit_by_lamp]
        pairs.append(pc)
        cam_pairs[c] = pc
        # every needed crowded mote is read in a round, even one whose crowd is all read (paused)
        mine[c] = crowded & need & ~zoom & ~lamp_close
        leftover[c] = crowded & need & (zoom | lamp_close)
    if partner is None:
        colour = colour_conflicts(n, np.vstack(pairs) if pairs else np.zeros((0, 2), int))
        alone = np.zeros(n, bool)  # its neighbours all paused: read in the first class, as the survey does
        for m in mine.values():
            alone |= m & (colour < 0)
        colour[alone] = 0
    else:
        colour, mine = cover_colour(n, cam_pairs, mine, {c: partner.get(c, np.zeros(n, bool)) for c in mine},
                                    None if partner_ok is None else
                                    {c: partner_ok.get(c, np.zeros(n, bool)) for c in mine})
    plan = plan_round_stations if stations else plan_radio_rounds
    rounds = {c: plan(intr, pan_tilt[c], views[c], colour, mine[c], margin_px,
                      views[c][-1] if views[c] else (0.0, 0.0)) for c in mine}
    addr = np.arange(1, n + 1) if addresses is None else np.asarray(addresses, int)
    involved = addr[(colour >= 0) | (crowd if partner is None else False)]  # and pauses the read crowded motes
    span = int(involved.max()) - int(involved.min()) + 1 if involved.size else 0
    packets = math.ceil(span / (8 * PAUSE_MAX_BYTES))
    return RadioSeparation(colour, rounds, leftover, packets * repeats)
