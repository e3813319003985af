"""Predicted field time of a sequential and of a coded survey on one rig model (survey clock).

**Sequential** (the runner's procedure, ``fgloc.survey.runner``): per node the LED is
switched on (one acknowledged radio command), every camera runs the real
:class:`fgloc.camera.led_search.LedLocator` (look where its last reading was, search
the grid nearest-first, centre, read back) on a :class:`ClockedHead` that records every
move, settle, frame and position read instead of moving, then the LED goes off.
Cameras work in parallel, so a node costs the radio plus its slowest camera.

**Coded** (:mod:`fgloc.camera.blink_codes`): one broadcast start (each mote takes its
word from the book by its address, ``drivers/tinyos/blink.py``; or, the old way, one
unicast start per mote), then every camera records ``frames_per_view`` frames (or
fields) in each view of its plan (:mod:`fgloc.survey.view_planner`), all cameras in
parallel, then one stop broadcast. ``retry_fraction`` of the views are retried right away
without moving (motes missed in the first window): a new burst (the default) or, with
``retry_frames``, the recording continues for that many frames and is decoded in
sliding windows (:func:`fgloc.camera.blink_decoder.decode_windows`). Motes too close to
separate at the survey zoom are recorded again in refinement passes at the lowest zoom
that separates them (:func:`fgloc.survey.view_planner.plan_refinement`,
:func:`refinement_ops`), retried with ``refine_retry_fraction``.

**Radio separation** (optional, ``radio_rounds`` of :func:`coded_survey_time`; planned
and priced in :mod:`fgloc.survey.field_plan_radio`, whose names this module re-exports):
instead of zooming, crowded motes are separated in time, one colour class lit per round;
with ``round_frames`` (short rounds) each round view records fewer samples, decoded
against the class's candidates.

**Pair decoding** (optional, :func:`pair_decoding`): a crowded group of exactly two
motes in a camera's wide view is labelled by the pair decoder
(:mod:`fgloc.camera.blink_pairs`) with the measured success rate; those motes need no
refinement or radio round from that camera. **Group decoding** (optional,
:func:`group_decoding`): the same for crowded groups of exactly three motes
(:mod:`fgloc.camera.blink_groups`).

Angles radians, times seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import LedLocator, PinholePixelModel, SearchConfig, Spot
from fgloc.core.geometry import FloatArray
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
    Zoom,
    parallel,
    price,
    sum_times,
)
from fgloc.survey.field_plan_radio import (  # noqa: F401  (RadioSeparation, radio_separation, view-major rounds: re-exported)
    RadioSeparation,
    coded_view_ops,
    radio_round_time,
    radio_separation,
    view_major_round_time,
    view_major_slots,
)
from fgloc.survey.view_planner import RadioRound, RefinePass, conflict_pairs, neighbour_px


class ClockedHead:
    """A head that only keeps time: moves are instant in code and priced as clock operations.

    ``grab_frame`` returns a 1x1 placeholder; :meth:`spot_finder` says where the lit
    target appears (pinhole geometry), so the real search logic runs unchanged.
    """

    def __init__(self, pixels: PinholePixelModel, margin_px: float = 5.0) -> None:
        self.pixels = pixels
        self.margin_px = margin_px
        self.pan = 0.0
        self.tilt = 0.0
        self.ops: list[Op] = []
        self.target: FloatArray | None = None
        self.centring = False

    def move_to(self, pan: float, tilt: float) -> None:
        dpan = math.remainder(pan - self.pan, 2 * math.pi)
        self.ops += [Slew(dpan, tilt - self.tilt, "centring" if self.centring else "slew"), Settle()]
        self.pan, self.tilt = pan, tilt

    def position(self) -> tuple[float, float]:
        self.ops.append(PositionRead())
        return self.pan, self.tilt

    def set_zoom(self, zoom: float) -> None:
        pass

    def zoom(self) -> float:
        return 0.0

    def stop(self) -> None:
        pass

    def home(self) -> None:
        self.move_to(0.0, 0.0)

    def grab_frame(self) -> np.ndarray:
        self.ops.append(Frames(1))
        return np.zeros((1, 1), np.uint8)

    def spot_finder(self, _frame: np.ndarray) -> Spot | None:
        if self.target is None:
            return None
        px = self.pixels.bearing_to_pixel(self.pan, self.tilt, self.target)
        k = self.pixels.intrinsics
        if px is None or not (self.margin_px <= px[0] <= k.width - 1 - self.margin_px
                              and self.margin_px <= px[1] <= k.height - 1 - self.margin_px):
            return None
        self.centring = True  # every move after the first sighting is a centring step
        return Spot(px[0], px[1], 255.0)


@dataclass
class SequentialTime:
    """Field time of a sequential survey and its counts."""

    time: FieldTime
    nodes: int
    looks: int
    not_found: int
    per_camera: dict[str, FieldTime] = field(default_factory=dict)


def sequential_survey_time(
    bearings: dict[str, FloatArray], intr: CameraIntrinsics, search: dict[str, SearchConfig], timing: RigTiming,
) -> SequentialTime:
    """Price the sequential survey. ``bearings[camera]`` is (N, 3) base-frame directions of the
    nodes in survey order (NaN rows: not visible); ``search[camera]`` its search range."""
    cams = list(bearings)
    n = len(next(iter(bearings.values())))
    pixels = PinholePixelModel(intr)
    heads = {c: ClockedHead(pixels) for c in cams}
    locators = {c: LedLocator(search[c], pixels, spot_finder=heads[c].spot_finder) for c in cams}
    last: dict[str, tuple[float, float] | None] = dict.fromkeys(cams)
    total: list[FieldTime] = []
    per_cam = {c: FieldTime({}) for c in cams}
    looks = missing = 0
    for j in range(n):
        lanes = []
        for c in cams:
            h = heads[c]
            h.ops, h.centring = [], False
            b = bearings[c][j]
            h.target = None if not np.all(np.isfinite(b)) else np.asarray(b, float)
            prev = last[c]
            start = prev if prev is not None else (0.5 * (search[c].pan_min + search[c].pan_max), 0.0)
            got = locators[c].locate(lambda op, h=h: op(h), start)  # type: ignore[misc]
            if got is None:
                missing += 1
            else:
                last[c] = got
            looks += sum(isinstance(o, Frames) for o in h.ops)
            lane = price(h.ops, timing)
            per_cam[c] = per_cam[c] + lane
            lanes.append(lane)
        total.append(price([Radio(unicast=1)], timing) + parallel(lanes) + price([Radio(unicast=1)], timing))
    return SequentialTime(sum_times(total), n, looks, missing, per_cam)


@dataclass
class CodedTime:
    """Field time of a coded survey and its counts."""

    time: FieldTime
    views: dict[str, int]
    frames_per_view: int
    refinements: int  #: refinement views (all cameras)


def coded_survey_time(
    views: dict[str, list[tuple[float, float]]], n_motes: int, frames_per_view: int, timing: RigTiming,
    retry_fraction: float = 0.0, refine: dict[str, list[RefinePass]] | None = None,
    broadcast_start: bool = True, start_broadcasts: int = 1, restarts: int = 0,
    extend_frames: int = 0, retry_frames: int | None = None, refine_retry_fraction: float = 0.0,
    zoom_out: bool = True, resync_s: float | None = None,
    radio_rounds: dict[str, list[RadioRound]] | None = None, pause_broadcasts: int = 3,
    radio_retry_fraction: float = 0.0, round_frames: int | None = None, round_order: str = "class",
) -> CodedTime:
    """Price the coded survey (see the module docstring). ``refine[camera]`` are its refinement
    passes (ascending zoom): zoom in to each pass's level, record its views, and after the
    last pass zoom back out (``zoom_out``; False: the survey ends at the last recording,
    as the sequential survey ends at its last node, and the head is left zoomed in).
    ``broadcast_start``: one broadcast starts every mote (each takes
    its word by address; sent ``start_broadcasts`` times), plus ``restarts`` unicast starts for motes that missed it;
    otherwise one unicast start per mote. A stop broadcast ends the survey.
    ``extend_frames``, ``retry_frames``: see :func:`coded_view_ops` (wide views retried
    with ``retry_fraction``, refinement views with ``refine_retry_fraction``).
    ``resync_s``: a synchronized book's start broadcast is repeated every ``resync_s``
    seconds of the survey (``start_broadcasts`` more broadcasts each time, priced on the
    radio lane, conservatively in series with the cameras).
    ``radio_rounds[camera]``: radio separation (:func:`radio_round_time`, ``pause_broadcasts``
    per pause update, ``radio_retry_fraction`` of round views retried) between the wide
    pass and the refinement. Every camera finishes its wide pass before the first pause,
    each round waits for the slowest camera, and one resume update precedes the
    refinement (see :func:`_coded_with_rounds`). ``round_frames``: short rounds, each round
    view records that many samples (:func:`radio_round_time`; None: as a wide view).
    ``round_order``: "class" (each class in turn, every camera visiting its views) or "view"
    (each camera stays on a view while its classes take turns, :func:`view_major_round_time`)."""
    refine = refine or {}
    if radio_rounds and any(rr.views for rs in radio_rounds.values() for rr in rs):
        return _coded_with_rounds(views, n_motes, frames_per_view, timing, retry_fraction, refine, broadcast_start,
                                  start_broadcasts, restarts, extend_frames, retry_frames, refine_retry_fraction,
                                  zoom_out, resync_s, radio_rounds, pause_broadcasts, radio_retry_fraction,
                                  round_frames, round_order)
    lanes = []
    for cam, vs in views.items():
        ops = coded_view_ops(vs, frames_per_view, retry_fraction, vs[0] if vs else (0.0, 0.0), extend_frames,
                             retry_frames)
        here = vs[-1] if vs else (0.0, 0.0)
        ops += refinement_ops(refine.get(cam, []), frames_per_view, here, refine_retry_fraction, extend_frames,
                              retry_frames, zoom_out)
        lanes.append(price(ops, timing))
    start = Radio(unicast=restarts, broadcast=start_broadcasts) if broadcast_start else Radio(unicast=n_motes)
    radio = price([start, Radio(broadcast=1)], timing)
    cameras = parallel(lanes)
    if resync_s is not None and broadcast_start:
        resyncs = max(0, math.ceil(cameras.total / resync_s) - 1)
        radio = radio + price([Radio(broadcast=resyncs * start_broadcasts)], timing)
    return CodedTime(radio + cameras, {c: len(v) for c, v in views.items()},
                     frames_per_view, sum(len(rp.views) for ps in refine.values() for rp in ps))


def _coded_with_rounds(
    views: dict[str, list[tuple[float, float]]], n_motes: int, frames_per_view: int, timing: RigTiming,
    retry_fraction: float, refine: dict[str, list[RefinePass]], broadcast_start: bool, start_broadcasts: int,
    restarts: int, extend_frames: int, retry_frames: int | None, refine_retry_fraction: float, zoom_out: bool,
    resync_s: float | None, radio_rounds: dict[str, list[RadioRound]], pause_broadcasts: int,
    radio_retry_fraction: float, round_frames: int | None = None, round_order: str = "class",
) -> CodedTime:
    """:func:`coded_survey_time` with radio separation: wide pass (parallel lanes), the rounds
    (:func:`radio_round_time`), one resume update if any refinement follows, then the
    zoom refinement (parallel lanes)."""
    wide = []
    here: dict[str, tuple[float, float]] = {}
    for cam, vs in views.items():
        wide.append(price(coded_view_ops(vs, frames_per_view, retry_fraction, vs[0] if vs else (0.0, 0.0),
                                         extend_frames, retry_frames), timing))
        here[cam] = vs[-1] if vs else (0.0, 0.0)
    rounds, here, _ = radio_round_time(radio_rounds, here, frames_per_view, timing, pause_broadcasts,
                                       radio_retry_fraction, retry_frames, extend_frames, round_frames, round_order)
    ref = [price(refinement_ops(refine.get(cam, []), frames_per_view, here[cam], refine_retry_fraction,
                                extend_frames, retry_frames, zoom_out), timing) for cam in views]
    resume = price([Radio(broadcast=pause_broadcasts)], timing) if any(r.total > 0 for r in ref) else ZERO
    cameras = parallel(wide) + rounds + resume + parallel(ref)
    start = Radio(unicast=restarts, broadcast=start_broadcasts) if broadcast_start else Radio(unicast=n_motes)
    radio = price([start, Radio(broadcast=1)], timing)
    if resync_s is not None and broadcast_start:
        resyncs = max(0, math.ceil(cameras.total / resync_s) - 1)
        radio = radio + price([Radio(broadcast=resyncs * start_broadcasts)], timing)
    return CodedTime(radio + cameras, {c: len(v) for c, v in views.items()},
                     frames_per_view, sum(len(rp.views) for ps in refine.values() for rp in ps))


def refinement_ops(passes: Sequence[RefinePass], frames_per_view: int, start: tuple[float, float],
                   retry_fraction: float = 0.0, extend_frames: int = 0, retry_frames: int | None = None,
                   zoom_out: bool = True) -> list[Op]:
    """Clock operations (phase 'centring') of refinement ``passes`` in order from head position
    ``start`` at the survey zoom: zoom to each pass's level, record its views
    (:func:`coded_view_ops`), and, with ``zoom_out``, zoom back out after the last."""
    ops: list[Op] = []
    here, zoom = start, 0.0
    for rp in passes:
        if not rp.views:
            continue
        ops += [Zoom(rp.zoom - zoom, "centring")]
        ops += [replace(o, phase="centring") for o in coded_view_ops(
            rp.views, frames_per_view, retry_fraction, here, extend_frames, retry_frames)]
        here, zoom = rp.views[-1], rp.zoom
    if zoom and zoom_out:
        ops += [Zoom(zoom, "centring")]
    return ops


def frames_for(code_length: int, periods: int = 3) -> int:
    """Frames per view: ``periods`` code periods (default three: each bit read three times, so
    ~9 % erased samples from drops and repeats rarely erase a bit completely) plus two."""
    return periods * code_length + 2


@dataclass
class PairDecoding:
    """Crowded motes of one camera resolved by pair decoding (:func:`pair_decoding`)."""

    pairs: np.ndarray  #: (P, 2) mote indices of the crowded groups of exactly two
    resolved: np.ndarray  #: (N,) bool: the motes of the pairs the pair decoder resolves
    third_px: np.ndarray  #: (P,) px from the pair to the nearest third mote (either LED)

    @property
    def resolved_pairs(self) -> int:
        return int(self.resolved.sum()) // 2


def pair_rate_table(text: str) -> tuple[tuple[float, float], ...]:
    """Parse ``"RATE"`` or ``"MAX_PX:RATE,...,inf:RATE"`` (ascending bounds on the distance
    to the nearest third mote, px) into :func:`pair_decoding`'s rate table; ValueError when
    malformed or a rate is outside [0, 1]."""
    parts = [p for p in text.split(",") if p.strip()]
    out = []
    for p in parts:
        bound, _, rate = p.rpartition(":")
        r = float(rate)
        b = math.inf if not bound else float(bound)
        if not 0.0 <= r <= 1.0:
            raise ValueError(f"rate {r} not in [0, 1]")
        out.append((b, r))
    if not out or any(a[0] >= b[0] for a, b in zip(out, out[1:])) or out[-1][0] != math.inf:
        raise ValueError(f"bounds must ascend and end with inf ({text})")
    return tuple(out)


def pair_decoding(intr: CameraIntrinsics, pan_tilt: np.ndarray, separation_px: float,
                  rate: float | Sequence[tuple[float, float]], rng: np.random.Generator,
                  field_rows: bool = False) -> PairDecoding:
    """Crowded motes (``pan_tilt`` (N, 2) radians, closer than ``separation_px`` at the wide
    zoom, tangent plane as :func:`fgloc.survey.view_planner.conflict_pairs`) that form a
    group of **exactly two** (connected components of the conflict graph) are labelled by
    the pair decoder (:mod:`fgloc.camera.blink_pairs`) in the wide view with probability
    ``rate`` each (the resolved share measured by ``scripts/blink_montecarlo.py --pairs``,
    drawn from ``rng``): those need no refinement. ``rate`` may be a table
    ``((max_px, rate), ..., (inf, rate))``: the rate of the first bound above the pair's
    distance to its nearest third mote (px, either LED; :func:`pair_rate_table`), since
    a third LED near the aperture spoils the pair's levels. Larger groups, and the pairs not drawn,
    are refined as before."""
    pt = np.asarray(pan_tilt, float)
    pairs = _pairs_alone(conflict_pairs(pt, intr, separation_px, field_rows), len(pt))
    resolved, third = _draw_resolved(pairs, pt, intr, separation_px, rate, rng, field_rows)
    return PairDecoding(pairs, resolved, third)


def _pairs_alone(edges: np.ndarray, n: int) -> np.ndarray:
    """The edges (E, 2) of a graph on ``n`` vertices whose two ends have no other edge: its
    connected components of exactly two."""
    if not edges.size:
        return edges
    degree = np.bincount(edges.ravel(), minlength=n)
    return edges[(degree[edges[:, 0]] == 1) & (degree[edges[:, 1]] == 1)]


def _rates(rate: float | Sequence[tuple[float, float]], distances: np.ndarray) -> np.ndarray:
    """Per distance (px), ``rate`` when a number, else the rate of the first table bound above it."""
    if isinstance(rate, (int, float)):
        return np.full(len(distances), float(rate))
    return np.array([next((r for b, r in rate if t < b), rate[-1][1]) for t in distances])


def near_decoding(intr: CameraIntrinsics, pan_tilt: np.ndarray, low_px: float, high_px: float,
                  rate: float | Sequence[tuple[float, float]], rng: np.random.Generator,
                  field_rows: bool = False) -> np.ndarray:
    """(N,) bool: the motes whose nearest neighbour lies ``low_px`` to ``high_px`` away at the wide
    zoom (tangent plane as :func:`fgloc.survey.view_planner.neighbour_px`) that the decoder
    reads there, each drawn (in mote order, one ``rng.random`` each) with ``rate``: a number,
    or a table ``((max_px, rate), ..., (inf, rate))`` by that distance (:func:`pair_rate_table`),
    measured by ``scripts/blink_near_montecarlo.py`` on pairs with no third mote near. So only
    a mote whose one neighbour within ``high_px`` has no other there either (a pair alone at
    ``high_px``) is drawn; a mote in a larger crowd is not read. Closer than ``low_px`` is a
    crowd (pair and group decoding); ``high_px`` on is isolated."""
    pt = np.asarray(pan_tilt, float)
    d = neighbour_px(pt, intr, field_rows)
    alone = np.zeros(len(pt), bool)
    alone[_pairs_alone(conflict_pairs(pt, intr, high_px, field_rows), len(pt)).ravel()] = True
    return (d >= low_px) & (d < high_px) & alone & (rng.random(len(d)) < _rates(rate, d))


@dataclass(frozen=True)
class GroupDecoding:
    """Which crowded groups of exactly three motes the group decoder labels, per camera."""

    groups: np.ndarray  #: (G, 3) mote indices of the crowded groups of exactly three
    resolved: np.ndarray  #: (N,) bool: the motes of the groups the group decoder resolves
    fourth_px: np.ndarray  #: (G,) px from the group to the nearest fourth mote (any LED)

    @property
    def resolved_groups(self) -> int:
        return int(self.resolved.sum()) // 3


def group_decoding(intr: CameraIntrinsics, pan_tilt: np.ndarray, separation_px: float,
                   rate: float | Sequence[tuple[float, float]], rng: np.random.Generator,
                   field_rows: bool = False) -> GroupDecoding:
    """As :func:`pair_decoding` for crowded groups of **exactly three** motes (connected
    components of three in the conflict graph at ``separation_px``): each is labelled by
    the group decoder (:mod:`fgloc.camera.blink_groups`, ``PairConfig(max_group=3)``) in
    the wide view with probability ``rate`` (measured by ``scripts/blink_montecarlo.py
    --groups``; or a table by the distance to the nearest fourth mote, px, any LED of the
    group), drawn from ``rng``; those motes need no refinement."""
    pt = np.asarray(pan_tilt, float)
    groups = np.array(_components(conflict_pairs(pt, intr, separation_px, field_rows), len(pt), 3),
                      np.int64).reshape(-1, 3)
    resolved, fourth = _draw_resolved(groups, pt, intr, separation_px, rate, rng, field_rows)
    return GroupDecoding(groups, resolved, fourth)


def _components(edges: np.ndarray, n: int, size: int) -> list[list[int]]:
    """The connected components of exactly ``size`` vertices (sorted, in ascending order) of
    the graph on ``n`` vertices with ``edges`` (E, 2)."""
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for x, y in edges.tolist():
        parent[root(x)] = root(y)
    members: dict[int, list[int]] = {}
    for i in {int(v) for v in edges.ravel().tolist()}:
        members.setdefault(root(i), []).append(i)
    return sorted(sorted(m) for m in members.values() if len(m) == size)


def crowd_decoding(intr: CameraIntrinsics, pan_tilt: np.ndarray, separation_px: float,
                   rates: Mapping[int, float | Sequence[tuple[float, float]]], rng: np.random.Generator,
                   field_rows: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Crowds of ``k`` motes alone at the decoder's separation (connected components of
    exactly ``k`` in the conflict graph at ``separation_px``, for each ``k`` of ``rates``):
    which of their motes the decoder reads in the wide view. Each mote is drawn (crowds in
    ascending ``k``, then component order, then mote order; one ``rng.random`` per mote)
    with ``rates[k]``: a number, or a table ``((max_px, rate), ..., (inf, rate))`` by its
    distance to its nearest neighbour (px; :func:`pair_rate_table`), as measured by
    ``scripts/blink_near_montecarlo.py --group k --pairs`` (pair decoding, and group
    decoding of three LEDs, on; no other mote within twice the separation). Returns
    ((N,) bool read, (N,) bool in such a crowd). The draws are per mote, independent:
    the Monte Carlo measured the read share per mote, not which motes of a crowd are read
    together."""
    pt = np.asarray(pan_tilt, float)
    edges = conflict_pairs(pt, intr, separation_px, field_rows)
    d = neighbour_px(pt, intr, field_rows)
    read, member = np.zeros(len(pt), bool), np.zeros(len(pt), bool)
    for k in sorted(rates):
        for m in _components(edges, len(pt), k):
            member[m] = True
            read[m] = rng.random(k) < _rates(rates[k], d[m])
    return read, member


def _draw_resolved(groups: np.ndarray, pt: np.ndarray, intr: CameraIntrinsics, separation_px: float,
                   rate: float | Sequence[tuple[float, float]], rng: np.random.Generator,
                   field_rows: bool) -> tuple[np.ndarray, np.ndarray]:
    """For crowded groups (G, k) of motes: each group's distance (px) to the nearest other mote
    within 3 x ``separation_px`` of any of its LEDs (inf beyond), and which motes are resolved
    when each group is drawn (in order, one ``rng.random`` each) with its ``rate`` (a number,
    or the rate of the first table bound above that distance)."""
    resolved = np.zeros(len(pt), bool)
    nearest = np.full(len(groups), np.inf)
    if not len(groups):
        return resolved, nearest
    wide = conflict_pairs(pt, intr, 3.0 * separation_px, field_rows)  # neighbours up to 12 px
    adj: dict[int, set[int]] = {}
    for x, y in wide.tolist():
        adj.setdefault(x, set()).add(y)
        adj.setdefault(y, set()).add(x)
    fy = intr.fy / (2.0 if field_rows else 1.0)
    for k, g in enumerate(groups.tolist()):
        for m in set().union(*(adj.get(s, set()) for s in g)) - set(g):
            for s in g:
                dp = math.remainder(pt[m, 0] - pt[s, 0], 2 * math.pi) * math.cos(0.5 * (pt[m, 1] + pt[s, 1]))
                nearest[k] = min(nearest[k], math.hypot(dp * intr.fx, (pt[m, 1] - pt[s, 1]) * fy))
    hit = rng.random(len(groups)) < _rates(rate, nearest)
    resolved[groups[hit].ravel()] = True
    return resolved, nearest
