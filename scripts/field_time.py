"""Predicted field time of sequential vs coded surveys (survey clock), 100/1000 motes, 2/4 cameras.

Scene: motes uniform in the unit square on z = 0 (seeded), cameras 0.1 above the
square's corners ((0,0), (1,0) for two; all four corners for four), each base turned
towards the square's centre. Both surveys search the same region: the pan-tilt box
(sequential) or the directions (coded) of the square seen from each camera.
Camera: 640 x 480, 65 deg horizontal field of view (EVI-D100 wide end).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/field_time.py --miss-rate Q [--frames] [--sync] [--need 2] \
        [--old] [--unicast] [--separate zoom|radio|best] [--head EVI-D100] [--sizes 100x2,1000x4]

``--miss-rate`` is the per-decode miss rate of isolated motes measured by
scripts/blink_montecarlo.py for the same video and book. The coded survey (``Variant``):

* starts every mote by one broadcast sent three times (``--unicast``: one start per mote);
  with ``--sync`` the synchronized book, its start repeated every 10 s (resync);
* decodes fields on interlaced heads (``--frames``: frames);
* records K = 3L + 2 samples per view (``--extend N``: N more code lengths, sliding windows);
* retries a view in which any of its motes is expected to be missed by recording on for
  one more code length without moving (``--burst-retry``: a new burst of K, the old
  pricing); refinement views are retried the same way (``--no-refine-retry``: never);
* refines crowded motes (neighbour within 4 px at the survey zoom) in tiles, a
  higher-zoom tile also serving the lower-zoom targets it covers (``--separate-tiles``:
  not), on the cheapest, per camera, of the zoom ladders ``LADDERS`` priced on the
  clock (``--fixed-ladder``: ``--levels`` only); with ``--need 2``, only where fewer
  than two other cameras resolve the mote;
* ends at its last recording (``--zoom-out``: zooms back out first);
* ``--separate radio``: separates crowded motes in time instead (colour the conflict graph,
  pause the other classes by radio, re-record wide views per class,
  :func:`fgloc.survey.field_plans.radio_separation`); ``--separate best``: the cheapest
  subset of cameras doing so (the others zoom), on the clock. Default ``zoom``.

``--pair-decode RATE``: crowded groups of exactly two motes in a camera's wide view are
labelled by the pair decoder (:mod:`fgloc.camera.blink_pairs`) with the measured success
``RATE`` (or, as ``PX:RATE,...,inf:RATE``, the rate by the distance to the pair's nearest
third mote; seeded draw per pair, :func:`fgloc.survey.field_plans.pair_decoding`) and need
no refinement or radio round from that camera; the rest as before.
``--group-decode RATE`` (or ``PX:RATE,...,inf:RATE`` by the distance to the nearest fourth
mote): the same for crowded groups of exactly three motes and the group decoder
(:mod:`fgloc.camera.blink_groups`, :func:`fgloc.survey.field_plans.group_decoding`; its own
seeded draws, so the pair draws do not change).

``--round-frames K' --round-miss-rate Q`` (short rounds, with ``--separate radio|best``): each
radio-round view records K' samples (as few as L + 2) and labels its blobs against the
class's candidates (:mod:`fgloc.camera.blink_candidates`: in a round only that class is
lit, with known IDs and predicted directions); round views are retried, continuing by one
code length, at the candidate miss rate Q measured by
``scripts/blink_candidates_montecarlo.py --candidates``. Off by default: every figure without it is unchanged.

``--partner-decode RATE --partner-group-decode RATE`` (cover rounds, with ``--separate
radio|best``; ``PX:RATE,...,inf:RATE`` tables as above): a crowded group of exactly two
(three) needs all but one member read in a radio round, the last decoded from the wide view
by the known-partner decoder (:mod:`fgloc.camera.blink_partner`) with the measured rate
(``scripts/blink_montecarlo.py --pairs|--groups --partner``); a failure is read in the
first later round it fits (:mod:`fgloc.survey.field_plan_cover`). ``--partner-any`` with
``--partner-decode 1``: every crowded group leaves one member (an upper bound). Off by default.

``--round-order view`` (with ``--separate radio|best``): view-major rounds. Each camera's
round views are shared across the colour classes (stations,
:func:`fgloc.survey.view_planner.plan_round_stations`) and the camera stays on a station
while the classes it needs there take turns, one lit class per slot
(:func:`fgloc.survey.field_plan_radio.view_major_slots`): fewer slews, more pause updates.
``best``: the cheaper of class- and view-major on the clock. Default ``class``.

``--separation PX --near-decode TABLE``: the decoder's measured separation (about 8 px,
``scripts/blink_near_montecarlo.py``) instead of the 4 px crowd criterion; a mote in a pair
alone within PX, 4 px or more from its neighbour, is read in the wide view at its bin's
share. ``--crowd-decode K=TABLE`` (repeatable, K = 3..5): the motes of crowds of K alone
within PX are read at the share of their nearest-neighbour bin
(:func:`fgloc.survey.field_plans.crowd_decoding`; ``blink_near_montecarlo.py --group K``),
in place of the 4 px pair and group draws inside them. In radio rounds a read crowded mote
is paused like every mote outside the lit class, so it conflicts with nobody.

``--seeds N``: N seeded scenes per size (seeds 0..N-1) and, after the per-scene rows, the
median and range of the speed-up over them.

``--old`` prices the previous plan (rotation-free book, burst retries of wide views only,
separate tiles on the fixed ladder, zoom-out). The sequential column is the same in
every variant.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from field_time_cli import build_parser, check_scene_flags, round_frames_of, variant_from_args  # noqa: E402
from field_time_report import print_header, print_seed_summary, report  # noqa: E402
from field_time_variants import LADDERS, OLD, RESYNC_S, SEPARATION_PX, Variant  # noqa: E402

from fgloc.camera.blink_codes import code_book, sync_code_book  # noqa: E402
from fgloc.camera.intrinsics import CameraIntrinsics  # noqa: E402
from fgloc.camera.led_search import SearchConfig  # noqa: E402
from fgloc.core.geometry import bearing_pan_tilt, rot_z, world_to_base  # noqa: E402
from fgloc.core.model import CameraPose  # noqa: E402
from fgloc.survey.clock import HEAD_MODELS, CameraTiming, RigTiming, price  # noqa: E402
from fgloc.survey.field_plans import (  # noqa: E402
    CodedTime,
    GroupDecoding,
    PairDecoding,
    RadioSeparation,
    SequentialTime,
    coded_survey_time,
    crowd_decoding,
    frames_for,
    group_decoding,
    near_decoding,
    pair_decoding,
    radio_separation,
    refinement_ops,
    sequential_survey_time,
)
from fgloc.survey.view_planner import (  # noqa: E402
    RefinePass,
    coverage,
    needed_from,
    neighbour_px,
    plan_refinement,
    plan_views,
)

#: the names tests and other scripts use (Variant and its constants live in field_time_variants,
#: the command line in field_time_cli, the table in field_time_report)
__all__ = ["LADDERS", "OLD", "RESYNC_S", "SEPARATION_PX", "Variant", "cameras", "field_directions", "main",
           "report", "round_frames_of", "run"]

_SEQUENTIAL: dict[tuple[int, int, int, RigTiming], SequentialTime] = {}  #: the same in every variant


# --- the scene ------------------------------------------------------------------------------------


def cameras(n: int, height: float = 0.1) -> dict[str, CameraPose]:
    """``n`` (1..4) cameras ``cam0``.. ``height`` above the unit square's corners (0,0), (1,0),
    (1,1), (0,1) in that order, each base turned (yaw about z) towards the centre (0.5, 0.5)."""
    corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][:n]
    out = {}
    for i, (x, y) in enumerate(corners):
        yaw = math.atan2(0.5 - y, 0.5 - x)
        out[f"cam{i}"] = CameraPose(np.array([x, y, height]), rot_z(yaw))
    return out


def field_directions(pose: CameraPose, step: float = 0.01) -> np.ndarray:
    """(M, 2) (pan, tilt) radians, in ``pose``'s base frame, of a grid of points ``step`` apart
    over the unit square on z = 0 (the region both surveys search)."""
    g = np.arange(0.0, 1.0 + 1e-9, step)
    xx, yy = np.meshgrid(g, g)
    pts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    p, t = bearing_pan_tilt(world_to_base(pose.rotation, pose.position, pts))
    return np.column_stack([p, t])


@dataclass(frozen=True)
class Scene:
    """One seeded scene as the rig sees it; the per-camera dicts are keyed ``cam0``.. in order."""

    n_motes: int  #: N, uniform in the unit square on z = 0
    n_cams: int  #: cameras asked for (:func:`cameras` places at most four)
    intr: CameraIntrinsics  #: every camera's, at the wide end (640 x 480 px, 65 deg horizontal)
    cams: dict[str, CameraPose]
    bearings: dict[str, np.ndarray]  #: (N, 3) unit directions of the motes in each camera's base frame
    pts: dict[str, np.ndarray]  #: (N, 2) (pan, tilt) radians of the motes from each camera
    searches: dict[str, SearchConfig]  #: the sequential survey's pan-tilt box of the square, radians
    views: dict[str, list[tuple[float, float]]]  #: the coded survey's wide views (pan, tilt) radians, in order


def _search_box(region: np.ndarray) -> SearchConfig:
    """The pan-tilt box (radians) bounding ``region``'s (M, 2) (pan, tilt) directions."""
    return SearchConfig(pan_min=float(region[:, 0].min()), pan_max=float(region[:, 0].max()),
                        tilt_min=float(region[:, 1].min()), tilt_max=float(region[:, 1].max()))


def seeded_scene(n_motes: int, n_cams: int, seed: int) -> Scene:
    """``n_motes`` motes uniform in the unit square on z = 0 (``default_rng(seed)``), seen by
    :func:`cameras` ``(n_cams)``, with each camera's search box and wide views of the square."""
    rng = np.random.default_rng(seed)
    nodes = np.column_stack([rng.uniform(0, 1, (n_motes, 2)), np.zeros(n_motes)])
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    cams = cameras(n_cams)
    bearings, pts, searches, views = {}, {}, {}, {}
    for c, pose in cams.items():
        d = world_to_base(pose.rotation, pose.position, nodes)
        bearings[c] = d / np.linalg.norm(d, axis=1, keepdims=True)
        pts[c] = np.column_stack(bearing_pan_tilt(bearings[c]))
        region = field_directions(pose)
        searches[c] = _search_box(region)
        views[c] = plan_views(intr, region)
    return Scene(n_motes, n_cams, intr, cams, bearings, pts, searches, views)


# --- what the wide views read ---------------------------------------------------------------------


def _retry_fraction(intr: CameraIntrinsics, pt: np.ndarray, views: list[tuple[float, float]], q: float) -> float:
    """Expected fraction of ``views`` with at least one of their motes missed (rate ``q`` each)."""
    if not views:
        return 0.0
    per_view = coverage(intr, pt, np.array(views), 12.0).sum(axis=1)
    return float(np.mean(1.0 - (1.0 - q) ** per_view))


def wide_retry_fraction(scene: Scene, miss_rate: float) -> float:
    """Expected share of the wide views retried (mean over the cameras of :func:`_retry_fraction`)."""
    return sum(_retry_fraction(scene.intr, scene.pts[c], scene.views[c], miss_rate) / scene.n_cams
               for c in scene.cams)


@dataclass(frozen=True)
class WideReads:
    """Which motes each camera reads in its wide views ((N,) bool per camera, or a decoder's draws)."""

    resolved: dict[str, np.ndarray]  #: isolated at the separation, or read by any decoder below
    near: dict[str, np.ndarray]  #: read though the nearest neighbour lies 4 px to the separation away
    pairs: dict[str, PairDecoding]  #: the pair decoder's draws (4 px pairs), less the crowds' motes
    groups: dict[str, GroupDecoding]  #: the group decoder's draws (4 px groups of three), less the crowds'
    crowd_read: dict[str, np.ndarray]  #: motes of crowds alone at the separation that the decoder reads
    crowd_member: dict[str, np.ndarray]  #: motes of those crowds


def wide_reads(scene: Scene, variant: Variant, seed: int, fields: bool) -> WideReads:
    """The decoders' seeded draws (each its own stream ``default_rng([seed, i])``, so turning one
    on leaves the others' draws as they were) and what each camera resolves in its wide views
    (pixels on field rows when ``fields``)."""
    intr, pts, cams, sep = scene.intr, scene.pts, scene.cams, variant.separation_px
    resolved = {c: neighbour_px(pts[c], intr, fields) >= sep for c in cams}
    near_rng = np.random.default_rng([seed, 20])
    near = {c: near_decoding(intr, pts[c], SEPARATION_PX, sep, variant.near_rate, near_rng, fields) for c in cams}
    pair_rng = np.random.default_rng([seed, 16])
    pairs = {c: pair_decoding(intr, pts[c], SEPARATION_PX, variant.pair_rate, pair_rng, fields) for c in cams}
    group_rng = np.random.default_rng([seed, 17])
    groups = {c: group_decoding(intr, pts[c], SEPARATION_PX, variant.group_rate, group_rng, fields) for c in cams}
    crowd_rng = np.random.default_rng([seed, 21])
    crowd = {c: crowd_decoding(intr, pts[c], sep, dict(variant.crowd_rates), crowd_rng, fields) for c in cams}
    for c in cams:  # a crowd's own measured share replaces the 4 px pair and group draws inside it
        pairs[c] = replace(pairs[c], resolved=pairs[c].resolved & ~crowd[c][1])
        groups[c] = replace(groups[c], resolved=groups[c].resolved & ~crowd[c][1])
        resolved[c] = resolved[c] | pairs[c].resolved | groups[c].resolved | near[c] | crowd[c][0]
    return WideReads(resolved, near, pairs, groups, {c: crowd[c][0] for c in cams}, {c: crowd[c][1] for c in cams})


def needed_motes(scene: Scene, reads: WideReads, variant: Variant) -> dict[str, np.ndarray | None]:
    """Which motes ((N,) bool) each camera must still separate by refinement or radio; None: every
    crowded one. With ``variant.need``, only those fewer than that many other cameras resolve;
    motes a decoder the variant turns on reads in the wide view need nothing more from that camera."""
    cams = scene.cams
    needed: dict[str, np.ndarray | None] = (
        dict(needed_from(reads.resolved, variant.need)) if variant.need else {c: None for c in cams})
    read_wide: list[dict[str, np.ndarray]] = []
    if variant.pair_rate:  # pair-decoded motes
        read_wide.append({c: reads.pairs[c].resolved for c in cams})
    if variant.group_rate:  # group-decoded motes
        read_wide.append({c: reads.groups[c].resolved for c in cams})
    if variant.separation_px > SEPARATION_PX:  # motes read in the wide view though a neighbour lies within sep
        read_wide.append(reads.near)
        read_wide.append(reads.crowd_read)
    for read in read_wide:
        needed = {c: (np.ones(scene.n_motes, bool) if needed[c] is None else needed[c]) & ~read[c] for c in cams}
    return needed


@dataclass(frozen=True)
class PartnerDraws:
    """Cover rounds, per camera ((N,) bool): which crowded motes may be left unread in the rounds
    (``eligible``: decodable by the known-partner decoder) and whose decode succeeds (``ok``)."""

    eligible: dict[str, np.ndarray]
    ok: dict[str, np.ndarray]


def partner_draws(scene: Scene, variant: Variant, seed: int, fields: bool) -> PartnerDraws | None:
    """The known-partner decoder's draws (None: cover rounds off). ``partner_any``: every crowded
    mote (closer than 4 px) is eligible and succeeds (an upper bound); otherwise the motes of the
    4 px pairs (groups of three) with ``partner_rate`` (``partner_group_rate``) on, each drawn on
    its own stream ``default_rng([seed, 18])`` (``[seed, 19]``) so the other draws stay as they were."""
    if not (variant.partner_rate or variant.partner_group_rate):
        return None
    intr, pts = scene.intr, scene.pts
    partner_rng = np.random.default_rng([seed, 18])
    group_partner_rng = np.random.default_rng([seed, 19])
    draws = PartnerDraws({}, {})
    for c in scene.cams:
        if variant.partner_any:
            draws.eligible[c] = ~(neighbour_px(pts[c], intr, fields) >= SEPARATION_PX)
            draws.ok[c] = draws.eligible[c].copy()
            continue
        draws.eligible[c] = np.zeros(scene.n_motes, bool)
        draws.ok[c] = np.zeros(scene.n_motes, bool)
        if variant.partner_rate:
            draws.eligible[c] |= pair_decoding(intr, pts[c], SEPARATION_PX, 1.0, np.random.default_rng(0),
                                               fields).resolved
            draws.ok[c] |= pair_decoding(intr, pts[c], SEPARATION_PX, variant.partner_rate, partner_rng,
                                         fields).resolved
        if variant.partner_group_rate:
            draws.eligible[c] |= group_decoding(intr, pts[c], SEPARATION_PX, 1.0, np.random.default_rng(0),
                                                fields).resolved
            draws.ok[c] |= group_decoding(intr, pts[c], SEPARATION_PX, variant.partner_group_rate,
                                          group_partner_rng, fields).resolved
    return draws


# --- the coded survey on the clock ----------------------------------------------------------------


class Refinement(NamedTuple):
    """One camera's zoom refinement (:meth:`CodedPlanner.refinement`)."""

    passes: list[RefinePass]
    lost: int  #: crowded motes it leaves unresolved
    retry: float  #: expected share of its views retried
    views: int  #: its views, all passes


@dataclass(frozen=True)
class CodedPlan:
    """The coded survey priced for one choice of radio cameras and round order."""

    coded: CodedTime
    round_order: str  #: "class" or "view" with radio rounds, "-" without
    unresolved: int  #: crowded motes no refinement resolves (all cameras)
    refine_retry: float  #: expected share of the refinement views retried
    radio_cams: tuple[str, ...]  #: the cameras separating by radio
    classes: int  #: colour classes of the radio separation (0: none)
    round_views: int  #: radio-round views (all cameras)
    radio_retry: float  #: expected share of the radio-round views retried


@dataclass
class CodedPlanner:
    """Prices the coded survey of one scene on ``timing``'s clock (seconds) for any subset of
    cameras separating by radio, the rest refining by zoom; each camera's refinement is planned
    once per role (zoom only, or the leftover of its radio rounds) and reused."""

    scene: Scene
    variant: Variant
    timing: RigTiming  #: the coded survey's clock (the camera at its field rate when decoding fields)
    fields: bool  #: decode fields (pixels on field rows)
    miss_rate: float  #: per-decode miss rate of an isolated mote
    levels: tuple[float, ...]  #: the fixed zoom ladder (fractions of the optical range)
    k: int  #: samples per wide view (periods x L + 2)
    code_length: int  #: L, samples
    retry_views: float  #: expected share of the wide views retried
    needed: dict[str, np.ndarray | None]  #: :func:`needed_motes`
    partner: PartnerDraws | None  #: :func:`partner_draws`
    _refinements: dict[tuple[str, bool], Refinement] = field(default_factory=dict)

    @property
    def extend(self) -> int:
        """Samples recorded beyond ``k`` in every view."""
        return self.variant.extend * self.code_length

    @property
    def round_k(self) -> int:
        """Samples of a short-round view (a L + b); 0: short rounds off."""
        return self.variant.round_frames[0] * self.code_length + self.variant.round_frames[1]

    @property
    def retry_frames(self) -> int | None:
        """Samples a retry records on (one code length); None: a new burst of ``k``."""
        return self.code_length if self.variant.continuous_retry else None

    def _ladder_refinement(self, c: str, need_c: np.ndarray | None,
                           ladder: tuple[float, ...]) -> tuple[float, Refinement]:
        """Camera ``c``'s refinement on ``ladder`` from its last wide view, and its price (s)."""
        intr, pt, start, v = self.scene.intr, self.scene.pts[c], self.scene.views[c][-1], self.variant
        passes, lost = plan_refinement(intr, pt, v.separation_px, ladder, start=start,
                                       field_rows=self.fields, needed=need_c, share_tiles=v.share_tiles)
        nv = sum(len(rp.views) for rp in passes)
        q = sum(_retry_fraction(intr.at_zoom(rp.zoom), pt, rp.views, self.miss_rate) * len(rp.views)
                for rp in passes) / max(nv, 1)
        ops = refinement_ops(passes, self.k, start, q if v.retry_refinement else 0.0, self.extend,
                             self.retry_frames, v.zoom_out)
        return price(ops, self.timing).total, Refinement(passes, lost, q, nv)

    def cheapest_refinement(self, c: str, need_c: np.ndarray | None) -> Refinement:
        """The cheapest ladder's refinement of camera ``c`` on the clock (ties: the first of
        :data:`LADDERS`); only ``levels`` without ``pick_ladder``."""
        best = math.inf
        for ladder in (LADDERS if self.variant.pick_ladder else (self.levels,)):
            cost, refinement = self._ladder_refinement(c, need_c, ladder)
            if cost < best:
                best, out = cost, refinement
        return out

    def refinement(self, c: str, rs: RadioSeparation | None, radio_cams: tuple[str, ...]) -> Refinement:
        """Camera ``c``'s refinement: of its needed motes, or of its radio rounds' leftover when it
        separates by radio (``rs``); a camera's leftover depends on it alone, so it is cached."""
        radio = rs is not None and c in radio_cams
        key = (c, radio)
        if key not in self._refinements:
            need_c = rs.leftover[c] if rs is not None and radio else self.needed[c]
            self._refinements[key] = self.cheapest_refinement(c, need_c)
        return self._refinements[key]

    def _radio_separation(self, radio_cams: tuple[str, ...], order: str) -> RadioSeparation | None:
        """The radio rounds of ``radio_cams`` (view-major stations for ``order`` "view"); None: none."""
        if not radio_cams:
            return None
        s, p = self.scene, self.partner
        return radio_separation(s.intr, s.pts, s.views, self.variant.separation_px, radio_cams, self.fields,
                                self.needed, partner=p.eligible if p else None, partner_ok=p.ok if p else None,
                                stations=order == "view")

    def _radio_retry(self, rs: RadioSeparation | None) -> tuple[float, int]:
        """Expected share of the radio-round views retried (at the round miss rate) and their count."""
        radio_retry, n_round = 0.0, 0
        if rs is not None:
            q_round = self.miss_rate if self.variant.round_miss_rate is None else self.variant.round_miss_rate
            for rounds in rs.rounds.values():
                for rr in rounds:
                    radio_retry += sum(1.0 - (1.0 - q_round) ** m for m in rr.view_targets)
                    n_round += len(rr.views)
            radio_retry /= max(n_round, 1)
        return radio_retry, n_round

    def plan_order(self, radio_cams: tuple[str, ...], order: str) -> CodedPlan:
        """The survey with ``radio_cams`` separating by radio in rounds of ``order`` ("class" or
        "view"), every camera refining what is left by zoom, priced on the clock."""
        v, rs = self.variant, self._radio_separation(radio_cams, order)
        refine: dict[str, list[RefinePass]] = {}
        unresolved = n_refine = 0
        refine_retry = 0.0
        for c in self.scene.cams:
            refine[c], lost_c, q_c, nv_c = self.refinement(c, rs, radio_cams)
            unresolved += lost_c
            refine_retry += q_c * nv_c
            n_refine += nv_c
        refine_retry /= max(n_refine, 1)
        radio_retry, n_round = self._radio_retry(rs)
        coded = coded_survey_time(
            self.scene.views, self.scene.n_motes, self.k, self.timing,
            retry_fraction=self.retry_views, refine=refine, broadcast_start=v.broadcast, start_broadcasts=3,
            extend_frames=self.extend, retry_frames=self.retry_frames,
            refine_retry_fraction=refine_retry if v.retry_refinement else 0.0, zoom_out=v.zoom_out,
            resync_s=RESYNC_S if v.sync else None, radio_rounds=rs.rounds if rs else None,
            pause_broadcasts=rs.pause_broadcasts if rs else 3,
            radio_retry_fraction=radio_retry if v.retry_refinement else 0.0,
            round_frames=self.round_k or None, round_order=order)
        return CodedPlan(coded, order if rs else "-", unresolved, refine_retry, radio_cams,
                         rs.classes if rs else 0, n_round, radio_retry)

    def plan(self, radio_cams: tuple[str, ...]) -> CodedPlan:
        """Refinement (and radio separation for ``radio_cams``) priced on the clock; with
        ``round_order`` "best" the cheaper of the class- and view-major rounds."""
        orders = ("class", "view") if self.variant.round_order == "best" else (self.variant.round_order,)
        return min((self.plan_order(radio_cams, o) for o in (orders if radio_cams else ("class",))),
                   key=lambda pl: pl.coded.time.total)

    def cheapest(self, choices: list[tuple[str, ...]]) -> CodedPlan:
        """The cheapest on the clock of the plans of ``choices`` of radio cameras (ties: the first)."""
        return min((self.plan(ch) for ch in choices), key=lambda pl: pl.coded.time.total)


def coded_clock(timing: RigTiming, fields: bool) -> RigTiming:
    """The coded survey's clock: ``timing`` with the camera at its field rate when decoding fields."""
    return replace(timing, camera=timing.camera.at_field_rate()) if fields else timing


def radio_choices(separate: str, cams: list[str]) -> list[tuple[str, ...]]:
    """The subsets of ``cams`` to try separating by radio: none ("zoom"), all ("radio"), or every
    subset ("best", in bitmask order: the cheapest on the clock is taken)."""
    if separate == "zoom":
        return [()]
    if separate == "radio":
        return [tuple(cams)]
    return [tuple(c for i, c in enumerate(cams) if m >> i & 1) for m in range(2 ** len(cams))]


def sequential_time(scene: Scene, seed: int, timing: RigTiming) -> SequentialTime:
    """The sequential survey of ``scene`` (seeded with ``seed``) on ``timing``'s clock, priced once
    per motes, cameras, seed and timing (it is the same in every variant)."""
    key = (scene.n_motes, scene.n_cams, seed, timing)
    if key not in _SEQUENTIAL:
        _SEQUENTIAL[key] = sequential_survey_time(scene.bearings, scene.intr, scene.searches, timing)
    return _SEQUENTIAL[key]


# --- one scene's result ---------------------------------------------------------------------------


def _radio_label(chosen: CodedPlan) -> str:
    """The radio cameras, comma-separated ("-": none), marked when the rounds are view-major."""
    label = ",".join(chosen.radio_cams) or "-"
    return label + " (view-major)" if chosen.round_order == "view" else label


def _survey_columns(planner: CodedPlanner, chosen: CodedPlan, seq: SequentialTime) -> dict[str, Any]:
    """Times (s) and phases of both surveys, the coded survey's counts and retry shares."""
    coded, n_cams = chosen.coded, planner.scene.n_cams
    return {
        "motes": planner.scene.n_motes, "cameras": n_cams,
        "seq": seq.time.total, "seq_desc": seq.time.describe(), "coded": coded.time.total,
        "coded_desc": coded.time.describe(), "views": sum(coded.views.values()) / n_cams,
        "L": planner.code_length, "K": planner.k + planner.extend, "refine": coded.refinements,
        "retry": planner.retry_views, "refine_retry": chosen.refine_retry, "missing": seq.not_found,
        "unresolved": chosen.unresolved, "radio_cams": _radio_label(chosen),
        "classes": chosen.classes, "round_views": chosen.round_views, "radio_retry": chosen.radio_retry,
        "round_K": planner.round_k if chosen.radio_cams else 0,
        "rate": planner.timing.camera.frame_rate_hz, "phases": coded.time.phases, "seq_phases": seq.time.phases,
    }


def _crowd_counts(scene: Scene, reads: WideReads, sep: float, fields: bool) -> dict[str, int]:
    """Crowd counts over the cameras: 4 px pairs and groups of three (with a third / fourth mote
    within 8 px, and resolved by their decoders), crowd motes alone at ``sep`` px (and read), and
    mote-views with a neighbour closer than ``sep`` px."""
    pairs, groups = reads.pairs.values(), reads.groups.values()
    return {
        "pairs": sum(len(p.pairs) for p in pairs),
        "pairs_resolved": sum(p.resolved_pairs for p in pairs),
        "pairs_third8": sum(int((p.third_px < 8.0).sum()) for p in pairs),
        "groups": sum(len(g.groups) for g in groups),
        "groups_resolved": sum(g.resolved_groups for g in groups),
        "groups_fourth8": sum(int((g.fourth_px < 8.0).sum()) for g in groups),
        "crowd_motes": sum(int(reads.crowd_member[c].sum()) for c in scene.cams),
        "crowd_read": sum(int(reads.crowd_read[c].sum()) for c in scene.cams),
        "crowded": sum(int((~(neighbour_px(scene.pts[c], scene.intr, fields) >= sep)).sum()) for c in scene.cams),
    }


def run(n_motes: int, n_cams: int, timing: RigTiming, miss_rate: float, seed: int = 0,
        variant: Variant = Variant(), levels: tuple[float, ...] = (1 / 9, 3 / 9, 1.0),
        periods: int = 3) -> dict[str, Any]:
    """Both surveys of the seeded scene of ``n_motes`` motes and ``n_cams`` cameras on ``timing``'s
    clock, the coded one run as ``variant`` (the cheapest of its radio choices; isolated motes
    missed at ``miss_rate`` per decode, ``periods`` code periods per view, ``levels`` the fixed
    zoom ladder): times in seconds, counts and retry shares, keyed as :func:`report` reads them."""
    scene = seeded_scene(n_motes, n_cams, seed)
    book = sync_code_book(n_motes) if variant.sync else code_book(n_motes)
    fields = variant.fields and timing.head.interlaced
    reads = wide_reads(scene, variant, seed, fields)
    planner = CodedPlanner(
        scene=scene, variant=variant, timing=coded_clock(timing, fields), fields=fields, miss_rate=miss_rate,
        levels=levels, k=frames_for(book.length, periods), code_length=book.length,
        retry_views=wide_retry_fraction(scene, miss_rate), needed=needed_motes(scene, reads, variant),
        partner=partner_draws(scene, variant, seed, fields))
    chosen = planner.cheapest(radio_choices(variant.separate, list(scene.cams)))
    seq = sequential_time(scene, seed, timing)
    return {**_survey_columns(planner, chosen, seq), **_crowd_counts(scene, reads, variant.separation_px, fields)}


# --- the command line (options, checks and the Variant: field_time_cli) ---------------------------


def main() -> None:
    """Print the table of both surveys' times for every ``--sizes`` scene and seed."""
    ap = build_parser(__doc__.splitlines()[0])
    args = ap.parse_args()
    check_scene_flags(ap, args)
    levels = tuple(float(x) for x in args.levels.split(","))
    timing = RigTiming(head=HEAD_MODELS[args.head], camera=CameraTiming(frame_rate_hz=args.fps))
    variant = variant_from_args(ap, args)
    print_header(args, levels, variant)
    for size in args.sizes.split(","):
        n, c = (int(x) for x in size.split("x"))
        speedups = [report(run(n, c, timing, args.miss_rate, seed, variant, levels, args.periods), variant, args)
                    for seed in range(args.seeds)]
        print_seed_summary(n, c, args.seeds, speedups)


if __name__ == "__main__":
    main()
