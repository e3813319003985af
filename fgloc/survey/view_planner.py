"""Plan the views one camera records in a coded survey: cover the search region in few tiles.

The region is a set of base-frame directions (radians, ``(pan, tilt)`` rows) to cover:
a sampled pan-tilt box (:func:`box_targets`) or the directions of a sampled deployment
area. A view at head (pan, tilt) *covers* a target when the target projects inside the
image at least ``margin_px`` from the border, by the exact composition of
:mod:`fgloc.camera.pixel_angles` (so views near the nadir, whose footprint spans a wide
range of pan, are used as such). Views are chosen greedily (largest number of still
uncovered targets first, candidates on a grid of ``step`` x the field of view), then
ordered nearest-neighbour from the head's start position so slews stay short.

Crowded targets (:func:`plan_refinement`): targets too close to a neighbour to be
separated at the survey zoom are recorded again, each at the lowest zoom of a short
ladder that separates it, in tiles planned the same way; targets no zoom separates are
counted, not chased.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import in_image, pan_tilt_to_pixel
from fgloc.core.geometry import pan_tilt_bearing


def box_targets(pan_min: float, pan_max: float, tilt_min: float, tilt_max: float, step: float) -> np.ndarray:
    """(M, 2) (pan, tilt) samples of a box, ``step`` radians apart (the edges included)."""
    pans = np.linspace(pan_min, pan_max, max(2, math.ceil((pan_max - pan_min) / step) + 1))
    tilts = np.linspace(tilt_min, tilt_max, max(2, math.ceil((tilt_max - tilt_min) / step) + 1))
    pp, tt = np.meshgrid(pans, tilts)
    return np.column_stack([pp.ravel(), tt.ravel()])


def coverage(intr: CameraIntrinsics, targets: np.ndarray, views: np.ndarray, margin_px: float) -> np.ndarray:
    """(V, M) bool: view v (head pan, tilt) sees target m at least ``margin_px`` inside the image."""
    out = np.zeros((len(views), len(targets)), dtype=bool)
    for v, (p, t) in enumerate(views):
        uv, front = pan_tilt_to_pixel(intr, targets[:, 0], targets[:, 1], float(p), float(t))
        out[v] = front & in_image(intr, uv, margin_px)
    return out


def plan_views(
    intr: CameraIntrinsics, targets: np.ndarray, margin_px: float = 12.0, step: float = 0.125,
    start: tuple[float, float] = (0.0, 0.0), tilt_limits: tuple[float, float] = (-math.pi / 2, math.pi / 2),
    minimal: bool = False, groups: np.ndarray | None = None,
) -> list[tuple[float, float]]:
    """Head positions (pan, tilt) radians whose views cover every target, in visiting order.

    Targets no candidate view can cover (beyond the tilt limits) are left out silently;
    :func:`coverage` tells which are covered. ``minimal``: the fewest candidate views that
    cover them (:func:`fewest_views`) instead of the greedy choice, when the greedy choice has
    at most :data:`FEWEST_MAX_VIEWS` views; with ``groups`` (a group
    id per target, e.g. the directions around one blob) a view counts for a group only when it
    covers all its targets, so no group is split between two views' borders (a group no view
    covers whole is covered target by target).
    """
    targets = np.asarray(targets, dtype=float)
    if targets.size == 0:
        return []
    hfov = 2.0 * math.atan(intr.width / (2.0 * intr.fx))
    vfov = 2.0 * math.atan(intr.height / (2.0 * intr.fy))
    centre = np.mean(pan_tilt_bearing(targets[:, 0], targets[:, 1]), axis=0)
    c_pan = math.atan2(centre[1], centre[0])
    rel = np.remainder(targets[:, 0] - c_pan + math.pi, 2.0 * math.pi) - math.pi + c_pan
    pans = np.arange(rel.min(), rel.max() + step * hfov, step * hfov)
    t_lo = max(float(targets[:, 1].min()), tilt_limits[0])
    t_hi = min(float(targets[:, 1].max()), tilt_limits[1])
    tilts = np.arange(t_lo, t_hi + step * vfov, step * vfov)
    tilts = np.clip(tilts, *tilt_limits)
    cand = np.array([(p, t) for t in tilts for p in pans])
    cov = coverage(intr, targets, cand, margin_px)
    todo = cov.any(axis=0)
    chosen: list[int] = []
    while todo.any():
        gain = (cov & todo).sum(axis=1)
        best = int(np.argmax(gain))
        if gain[best] == 0:
            break
        chosen.append(best)
        todo &= ~cov[best]
    if minimal and 1 < len(chosen) <= FEWEST_MAX_VIEWS:
        fewest = fewest_views(cov if groups is None else whole_groups(cov, np.asarray(groups)))
        if fewest is not None and (groups is not None or len(fewest) < len(chosen)):
            chosen = fewest
    return nearest_first([(float(cand[i, 0]), float(cand[i, 1])) for i in chosen], start)


def whole_groups(cov: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(V, K) bool: per view of ``cov`` ((V, M), :func:`coverage`), whether it covers every target
    of each group (``groups``: (M,) group ids) that some view covers whole; the targets of the
    other groups follow as their own columns."""
    ids = np.unique(groups)
    whole = np.stack([cov[:, groups == g].all(axis=1) for g in ids], axis=1)
    split = np.isin(groups, ids[~whole.any(axis=0)])
    return np.concatenate([whole[:, whole.any(axis=0)], cov[:, split]], axis=1)


#: the largest greedy cover :func:`plan_views` tries to shrink with :func:`fewest_views`; a larger
#: one is kept. A count, so the plan does not depend on the machine. A large cover is where the
#: integer program stalls: the example rig's 340 x 113 deg box at a 40 deg field of view (2170
#: candidate views, greedy 59) had not returned after several minutes in the test suite.
#: The benchmark's greedy covers (scripts/coded_survey.py, wide passes and rungs) take 1-14 views.
FEWEST_MAX_VIEWS = 24

#: branch-and-bound nodes :func:`fewest_views` may explore (a count, not a time: the plan must not
#: depend on the machine, so a resumed survey plans the same views)
FEWEST_NODE_LIMIT = 20000


def fewest_views(cov: np.ndarray) -> list[int] | None:
    """The fewest rows of ``cov`` ((V, M) bool, :func:`coverage`) that together cover every
    column some row covers: a minimum set cover, solved as a 0-1 integer program by HiGHS
    (``scipy.optimize.milp``), deterministic for the same input. None when the solver finds no
    cover within :data:`FEWEST_NODE_LIMIT` nodes. The greedy cover can need half again as many:
    a 65 x 51 deg view over a 100 x 60 deg search box, greedy 6 views, fewest 4."""
    need = cov.any(axis=0)
    if not need.any():
        return []
    chosen = list(_fewest_cover(np.packbits(cov, axis=1).tobytes(), cov.shape))
    return chosen if bool(np.all(np.asarray(cov[chosen].any(axis=0))[need])) else None


@functools.lru_cache(maxsize=64)
def _fewest_cover(packed: bytes, shape: tuple[int, int]) -> tuple[int, ...]:
    """:func:`fewest_views`' integer program on the coverage ``packed`` by rows (``np.packbits``),
    remembered: the surveys of one process (a test session) often plan the same box again."""
    from scipy.optimize import Bounds, LinearConstraint, milp

    cov = np.unpackbits(np.frombuffer(packed, np.uint8).reshape(shape[0], -1), axis=1, count=shape[1]).astype(bool)
    need = cov.any(axis=0)
    a = cov[:, need].T.astype(float)
    res = milp(c=np.ones(len(cov)), constraints=LinearConstraint(a, lb=1.0, ub=np.inf),
               integrality=np.ones(len(cov)), bounds=Bounds(0.0, 1.0), options={"node_limit": FEWEST_NODE_LIMIT})
    return () if res.x is None else tuple(int(i) for i in np.flatnonzero(res.x > 0.5))


def nearest_first(views: list[tuple[float, float]], start: tuple[float, float]) -> list[tuple[float, float]]:
    """``views`` in nearest-neighbour order from ``start`` (angles between view directions)."""
    order: list[tuple[float, float]] = []
    here = pan_tilt_bearing(*start)
    left = list(views)
    while left:
        d = [math.acos(min(1.0, float(pan_tilt_bearing(*v) @ here))) for v in left]
        k = int(np.argmin(d))
        order.append(left.pop(k))
        here = pan_tilt_bearing(*order[-1])
    return order


def neighbour_px(pan_tilt: np.ndarray, intr: CameraIntrinsics, field_rows: bool = False) -> np.ndarray:
    """(N,) distance in pixels (at ``intr``'s focal lengths) from each target to its nearest
    neighbour, in the tangent plane at the target: ``dx = dpan cos(tilt) fx``,
    ``dy = dtilt fy`` (image x along pan, y along tilt, as at a view's centre).
    ``field_rows``: one video field (every second row), so ``fy`` is halved."""
    pt = np.asarray(pan_tilt, dtype=float)
    if len(pt) < 2:
        return np.full(len(pt), np.inf)
    fy = intr.fy / (2.0 if field_rows else 1.0)
    dpan = np.remainder(pt[:, None, 0] - pt[None, :, 0] + math.pi, 2.0 * math.pi) - math.pi
    dx = dpan * np.cos(0.5 * (pt[:, None, 1] + pt[None, :, 1])) * intr.fx
    dy = (pt[:, None, 1] - pt[None, :, 1]) * fy
    d = np.hypot(dx, dy)
    np.fill_diagonal(d, np.inf)
    return np.asarray(d.min(axis=1))


@dataclass(frozen=True)
class RefinePass:
    """Views recorded at one zoom (fraction of the optical range) to separate crowded targets."""

    zoom: float
    views: list[tuple[float, float]]
    targets: int  #: targets this pass is for


def plan_refinement(
    intr: CameraIntrinsics, pan_tilt: np.ndarray, separation_px: float, levels: tuple[float, ...] = (1 / 9, 3 / 9, 1.0),
    margin_px: float = 12.0, start: tuple[float, float] = (0.0, 0.0), field_rows: bool = False,
    max_magnification: float = 10.0, needed: np.ndarray | None = None, share_tiles: bool = False,
) -> tuple[list[RefinePass], int]:
    """Zoom in only where needed: targets whose nearest neighbour is closer than
    ``separation_px`` at the survey zoom (``intr``) are refined at the lowest zoom of
    ``levels`` (ascending) that puts the neighbour ``separation_px`` away, each level's
    targets covered by :func:`plan_views` at that zoom (tiles, not one view per target).
    Returns the passes (ascending zoom, empty levels left out) and the number of targets
    no level separates (reported missed from this camera, not recorded again).
    ``needed`` (bool per target, default all): crowded targets not needed from this
    camera (e.g. resolved by two other cameras, :func:`needed_from`) are neither refined
    nor counted; their neighbours still count as crowding.
    ``share_tiles``: plan the levels from the highest zoom down, and let a tile of a
    higher zoom also serve the lower-zoom targets it covers (a higher zoom separates
    them too), so the lower levels need fewer tiles; recorded in ascending zoom all the same."""
    pt = np.asarray(pan_tilt, dtype=float)
    d = neighbour_px(pt, intr, field_rows)
    need = separation_px / np.maximum(d, 1e-12)  # magnification each target needs
    passes: list[RefinePass] = []
    done = need <= 1.0
    if needed is not None:
        done |= ~np.asarray(needed, dtype=bool)
    here = start
    if share_tiles:
        todo = ~done
        assigned = np.full(len(pt), -1)
        mags = [intr.at_zoom(z, max_magnification).fx / intr.fx for z in levels]
        for li, mag in enumerate(mags):
            assigned[todo & (assigned < 0) & (need <= mag)] = li
        plans: dict[int, list[tuple[float, float]]] = {}
        for li in range(len(levels) - 1, -1, -1):
            mine = todo & (assigned == li)
            if not mine.any():
                continue
            zi = intr.at_zoom(levels[li], max_magnification)
            plans[li] = plan_views(zi, pt[mine], margin_px)
            if plans[li]:  # lower-level targets inside these tiles are served here
                cov = coverage(zi, pt, np.array(plans[li]), margin_px).any(axis=0)
                todo &= ~(cov & (assigned < li) & (assigned >= 0))
        for li in sorted(plans):
            if plans[li]:
                views = nearest_first(plans[li], here)
                passes.append(RefinePass(levels[li], views, int((assigned == li).sum())))
                here = views[-1]
        done |= assigned >= 0
        return passes, int((~done).sum())
    here = start
    for z in levels:
        mag = intr.at_zoom(z, max_magnification).fx / intr.fx
        mine = ~done & (need <= mag)
        if mine.any():
            views = plan_views(intr.at_zoom(z, max_magnification), pt[mine], margin_px, start=here)
            passes.append(RefinePass(z, views, int(mine.sum())))
            here = views[-1] if views else here
        done |= mine
    return passes, int((~done).sum())


def needed_from(resolved: dict[str, np.ndarray], cameras_needed: int = 2) -> dict[str, np.ndarray]:
    """Which targets each camera must still resolve (by refinement): ``resolved[camera]``
    says (bool per target, same target order for every camera) which targets that
    camera's survey-zoom views already separate. A target resolved by at least
    ``cameras_needed`` other cameras is not needed from a camera that does not resolve
    it (two bearings locate a node on the plane); otherwise every camera must resolve
    it. With two cameras every target is needed from both."""
    cams = list(resolved)
    count = np.sum([np.asarray(resolved[c], dtype=bool) for c in cams], axis=0)
    return {c: count - np.asarray(resolved[c], dtype=int) < cameras_needed for c in cams}


# ----- radio separation: crowded motes separated in time (pause by colour class) -------------------
def conflict_pairs(pan_tilt: np.ndarray, intr: CameraIntrinsics, separation_px: float,
                   field_rows: bool = False) -> np.ndarray:
    """(E, 2) index pairs ``i < j`` of targets closer than ``separation_px`` to each other at
    ``intr``'s focal lengths (tangent-plane distance, as :func:`neighbour_px`)."""
    pt = np.asarray(pan_tilt, dtype=float)
    if len(pt) < 2:
        return np.zeros((0, 2), dtype=int)
    fy = intr.fy / (2.0 if field_rows else 1.0)
    dpan = np.remainder(pt[:, None, 0] - pt[None, :, 0] + math.pi, 2.0 * math.pi) - math.pi
    dx = dpan * np.cos(0.5 * (pt[:, None, 1] + pt[None, :, 1])) * intr.fx
    dy = (pt[:, None, 1] - pt[None, :, 1]) * fy
    i, j = np.nonzero(np.triu(np.hypot(dx, dy) < separation_px, k=1))
    return np.column_stack([i, j]).astype(int)


def colour_conflicts(n: int, pairs: np.ndarray) -> np.ndarray:
    """Greedy colouring (DSatur: next the target whose neighbours already use the most
    colours, ties by degree then index; smallest free colour) of the conflict graph on
    ``n`` targets with edges ``pairs``: (n,) colour per target, -1 for targets in no pair.
    Adjacent targets always get different colours; a 2-colourable graph gets 2."""
    colour = np.full(n, -1, dtype=int)
    adj: dict[int, set[int]] = {}
    for a, b in np.asarray(pairs, dtype=int).reshape(-1, 2).tolist():
        if a != b:
            adj.setdefault(a, set()).add(b)
            adj.setdefault(b, set()).add(a)
    seen: dict[int, set[int]] = {v: set() for v in adj}
    left = set(adj)
    while left:
        v = max(left, key=lambda u: (len(seen[u]), len(adj[u]), -u))
        c = next(c for c in range(len(seen[v]) + 1) if c not in seen[v])
        colour[v] = c
        left.discard(v)
        for u in adj[v]:
            seen[u].add(c)
    return colour


def greedy_cover(cov: np.ndarray, targets: np.ndarray, counts: dict[int, int] | None = None) -> list[int]:
    """Rows of ``cov`` ((V, M) bool: view v covers target m) that together cover every coverable
    target of ``targets`` ((M,) bool), greedily (most still uncovered first; ties: the lowest
    row), in the order picked. ``counts``, when given, receives per picked row the targets it
    was picked for (each target counted once)."""
    todo = np.asarray(targets, dtype=bool) & (cov.any(axis=0) if len(cov) else False)
    picked: list[int] = []
    while todo.any():
        best = int(np.argmax((cov & todo).sum(axis=1)))
        picked.append(best)
        if counts is not None:
            counts[best] = int((cov[best] & todo).sum())
        todo &= ~cov[best]
    return picked


@dataclass(frozen=True)
class RadioRound:
    """One colour class of a radio separation, seen by one camera: the wide views it records
    again while every other class's conflicting motes are paused."""

    colour: int
    views: list[tuple[float, float]]
    view_targets: tuple[int, ...]  #: per view, the class's conflicting targets it is recorded for


def plan_radio_rounds(
    intr: CameraIntrinsics, pan_tilt: np.ndarray, views: list[tuple[float, float]], colour: np.ndarray,
    targets: np.ndarray, margin_px: float = 12.0, start: tuple[float, float] = (0.0, 0.0),
    replan: bool = True,
) -> list[RadioRound]:
    """Per colour class (ascending), the views at the wide zoom that together cover the
    camera's ``targets`` (bool per target: the conflicting targets this camera must read)
    of that class: a greedy set cover over its wide ``views``, or, with ``replan`` and when
    it needs fewer views, new wide-zoom views planned around the class's targets alone
    (:func:`plan_views`). Views in nearest-neighbour order from the head position (the
    last view of the previous round). Classes with nothing to read here give a round
    without views. Targets no wide view covers are left out (as :func:`plan_views`)."""
    pt = np.asarray(pan_tilt, dtype=float)
    if not views:
        return []
    rounds = []
    here = start
    for c in range(int(colour.max()) + 1 if colour.size else 0):
        mine = np.asarray(targets, dtype=bool) & (colour == c)
        chosen = [views[i] for i in greedy_cover(coverage(intr, pt, np.array(views), margin_px), mine)]
        if replan and mine.any():
            fresh = plan_views(intr, pt[mine], margin_px, start=here)
            if len(fresh) < len(chosen):
                chosen = fresh
        picked = nearest_first(chosen, here)
        counts = (tuple(int(x) for x in (coverage(intr, pt, np.array(picked), margin_px) & mine).sum(axis=1))
                  if picked else ())
        rounds.append(RadioRound(c, picked, counts))
        here = picked[-1] if picked else here
    return rounds


def plan_round_stations(
    intr: CameraIntrinsics, pan_tilt: np.ndarray, views: list[tuple[float, float]], colour: np.ndarray,
    targets: np.ndarray, margin_px: float = 12.0, start: tuple[float, float] = (0.0, 0.0),
) -> list[RadioRound]:
    """Radio rounds whose views are shared across colour classes (*stations*), for the
    view-major order (:func:`fgloc.survey.field_plan_radio.radio_round_time` ``order="view"``):
    one set of wide-zoom views covers the camera's ``targets`` of every class (a greedy cover
    over its wide ``views``, or :func:`plan_views` around the targets when that needs fewer),
    and each class is read at the fewest of these stations that cover its targets (greedy).
    Returned as :func:`plan_radio_rounds` does (one :class:`RadioRound` per class, ascending),
    but the same station appears, as the identical (pan, tilt) tuple, in every class it
    serves, so a camera can stay on it while the classes take turns."""
    pt = np.asarray(pan_tilt, dtype=float)
    if not views:
        return []
    mine = np.asarray(targets, dtype=bool) & (colour >= 0)
    chosen = [views[i] for i in greedy_cover(coverage(intr, pt, np.array(views), margin_px), mine)]
    if mine.any():
        fresh = plan_views(intr, pt[mine], margin_px, start=start)
        if len(fresh) < len(chosen):
            chosen = fresh
    stations = nearest_first(chosen, start)
    at = coverage(intr, pt, np.array(stations), margin_px) if stations else np.zeros((0, len(pt)), bool)
    rounds = []
    for c in range(int(colour.max()) + 1 if colour.size else 0):
        counts: dict[int, int] = {}
        greedy_cover(at, mine & (colour == c), counts)
        keep = sorted(counts)  # visiting order of the stations
        rounds.append(RadioRound(c, [stations[i] for i in keep], tuple(counts[i] for i in keep)))
    return rounds


@dataclass(frozen=True)
class Slot:
    """One slot of view-major radio rounds: the lit class and the cameras recording it (camera ->
    index of its view)."""

    lit: int
    views: dict[str, int]


def view_major_schedule(needs: Mapping[str, Sequence[set[int] | frozenset[int]]]) -> list[Slot]:
    """View-major radio rounds: the slots for ``needs`` (camera -> per view, in visiting
    order, the classes that view needs). Pauses are global, so the cameras agree on the lit
    class: each slot lights one class, and every camera whose *current* view (its first
    view with a class left) needs it records it there; the others wait. The class of a
    slot is the one that finishes the most cameras' views (all a view still needs), then
    serves the most cameras (ties: the class lit already, then the lowest): a camera whose
    view is finished moves on while the others record, so it waits less later (at 1000 motes
    and 4 cameras, 15 classes, this is ~20 s shorter than serving the most cameras first).
    Every (camera, view, class) job lands in exactly one slot."""
    left = {c: [set(v) for v in views] for c, views in needs.items()}
    at = {c: 0 for c in left}
    slots: list[Slot] = []
    lit: int | None = None
    while True:
        for c in left:  # skip views with nothing (left) to record
            while at[c] < len(left[c]) and not left[c][at[c]]:
                at[c] += 1
        current = {c: left[c][at[c]] for c in sorted(left) if at[c] < len(left[c])}
        if not current:
            return slots
        demand: dict[int, int] = {}
        for classes in current.values():
            for k in classes:
                demand[k] = demand.get(k, 0) + 1
        # a class that is all a camera's view still needs lets that camera move on
        finishes = {x: sum(1 for classes in current.values() if classes == {x}) for x in demand}
        k = max(demand, key=lambda x: (finishes[x], demand[x], x == lit, -x))
        slots.append(Slot(k, {c: at[c] for c, classes in current.items() if k in classes}))
        for c in slots[-1].views:
            left[c][at[c]].discard(k)
        lit = k
