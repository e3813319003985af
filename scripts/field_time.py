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

import argparse
import math
from dataclasses import dataclass, replace

import numpy as np

from fgloc.camera.blink_codes import code_book, sync_code_book
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import SearchConfig
from fgloc.core.geometry import bearing_pan_tilt, rot_z, world_to_base
from fgloc.core.model import CameraPose
from fgloc.survey.clock import HEAD_MODELS, CameraTiming, RigTiming, price
from fgloc.survey.field_plans import (
    CodedTime,
    SequentialTime,
    coded_survey_time,
    crowd_decoding,
    frames_for,
    group_decoding,
    near_decoding,
    pair_decoding,
    pair_rate_table,
    radio_separation,
    refinement_ops,
    sequential_survey_time,
)
from fgloc.survey.view_planner import RefinePass, coverage, needed_from, neighbour_px, plan_refinement, plan_views

SEPARATION_PX = 4.0  #: crowds (pairs, groups of three) are motes closer than this at the wide zoom


def cameras(n: int, height: float = 0.1) -> dict[str, CameraPose]:
    corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)][:n]
    out = {}
    for i, (x, y) in enumerate(corners):
        yaw = math.atan2(0.5 - y, 0.5 - x)
        out[f"cam{i}"] = CameraPose(np.array([x, y, height]), rot_z(yaw))
    return out


def field_directions(pose: CameraPose, step: float = 0.01) -> np.ndarray:
    g = np.arange(0.0, 1.0 + 1e-9, step)
    xx, yy = np.meshgrid(g, g)
    pts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    p, t = bearing_pan_tilt(world_to_base(pose.rotation, pose.position, pts))
    return np.column_stack([p, t])


@dataclass(frozen=True)
class Variant:
    """How the coded survey is run (see the module docstring)."""

    fields: bool = True  #: decode fields on interlaced heads
    broadcast: bool = True  #: one broadcast start, not one unicast per mote
    sync: bool = False  #: synchronized book (epoch broadcast, resync every RESYNC_S)
    extend: int = 0  #: more code lengths recorded in every view (sliding windows)
    continuous_retry: bool = True  #: a retry goes on recording one code length, not a new burst
    retry_refinement: bool = True  #: refinement views are retried like wide views
    zoom_out: bool = False  #: zoom back out after the last refinement pass
    need: int = 0  #: refine a mote only where fewer than this many other cameras resolve it (0: always)
    share_tiles: bool = True  #: a higher-zoom refinement tile also serves lower-zoom targets it covers
    pick_ladder: bool = True  #: per camera, the zoom ladder of LADDERS whose refinement is cheapest on the clock
    #: crowded motes: "zoom" refinement only; "radio": every camera pauses colour classes and
    #: re-records its wide views; "best": the cheapest subset of cameras doing so, on the clock
    separate: str = "zoom"
    #: pair decoding: share of crowded groups of exactly two that the pair decoder resolves in
    #: the wide view (measured, scripts/blink_montecarlo.py --pairs); 0: off
    pair_rate: float | tuple[tuple[float, float], ...] = 0.0
    #: group decoding: the same for crowded groups of exactly three (blink_montecarlo.py --groups); 0: off
    group_rate: float | tuple[tuple[float, float], ...] = 0.0
    #: short rounds: radio-round views record this many samples, labelled against the class's
    #: candidates (blink_candidates); 0: off (a round view records K like a wide view)
    round_frames: tuple[int, int] = (0, 0)  #: (a, b): a L + b samples; (0, 0): off
    #: isolated miss rate of a short-round view (blink_candidates_montecarlo.py --candidates); None: the wide rate
    round_miss_rate: float | None = None
    #: cover rounds: share of crowded groups of exactly two whose unread member the known-partner
    #: decoder reads from the wide view once the other was read in a round (blink_montecarlo.py
    #: --partner), or a table by the distance to the nearest third mote; 0: off (colour rounds)
    partner_rate: float | tuple[tuple[float, float], ...] = 0.0
    partner_any: bool = False  #: every crowded group may leave one member unread (upper bound only)
    #: the same for crowded groups of exactly three (two read in rounds, the third decoded); 0: off
    partner_group_rate: float | tuple[tuple[float, float], ...] = 0.0
    #: radio rounds: "class" (class-major), "view" (each camera's round views shared across classes,
    #: it stays on a view while its classes take turns: field_plan_radio.view_major_round_time) or
    #: "best" (the cheaper of the two on the clock)
    round_order: str = "class"
    #: the blind decoder reads a mote as isolated when no other lies this close (px) at the wide
    #: zoom; 4 (the default, every earlier table) is the crowd criterion; a larger value with
    #: ``near_rate`` prices the measured read rate of motes whose neighbour lies between 4 px and it
    separation_px: float = SEPARATION_PX
    #: share of those motes the blind decoder reads (blink_near_montecarlo.py), or a table by
    #: the nearest neighbour's distance; 0: none is read (all refined or separated)
    near_rate: float | tuple[tuple[float, float], ...] = 0.0
    #: crowds of k motes alone at ``separation_px`` (k, rate or table by each mote's nearest
    #: neighbour, blink_near_montecarlo.py --group k --pairs): the share of their motes the
    #: decoder reads in the wide view (field_plans.crowd_decoding); their draws replace the
    #: pair and group decoders' draws of the crowds within 4 px inside them; (): none is read
    crowd_rates: tuple[tuple[int, float | tuple[tuple[float, float], ...]], ...] = ()


_SEQUENTIAL: dict[tuple[int, int, int, RigTiming], SequentialTime] = {}
OLD = Variant(continuous_retry=False, retry_refinement=False, zoom_out=True, share_tiles=False,
              pick_ladder=False)
#: candidate refinement zoom ladders (fractions of the optical range, 1x..10x): the old one first
LADDERS = ((1 / 9, 3 / 9, 1.0), (1 / 9, 2 / 9, 4 / 9, 1.0), (0.2, 0.5, 1.0), (1 / 18, 1 / 9, 2 / 9, 1 / 3, 5 / 9, 1.0))
RESYNC_S = 10.0


def _retry_fraction(intr: CameraIntrinsics, pt: np.ndarray, views: list[tuple[float, float]], q: float) -> float:
    """Expected fraction of ``views`` with at least one of their motes missed (rate ``q`` each)."""
    if not views:
        return 0.0
    per_view = coverage(intr, pt, np.array(views), 12.0).sum(axis=1)
    return float(np.mean(1.0 - (1.0 - q) ** per_view))


def run(n_motes: int, n_cams: int, timing: RigTiming, miss_rate: float, seed: int = 0,
        variant: Variant = Variant(), levels: tuple[float, ...] = (1 / 9, 3 / 9, 1.0),
        periods: int = 3) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    nodes = np.column_stack([rng.uniform(0, 1, (n_motes, 2)), np.zeros(n_motes)])
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    cams = cameras(n_cams)
    bearings, searches, views = {}, {}, {}
    book = sync_code_book(n_motes) if variant.sync else code_book(n_motes)
    k = frames_for(book.length, periods)
    fields = variant.fields and timing.head.interlaced
    coded_timing = replace(timing, camera=timing.camera.at_field_rate()) if fields else timing
    retry_views = 0.0
    pts: dict[str, np.ndarray] = {}
    for c, pose in cams.items():
        d = world_to_base(pose.rotation, pose.position, nodes)
        bearings[c] = d / np.linalg.norm(d, axis=1, keepdims=True)
        region = field_directions(pose)
        searches[c] = SearchConfig(pan_min=float(region[:, 0].min()), pan_max=float(region[:, 0].max()),
                                   tilt_min=float(region[:, 1].min()), tilt_max=float(region[:, 1].max()))
        views[c] = plan_views(intr, region)
        pts[c] = np.column_stack(bearing_pan_tilt(bearings[c]))
        retry_views += _retry_fraction(intr, pts[c], views[c], miss_rate) / n_cams
    sep = variant.separation_px
    resolved = {c: neighbour_px(pts[c], intr, fields) >= sep for c in cams}
    near_rng = np.random.default_rng([seed, 20])  # its own stream: the other draws stay as they were
    near = {c: near_decoding(intr, pts[c], SEPARATION_PX, sep, variant.near_rate, near_rng, fields) for c in cams}
    pair_rng = np.random.default_rng([seed, 16])
    pairs = {c: pair_decoding(intr, pts[c], SEPARATION_PX, variant.pair_rate, pair_rng, fields) for c in cams}
    group_rng = np.random.default_rng([seed, 17])  # its own stream: the pair draws stay as they were
    groups = {c: group_decoding(intr, pts[c], SEPARATION_PX, variant.group_rate, group_rng, fields) for c in cams}
    crowd_rng = np.random.default_rng([seed, 21])
    crowd = {c: crowd_decoding(intr, pts[c], sep, dict(variant.crowd_rates), crowd_rng, fields) for c in cams}
    for c in cams:  # a crowd's own measured share replaces the 4 px pair and group draws inside it
        pairs[c] = replace(pairs[c], resolved=pairs[c].resolved & ~crowd[c][1])
        groups[c] = replace(groups[c], resolved=groups[c].resolved & ~crowd[c][1])
        resolved[c] = resolved[c] | pairs[c].resolved | groups[c].resolved | near[c] | crowd[c][0]
    needed: dict[str, np.ndarray | None] = (
        dict(needed_from(resolved, variant.need)) if variant.need else {c: None for c in cams})
    if variant.pair_rate:  # pair-decoded motes need nothing more from that camera
        needed = {c: (np.ones(n_motes, bool) if needed[c] is None else needed[c]) & ~pairs[c].resolved  # type: ignore[operator]
                  for c in cams}
    if variant.group_rate:  # group-decoded motes too
        needed = {c: (np.ones(n_motes, bool) if needed[c] is None else needed[c]) & ~groups[c].resolved  # type: ignore[operator]
                  for c in cams}
    if sep > SEPARATION_PX:  # motes read in the wide view though a neighbour lies within sep
        needed = {c: (np.ones(n_motes, bool) if needed[c] is None else needed[c]) & ~near[c] & ~crowd[c][0]  # type: ignore[operator]
                  for c in cams}
    partner_eligible: dict[str, np.ndarray] | None = None
    partner_ok: dict[str, np.ndarray] | None = None
    if variant.partner_rate or variant.partner_group_rate:  # cover rounds: which groups may leave a member unread, which succeed
        partner_rng = np.random.default_rng([seed, 18])  # its own streams: the other draws stay as they were
        group_partner_rng = np.random.default_rng([seed, 19])
        partner_eligible, partner_ok = {}, {}
        for c in cams:
            if variant.partner_any:
                partner_eligible[c] = ~(neighbour_px(pts[c], intr, fields) >= SEPARATION_PX)
                partner_ok[c] = partner_eligible[c].copy()
                continue
            partner_eligible[c] = np.zeros(n_motes, bool)
            partner_ok[c] = np.zeros(n_motes, bool)
            if variant.partner_rate:
                partner_eligible[c] |= pair_decoding(intr, pts[c], SEPARATION_PX, 1.0, np.random.default_rng(0),
                                                     fields).resolved
                partner_ok[c] |= pair_decoding(intr, pts[c], SEPARATION_PX, variant.partner_rate, partner_rng,
                                               fields).resolved
            if variant.partner_group_rate:
                partner_eligible[c] |= group_decoding(intr, pts[c], SEPARATION_PX, 1.0, np.random.default_rng(0),
                                                      fields).resolved
                partner_ok[c] |= group_decoding(intr, pts[c], SEPARATION_PX, variant.partner_group_rate,
                                                group_partner_rng, fields).resolved
    extend = variant.extend * book.length
    round_k = variant.round_frames[0] * book.length + variant.round_frames[1]
    retry_frames = book.length if variant.continuous_retry else None

    def zoom_refine(c: str, need_c: np.ndarray | None) -> tuple[list[RefinePass], int, float, int]:
        """The cheapest ladder's refinement of camera ``c``: passes, lost, retry fraction, views."""
        best = math.inf
        for ladder in (LADDERS if variant.pick_ladder else (levels,)):
            passes, lost = plan_refinement(intr, pts[c], sep, ladder, start=views[c][-1],
                                           field_rows=fields, needed=need_c, share_tiles=variant.share_tiles)
            nv = sum(len(rp.views) for rp in passes)
            q = sum(_retry_fraction(intr.at_zoom(rp.zoom), pts[c], rp.views, miss_rate) * len(rp.views)
                    for rp in passes) / max(nv, 1)
            cost = price(refinement_ops(passes, k, views[c][-1], q if variant.retry_refinement else 0.0, extend,
                                        retry_frames, variant.zoom_out), coded_timing).total
            if cost < best:  # the cheapest ladder on the clock (ties: the first)
                best, out = cost, (passes, lost, q, nv)
        return out

    cache: dict[tuple[str, bool], tuple[list[RefinePass], int, float, int]] = {}

    def plan(radio_cams: tuple[str, ...]) -> dict[str, object]:
        """Refinement (and radio separation for ``radio_cams``) priced on the clock; with
        ``round_order`` "best" the cheaper of the class- and view-major rounds."""
        orders = ("class", "view") if variant.round_order == "best" else (variant.round_order,)
        return min((plan_order(radio_cams, o) for o in (orders if radio_cams else ("class",))),
                   key=lambda pl: pl["coded"].time.total)  # type: ignore[attr-defined]

    def plan_order(radio_cams: tuple[str, ...], order: str) -> dict[str, object]:
        rs = radio_separation(intr, pts, views, sep, radio_cams, fields, needed,
                              partner=partner_eligible, partner_ok=partner_ok,
                              stations=order == "view") if radio_cams else None
        refine: dict[str, list[RefinePass]] = {}
        unresolved = n_refine = 0
        refine_retry = 0.0
        for c in cams:
            need_c = needed[c] if rs is None or c not in radio_cams else rs.leftover[c]
            key = (c, rs is not None and c in radio_cams)  # a camera's leftover depends on it alone
            if key not in cache:
                cache[key] = zoom_refine(c, need_c)
            refine[c], lost_c, q_c, nv_c = cache[key]
            unresolved += lost_c
            refine_retry += q_c * nv_c
            n_refine += nv_c
        refine_retry /= max(n_refine, 1)
        radio_retry, n_round = 0.0, 0
        if rs is not None:
            q_round = miss_rate if variant.round_miss_rate is None else variant.round_miss_rate
            for c, rounds in rs.rounds.items():
                for rr in rounds:
                    radio_retry += sum(1.0 - (1.0 - q_round) ** m for m in rr.view_targets)
                    n_round += len(rr.views)
            radio_retry /= max(n_round, 1)
        coded = coded_survey_time(
            views, n_motes, k, coded_timing, retry_fraction=retry_views, refine=refine,
            broadcast_start=variant.broadcast, start_broadcasts=3, extend_frames=extend, retry_frames=retry_frames,
            refine_retry_fraction=refine_retry if variant.retry_refinement else 0.0, zoom_out=variant.zoom_out,
            resync_s=RESYNC_S if variant.sync else None, radio_rounds=rs.rounds if rs else None,
            pause_broadcasts=rs.pause_broadcasts if rs else 3,
            radio_retry_fraction=radio_retry if variant.retry_refinement else 0.0,
            round_frames=round_k or None, round_order=order)
        return {"coded": coded, "round_order": order if rs else "-", "unresolved": unresolved, "refine_retry": refine_retry, "radio_cams": radio_cams,
                "classes": rs.classes if rs else 0, "round_views": n_round, "radio_retry": radio_retry}

    if variant.separate == "zoom":
        choices: list[tuple[str, ...]] = [()]
    elif variant.separate == "radio":
        choices = [tuple(cams)]
    else:  # best: every subset of cameras separating by radio, the cheapest on the clock
        choices = [tuple(c for i, c in enumerate(cams) if m >> i & 1) for m in range(2 ** len(cams))]
    plans = [plan(ch) for ch in choices]
    chosen = min(plans, key=lambda pl: pl["coded"].time.total)  # type: ignore[attr-defined]
    coded = chosen["coded"]
    assert isinstance(coded, CodedTime)
    key = (n_motes, n_cams, seed, timing)
    if key not in _SEQUENTIAL:  # the same in every variant
        _SEQUENTIAL[key] = sequential_survey_time(bearings, intr, searches, timing)
    seq = _SEQUENTIAL[key]
    radio_cams = ",".join(chosen["radio_cams"]) or "-"  # type: ignore[arg-type]
    if chosen["round_order"] == "view":
        radio_cams += " (view-major)"
    return {
        "motes": n_motes, "cameras": n_cams,
        "seq": seq.time.total, "seq_desc": seq.time.describe(), "coded": coded.time.total,  # type: ignore[dict-item]
        "coded_desc": coded.time.describe(), "views": sum(coded.views.values()) / n_cams,  # type: ignore[dict-item]
        "L": book.length, "K": k + variant.extend * book.length, "refine": coded.refinements, "retry": retry_views,
        "refine_retry": chosen["refine_retry"], "missing": seq.not_found,  # type: ignore[dict-item]
        "unresolved": chosen["unresolved"], "radio_cams": radio_cams,  # type: ignore[dict-item]
        "classes": chosen["classes"], "round_views": chosen["round_views"],  # type: ignore[dict-item]
        "radio_retry": chosen["radio_retry"],  # type: ignore[dict-item]
        "round_K": round_k if chosen["radio_cams"] else 0,  # type: ignore[dict-item]
        "rate": coded_timing.camera.frame_rate_hz, "phases": coded.time.phases,  # type: ignore[dict-item]
        "seq_phases": seq.time.phases,  # type: ignore[dict-item]
        "pairs": sum(len(p.pairs) for p in pairs.values()),
        "pairs_resolved": sum(p.resolved_pairs for p in pairs.values()),
        "pairs_third8": sum(int((p.third_px < 8.0).sum()) for p in pairs.values()),
        "groups": sum(len(g.groups) for g in groups.values()),
        "groups_resolved": sum(g.resolved_groups for g in groups.values()),
        "groups_fourth8": sum(int((g.fourth_px < 8.0).sum()) for g in groups.values()),
        "crowd_motes": sum(int(crowd[c][1].sum()) for c in cams),
        "crowd_read": sum(int(crowd[c][0].sum()) for c in cams),
        "crowded": sum(int((~(neighbour_px(pts[c], intr, fields) >= sep)).sum()) for c in cams),
    }


def round_frames_of(text: str) -> tuple[int, int]:
    """``"18"`` -> (0, 18); ``"L+2"`` -> (1, 2); ``"2L+2"`` -> (2, 2): samples a L + b of a
    short-round view. ValueError unless at least one code length (a >= 1) or 8 samples."""
    t = text.replace(" ", "").upper()
    if "L" in t:
        a_txt, _, b_txt = t.partition("L")
        a = int(a_txt) if a_txt else 1
        b = int(b_txt) if b_txt else 0
        if a < 1 or b < 0:
            raise ValueError("a L + b needs a >= 1, b >= 0")
        return a, b
    k = int(t)
    if k < 8:
        raise ValueError("at least one code length (8 samples or more)")
    return 0, k


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--head", default="EVI-D100", choices=sorted(HEAD_MODELS))
    ap.add_argument("--miss-rate", type=float, default=0.0)
    ap.add_argument("--fps", type=float, default=30000.0 / 1001.0)
    ap.add_argument("--frames", action="store_true", help="decode frames, not fields (interlaced heads)")
    ap.add_argument("--unicast", action="store_true", help="one unicast start per mote, not a broadcast")
    ap.add_argument("--sync", action="store_true", help="the synchronized book (epoch broadcast, resync every 10 s)")
    ap.add_argument("--extend", type=int, default=0, help="code lengths recorded beyond K in every view")
    ap.add_argument("--burst-retry", action="store_true", help="a retry records a new burst of K frames")
    ap.add_argument("--no-refine-retry", action="store_true", help="refinement views are never retried")
    ap.add_argument("--zoom-out", action="store_true", help="zoom back out after the last refinement pass")
    ap.add_argument("--separate-tiles", action="store_true", help="each zoom level tiles only its own targets")
    ap.add_argument("--fixed-ladder", action="store_true", help="refine on --levels only, not the cheapest of LADDERS")
    ap.add_argument("--separate", default="zoom", choices=("zoom", "radio", "best"),
                    help="crowded motes: zoom refinement, radio separation (pause colour classes, re-record wide "
                    "views), or per camera the cheaper on the clock")
    ap.add_argument("--pair-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="crowded groups of exactly two motes are resolved by the pair decoder in the wide view with "
                    "this measured success rate (scripts/blink_montecarlo.py --pairs), or per bound on the distance "
                    "to the nearest third mote (px); default off")
    ap.add_argument("--group-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="crowded groups of exactly three motes are resolved by the group decoder in the wide view "
                    "with this measured rate (scripts/blink_montecarlo.py --groups), or per bound on the distance to "
                    "the nearest fourth mote (px); default off")
    ap.add_argument("--round-frames", default="", metavar="K'",
                    help="short rounds: each radio-round view records K' samples, labelled against the class's "
                    "candidates (fgloc.camera.blink_candidates): a count or a L + b in code lengths L (e.g. L+2, 2L+2); "
                    "default off")
    ap.add_argument("--round-miss-rate", type=float, default=None, metavar="Q",
                    help="with --round-frames: isolated miss rate of a short-round view (scripts/"
                    "blink_candidates_montecarlo.py --candidates); default: --miss-rate")
    ap.add_argument("--partner-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="cover rounds (with --separate radio|best): a crowded group of exactly two needs only one "
                    "member read in a radio round, the other decoded from the wide view by the known-partner decoder "
                    "with this success rate (scripts/blink_montecarlo.py --partner), or per bound on the distance to "
                    "the nearest third mote (px); failures are read in extra rounds; default off")
    ap.add_argument("--partner-group-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="cover rounds: the same for crowded groups of exactly three (two read in rounds, the third "
                    "decoded; scripts/blink_montecarlo.py --groups --partner), per bound on the nearest fourth mote")
    ap.add_argument("--partner-any", action="store_true",
                    help="with --partner-decode 1: every crowded group leaves one member unread (upper bound)")
    ap.add_argument("--round-order", default="class", choices=("class", "view", "best"),
                    help="with --separate radio|best: class-major rounds (each class in turn, every camera visiting "
                    "its views), view-major (each camera's round views shared across the classes; it stays on a "
                    "view while the classes it needs there take turns, one pause update per class change), or the "
                    "cheaper of the two on the clock; default class")
    ap.add_argument("--separation", type=float, default=SEPARATION_PX, metavar="PX",
                    help="a mote is isolated (read as such in the wide view) when no other lies within PX px at the "
                    "wide zoom; default 4 (the crowd criterion of every earlier table); the blind decoder's measured "
                    "separation is ~8 px (scripts/blink_near_montecarlo.py)")
    ap.add_argument("--near-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="with --separation above 4: the share of motes whose nearest neighbour lies 4 px to "
                    "--separation away that the blind decoder still reads (blink_near_montecarlo.py), or per bound "
                    "on that distance; default 0")
    ap.add_argument("--crowd-decode", action="append", default=[], metavar="K=RATE|K=PX:RATE,...,inf:RATE",
                    help="with --separation above 4, repeatable: the share of the motes of crowds of K (3 to 5) alone "
                    "at --separation that the decoder reads in the wide view (blink_near_montecarlo.py --group K "
                    "--pairs), or per bound on each mote's nearest-neighbour distance; replaces the pair and group "
                    "decoders' draws inside those crowds; default none")
    ap.add_argument("--need", type=int, default=0,
                    help="refine a mote only where fewer than this many other cameras resolve it (0: always)")
    ap.add_argument("--old", action="store_true", help="the previous plan: rotation-free book, burst retries of "
                    "wide views only, zoom out at the end (other flags but --frames/--unicast ignored)")
    ap.add_argument("--periods", type=int, default=3, help="code periods recorded per view (K = periods x L + 2)")
    ap.add_argument("--levels", default="0.111,0.333,1", help="refinement zoom ladder (fractions, ascending)")
    ap.add_argument("--sizes", default="100x2,100x4,1000x2,1000x4", help="scenes, motes x cameras")
    ap.add_argument("--seeds", type=int, default=1, help="seeded scenes per size (0..N-1); summary of the speed-ups")
    args = ap.parse_args()
    if args.seeds < 1:
        ap.error(f"--seeds: at least 1 ({args.seeds})")
    if not SEPARATION_PX <= args.separation <= 64.0:
        ap.error(f"--separation: px in [{SEPARATION_PX:g}, 64] ({args.separation})")
    if args.near_decode and args.separation <= SEPARATION_PX:
        ap.error(f"--near-decode: needs --separation above {SEPARATION_PX:g} px ({args.near_decode})")
    if args.crowd_decode and args.separation <= SEPARATION_PX:
        ap.error(f"--crowd-decode: needs --separation above {SEPARATION_PX:g} px ({args.crowd_decode[0]})")
    levels = tuple(float(x) for x in args.levels.split(","))
    timing = RigTiming(head=HEAD_MODELS[args.head], camera=CameraTiming(frame_rate_hz=args.fps))
    variant = Variant(fields=not args.frames, broadcast=not args.unicast, sync=args.sync,
                      extend=args.extend, continuous_retry=not args.burst_retry,
                      retry_refinement=not args.no_refine_retry, zoom_out=args.zoom_out, need=args.need,
                      share_tiles=not args.separate_tiles, pick_ladder=not args.fixed_ladder,
                      separate=args.separate, round_miss_rate=args.round_miss_rate, round_order=args.round_order,
                      separation_px=args.separation)
    if args.round_frames:
        try:
            variant = replace(variant, round_frames=round_frames_of(args.round_frames))
        except ValueError as exc:
            ap.error(f"--round-frames: {exc} ({args.round_frames})")
    if args.round_miss_rate is not None and not (args.round_frames and 0.0 <= args.round_miss_rate < 1.0):
        ap.error(f"--round-miss-rate: needs --round-frames and a rate in [0, 1) ({args.round_miss_rate})")
    # crowd-decoding rates: one rate, or per bound on the distance to the nearest other mote
    for flag, value, name in (("--pair-decode", args.pair_decode, "pair_rate"),
                              ("--group-decode", args.group_decode, "group_rate"),
                              ("--partner-decode", args.partner_decode, "partner_rate"),
                              ("--partner-group-decode", args.partner_group_decode, "partner_group_rate"),
                              ("--near-decode", args.near_decode, "near_rate")):
        if not value:
            continue
        try:
            table = pair_rate_table(value)
        except ValueError as exc:
            ap.error(f"{flag}: {exc} ({value})")
        variant = replace(variant, **{name: table[0][1] if len(table) == 1 else table})
    crowd_rates: dict[int, float | tuple[tuple[float, float], ...]] = {}
    for value in args.crowd_decode:
        size, _, text = value.partition("=")
        try:
            k, table = int(size), pair_rate_table(text)
            if not 3 <= k <= 5 or k in crowd_rates:
                raise ValueError(f"crowd size {k}: one of 3, 4, 5, each once")
        except ValueError as exc:
            ap.error(f"--crowd-decode: {exc} ({value})")
        crowd_rates[k] = table[0][1] if len(table) == 1 else table
    variant = replace(variant, crowd_rates=tuple(sorted(crowd_rates.items())))
    if args.partner_decode:
        variant = replace(variant, partner_any=args.partner_any)
    if args.partner_any and args.partner_decode.strip() not in ("1", "1.0"):
        ap.error(f"--partner-any: only with --partner-decode 1 (an upper bound) ({args.partner_decode or 'off'})")
    if args.old:
        variant = replace(OLD, fields=not args.frames, broadcast=not args.unicast)
    print(f"head {args.head}, {args.fps:.2f} frames/s, miss rate {args.miss_rate}, refinement zooms {levels}, {variant}")
    print("| motes | cameras | sequential (s) | coded (s) | speed-up | L | samples/view | decode rate (Hz) | "
          "views/camera | refinement views | retried views (wide / refinement) | unresolved | "
          "radio cameras | colour classes | radio round views (retry) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        n, c = (int(x) for x in size.split("x"))
        speedups = [report(run(n, c, timing, args.miss_rate, seed, variant, levels, args.periods), variant, args)
                    for seed in range(args.seeds)]
        if args.seeds > 1:
            print(f"|   | {n} x {c} over seeds 0..{args.seeds - 1}: speed-up median {np.median(speedups):.1f}x "
                  f"(range {min(speedups):.1f}-{max(speedups):.1f}x) |||||||||||")


def report(r: dict[str, float], variant: Variant, args: argparse.Namespace) -> float:
    """Print one scene's rows; returns its speed-up."""
    n, c = r["motes"], r["cameras"]
    print(f"| {n} | {c} | {r['seq']:.1f} | {r['coded']:.1f} | {r['seq'] / r['coded']:.1f}x | {r['L']} | "
          f"{r['K']} | {r['rate']:.2f} | {r['views']:.1f} | {r['refine']} | {r['retry']:.2f} / "
          f"{r['refine_retry']:.2f} | {r['unresolved']} | {r['radio_cams']} | {r['classes']} | "
          f"{r['round_views']} ({r['radio_retry']:.2f}) |")
    print(f"|   | sequential phases: {r['seq_desc']} (not found {r['missing']}) |||||||||||")
    print(f"|   | coded phases: {r['coded_desc']} |||||||||||")
    if r["round_K"]:
        print(f"|   | short rounds: {r['round_K']} samples per round view, candidate miss rate "
              f"{variant.round_miss_rate if variant.round_miss_rate is not None else args.miss_rate} |||||||||||")
    if variant.pair_rate:
        print(f"|   | pair decoding: {r['pairs']} crowded pairs of exactly two over the cameras "
              f"({r['pairs_third8']} with a third mote within 8 px), {r['pairs_resolved']} resolved; "
              f"{r['crowded']} crowded mote-views |||||||||||")
    if variant.group_rate:
        print(f"|   | group decoding: {r['groups']} crowded groups of exactly three over the cameras "
              f"({r['groups_fourth8']} with a fourth mote within 8 px), {r['groups_resolved']} resolved |||||||||||")
    if variant.crowd_rates:
        print(f"|   | crowd decoding: {r['crowd_motes']} mote-views in crowds of "
              f"{', '.join(str(k) for k, _ in variant.crowd_rates)} alone at {variant.separation_px:g} px, "
              f"{r['crowd_read']} read in the wide view |||||||||||")
    return r["seq"] / r["coded"]


if __name__ == "__main__":
    main()
