"""Coded against sequential ``fgloc survey`` on the in-process rig: field time, labels, accuracy.

Both surveys run end to end through :func:`fgloc.survey.session.run_survey` on the same
simulated scene per seed (the example rig with ``--motes`` nodes, two cameras 0.1 and
0.12 above (0, 0) and (1, 0), ``--width`` x 3/4 px frames at a 90 deg horizontal field of
view (or focal length ``--fx``), 5 % occluded pairs, one dead mote). Both are priced by the survey clock
(:mod:`fgloc.survey.clock`, EVI-D100 model): the coded survey reports its own field time;
the sequential one is priced here the way the coded survey prices its fallback nodes (each
node: its LED commands, the LED wait, then the slowest camera's moves, settles, frames and
position reads, :func:`fgloc.survey.coded_clock.node_field_time`).

Reported per mode: predicted field time (median over seeds, and per phase for the first
seed; per seed and camera the recordings, frames and priced lane seconds of the wide views and of
each refinement rung, ``r1``, ``r2``, ...: a view's move, settle, position read and recordings, a
rung's zoom travel with its first tile; the wide pass's unexplained blobs the ladder starts
from, how many lie at a reading of the same camera and how many at a crowded mote), readings decoded in views and measured by the fallback, mislabelled readings (a
decoded reading whose nearest visible node bearing is another node's; the two readings of a
pair-decoded blob judged together, :func:`labels`), readings more than
0.05 deg from their node's bearing, and the RMS node position error of the joint solve
(baseline units); with radio separation also the priced rounds alone (their lanes and pause
updates, ``CodedStats.rounds_s``), colour classes, pause updates and round recordings.

``--repeatability-deg`` > 0 gives the rig that head repeatability (rig.json
``head_repeatability_deg``, part of ``sigma_deg``): the simulated heads settle with a seeded
pointing error per move, shared by a coded view's readings, and the coded survey writes
views. The coded survey is then also solved with its views ignored (each reading
independent with its total sigma), and every solve is scored by the node NEES (planar, 2
dof) against truth: ANEES over all nodes of all seeds with its two-sided 95 % chi-square
bounds (independent nodes assumed), and per seed, with the mean of the seeds' ANEES and its
95 % interval over seeds (one scene's nodes share its camera-pose errors, so they are not
independent samples); each scene's joint NEES under its joint node covariance
(:mod:`fgloc.evaluate.joint_nees`, chi-square with 2N dof); and the ANEES against its
two-sided 95 % bounds under those joint covariances, over all seeds and per seed from that
scene alone (a scene's summed node NEES is the generalized chi-square ``sum_k lambda_k
chi2_1``, ``lambda`` the eigenvalues of its joint covariance whitened by the nodes'
marginals: :mod:`fgloc.evaluate.anees_bounds`). Usage::

    OPENBLAS_NUM_THREADS=1 python scripts/coded_survey.py --seeds 5 --motes 30 [--repeatability-deg 0.07]
    OPENBLAS_NUM_THREADS=1 python scripts/coded_survey.py --coded '{"separate": "radio"}' \
        --coded '{"separate": "radio", "rounds": "short"}'   # two lever sets side by side

``--video-seeds K`` records each scene's coded surveys K times (rig.json ``simulation.video_seed``):
a scene's field time depends on when each recording starts against the motes' phases, so a
lever that moves the survey clock by a fraction of a second also redraws every decode; the
mean over recordings separates the lever from that draw.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fgloc.core.model import Survey  # noqa: E402
from fgloc.drivers.inprocess_rig import InProcessRig  # noqa: E402
from fgloc.evaluate.anees_bounds import anees_bounds_of_eigenvalues, node_nees_eigenvalues  # noqa: E402
from fgloc.evaluate.joint_nees import joint_nees_and_covariance  # noqa: E402
from fgloc.evaluate.score import nees  # noqa: E402
from fgloc.files.journal import read_journal  # noqa: E402
from fgloc.files.rig_config import parse_rig  # noqa: E402
from fgloc.solve.joint import solve_survey  # noqa: E402
from fgloc.survey.clock import FieldTime, price, sum_times  # noqa: E402
from fgloc.survey.coded import CodedSurvey  # noqa: E402
from fgloc.survey.coded_clock import ClockSink, CountingLeds, clocked_opener, node_field_time, rig_timing  # noqa: E402
from fgloc.survey.session import OpenedRig, run_survey  # noqa: E402

EXAMPLE = ROOT / "examples" / "rig-simulated.json"

_STATS: list = []  # each coded run's CodedStats (the priced rounds, classes, pause updates)


def _keeping_stats(run_coded):  # noqa: ANN001, ANN202
    def run_and_keep(self, runner):  # noqa: ANN001, ANN202
        try:
            return run_coded(self, runner)
        finally:
            _STATS.append(self.stats)
    return run_and_keep


CodedSurvey.run = _keeping_stats(CodedSurvey.run)  # type: ignore[method-assign]

_PRICED: dict = {}  # camera -> view kind ("wide", "r1", ...) -> priced lane seconds of the current coded run


def view_kind(view: str) -> str:
    """A view id's kind in the breakdown: ``wide``, a rung (``r1``...), a radio round's class (``s0``...),
    or ``round`` (the fallback round's ``f<k>``)."""
    return "wide" if view.startswith("w") else "round" if view.startswith("f") else view.split("-")[0]


def _pricing_visits(visit):  # noqa: ANN001, ANN202
    """Wrap ``CodedSurvey._visit``: the camera's priced lane time since its previous view (the
    move, settle, position read, recordings, and a rung's zoom travel before its first tile)
    added to ``_PRICED`` under the view's kind."""
    last: dict = {}  # camera -> (its lane list, priced seconds after its previous view)

    def priced_visit(self, runner, camera, vid, *args, **kw):  # noqa: ANN001, ANN202
        out = visit(self, runner, camera, vid, *args, **kw)
        ops = self.lanes[camera]
        lane, before = last.get(camera, (None, 0.0))
        before = before if lane is ops else 0.0  # a barrier (radio separation) starts new lanes
        after = price(ops, self.lane_timing[camera]).total
        last[camera] = (ops, after)
        kind = view_kind(vid)
        _PRICED.setdefault(camera, {}).setdefault(kind, 0.0)
        _PRICED[camera][kind] += after - before
        return out
    priced_visit.last = last  # type: ignore[attr-defined]
    return priced_visit


def _pricing_zoom(refine):  # noqa: ANN001, ANN202
    """Wrap ``CodedSurvey.run_refine``: the zoom back to the survey zoom priced as ``zoom back``."""
    def priced_refine(self, runner, camera, *args, **kw):  # noqa: ANN001, ANN202
        out = refine(self, runner, camera, *args, **kw)
        ops = self.lanes[camera]
        if ops and type(ops[-1]).__name__ == "Zoom" and ops[-1].dzoom < 0:
            _PRICED.setdefault(camera, {})["zoom back"] = price(ops[-1:], self.lane_timing[camera]).total
        return out
    return priced_refine


CodedSurvey._visit = _pricing_visits(CodedSurvey._visit)  # type: ignore[method-assign]
CodedSurvey.run_refine = _pricing_zoom(CodedSurvey.run_refine)  # type: ignore[method-assign]


def rig_for(seed: int, motes: int, width: int, mode: str, fx: float | None = None, repeatability_deg: float = 0.0,
            coded: dict | None = None, field_boxes: bool = False, box_margin_deg: float = 5.0,
            video_seed: int | None = None):
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(motes)]
    f = fx or width / 2.0
    for cam in data["cameras"]:
        cam["intrinsics"] = {"fx": f, "fy": f, "cx": width / 2, "cy": width * 3 / 8, "width": width,
                             "height": width * 3 // 4}
    data["simulation"] = {"seed": seed, "heights": [0.1, 0.12], "occlusion": 0.05, "dead_nodes": ["n003"]}
    if video_seed is not None:  # another recording of the same scene (motes' phases and clocks, frame noise)
        data["simulation"]["video_seed"] = video_seed
    data["retry"] = {"backoff_s": 0.0}
    data["identification"] = mode
    if coded:
        data["coded"] = coded
    if repeatability_deg > 0:
        data["head_repeatability_deg"] = repeatability_deg
    if field_boxes:  # each camera searches the box around its visible nodes (SimScene.field_search_boxes)
        boxes = InProcessRig(parse_rig(data, str(EXAMPLE), EXAMPLE.parent)).scene.field_search_boxes(box_margin_deg)
        for cam in data["cameras"]:
            if cam["id"] in boxes:
                cam["search"] = boxes[cam["id"]]
    return parse_rig(data, str(EXAMPLE), EXAMPLE.parent)


def labels(rig, scene, state) -> tuple[int, int, int]:
    """(decoded readings, mislabelled, more than 0.05 deg off their own node's bearing).

    Mislabelled: another visible node's bearing lies nearer than the reading's own. The two
    readings of one pair-decoded blob (``partner``, same recording) are judged together: when
    the nearer node is the partner, they are mislabelled only if the swapped labels fit both
    readings better (their summed angular errors), since a shift common to the pair (the blob's
    noise) can carry one reading nearer its partner's mote than its own."""
    decoded = [o for o in state.observations.values() if o.view is not None]
    partner: dict[tuple[str, str, str], str] = {}  # (camera, view, node) -> its pair partner's node
    for (cam, vid, _att), rec in state.views.items():
        by_code = {int(r["code"]): str(r["node"]) for r in rec.get("readings", []) if "code" in r}
        for r in rec.get("readings", []):
            if r.get("partner") is not None and int(r["partner"]) in by_code:
                partner[(cam, vid, str(r["node"]))] = by_code[int(r["partner"])]
    by_view = {(o.camera, o.view, o.node): o for o in decoded}

    def errors_to_nodes(o) -> dict[str, float]:  # noqa: ANN001
        i = rig.camera_ids.index(o.camera)
        seen = [j for j in range(len(rig.node_ids)) if scene.visible[i, j] and rig.node_ids[j] not in scene.dead]
        app = scene.apparent[i, seen]
        err = np.hypot((np.remainder(o.pan - app[:, 0] + math.pi, 2 * math.pi) - math.pi) * np.cos(app[:, 1]),
                       o.tilt - app[:, 1])
        return {rig.node_ids[j]: float(e) for j, e in zip(seen, err)}

    wrong = far = 0
    for o in decoded:
        err = errors_to_nodes(o)
        own = err.get(o.node, math.inf)
        nearest = min(err, key=err.__getitem__)
        far += math.degrees(own) > 0.05
        if nearest == o.node:
            continue
        mate = partner.get((o.camera, o.view, o.node))
        q = by_view.get((o.camera, o.view, mate)) if mate == nearest else None
        if q is not None:
            q_err = errors_to_nodes(q)
            if own + q_err.get(q.node, math.inf) <= err[nearest] + q_err.get(o.node, math.inf):
                continue  # the pair's labels fit better as they are than swapped
        wrong += 1
    return len(decoded), wrong, far


def breakdown(rig, sim, state) -> dict:  # noqa: ANN001
    """Where the coded survey's recordings went, per camera, from its journal: wide views,
    their second recordings, refinement tiles per rung and theirs, separation rounds; and the
    fallback nodes with their priced time."""
    out: dict = {"cameras": {}}
    for cam in rig.camera_ids:
        recs = [r for (c, _v, _a), r in state.views.items() if c == cam]
        kinds: dict[str, list[int]] = {}
        for r in recs:
            v = str(r["view"])
            kind = view_kind(v)
            kinds.setdefault(kind, [0, 0, 0])
            kinds[kind][0 if int(r["attempt"]) == 0 else 1] += 1
            kinds[kind][2] += int(r.get("frames", 0))
        out["cameras"][cam] = kinds
    fb = [r for r in state.field_times if r.get("scope") in ("fallback_node", "fallback_group", "fallback_pair")]
    out["fallback_nodes"] = sum(1 if r.get("scope") == "fallback_node" else len(r.get("nodes", []))
                                for r in fb if r.get("scope") != "fallback_group")
    out["fallback_groups"] = sum(1 for r in fb if r.get("scope") == "fallback_group")
    out["fallback_s"] = sum(sum(float(x) for x in r["phases"].values()) for r in fb)
    return out


def wide_blobs(rig, sim, state) -> dict:  # noqa: ANN001
    """Per camera, the wide pass's unexplained blobs (each view's last recording, as the ladder
    starts from them): (blobs, at a reading of the camera's wide views, within
    :data:`~fgloc.survey.coded_ladder.EXPLAINED_PX`; at a visible mote with another within 4 px,
    the planner's crowd criterion, from the scene's truth)."""
    from fgloc.core.geometry import pan_tilt_bearing
    from fgloc.survey.coded_ladder import EXPLAINED_PX, direction, read_before

    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    out = {}
    for i, cam in enumerate(rig.camera_ids):
        last: dict = {}
        for (c, v, a), r in sorted(state.views.items()):
            if c == cam and v.startswith("w"):
                last[v] = r
        blobs = coded.unexplained(list(last.values()))
        read = read_before(state.views, cam, 0)
        live = [j for j, n in enumerate(rig.node_ids) if sim.scene.visible[i, j] and n not in sim.scene.dead]
        truth = np.array([pan_tilt_bearing(*sim.scene.apparent[i, j]) for j in live]).reshape(-1, 3)
        fx = rig.cameras[i].intrinsics.fx
        gap = np.arccos(np.clip(truth @ truth.T, -1, 1))
        np.fill_diagonal(gap, np.pi)
        crowded = gap.min(axis=1) * fx < 4.0
        at_read = at_crowd = 0
        for b in blobs:
            k = coded.intrinsics_at(cam, b[2])
            d = pan_tilt_bearing(*direction(b, lambda z: coded.intrinsics_at(cam, z)))
            at_read += bool(len(read)) and float(np.max(read @ d)) >= math.cos(EXPLAINED_PX / k.fx)
            near = np.arccos(np.clip(truth @ d, -1, 1)) * k.fx < 2.0 if len(truth) else np.zeros(0, bool)
            at_crowd += bool((near & crowded).any())
        out[cam] = (len(blobs), at_read, at_crowd)
    return out


def planner_prediction(rig, sim, retry_fraction: float, separation_px: float = 4.0) -> float:  # noqa: ANN001
    """The field-time planner's price (:mod:`fgloc.survey.field_plans`) of a coded survey of this
    rig: the integrated survey's wide views, the scene's visible motes refined on the cheapest
    zoom ladder with shared tiles (``separation_px``: 4 as scripts/field_time.py), retries continuing
    the recording for L frames (``retry_fraction`` of the views, as measured), no zoom-out, frames."""
    from fgloc.camera.blink_codes import code_book
    from fgloc.survey.coded import CodedSurvey
    from fgloc.survey.field_plans import coded_survey_time, frames_for, refinement_ops
    from fgloc.survey.view_planner import plan_refinement

    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    views = {c: coded.plan(c) for c in rig.camera_ids}
    book = code_book(len(rig.node_ids))
    k = frames_for(book.length)
    timing = rig_timing(rig.cameras[0].model)
    ladders = ((1 / 9, 3 / 9, 1.0), (1 / 9, 2 / 9, 4 / 9, 1.0), (0.2, 0.5, 1.0),
               (1 / 18, 1 / 9, 2 / 9, 1 / 3, 5 / 9, 1.0))
    refine = {}
    for i, c in enumerate(rig.camera_ids):
        live = [j for j, n in enumerate(rig.node_ids) if sim.scene.visible[i, j] and n not in sim.scene.dead]
        pts = sim.scene.apparent[i, live]
        intr = rig.cameras[i].intrinsics
        best = math.inf
        for ladder in ladders:
            passes, _ = plan_refinement(intr, pts, separation_px, ladder, start=views[c][-1], share_tiles=True)
            cost = price(refinement_ops(passes, k, views[c][-1], retry_fraction, 0, book.length, False),
                         timing).total
            if cost < best:
                best, refine[c] = cost, passes
    return coded_survey_time(views, len(rig.node_ids), k, timing, retry_fraction, refine, retry_frames=book.length,
                             refine_retry_fraction=retry_fraction, zoom_out=False).time.total


def without_views(survey: Survey) -> Survey:
    """The survey as a version-1 reader sees it: each reading independent with its total sigma."""
    from dataclasses import replace

    return replace(survey, observations=[replace(o, view=None, view_sigma=None, view_pan=None)
                                         for o in survey.observations])


def errors(survey: Survey, truth) -> tuple[list[float], list[float], tuple[float, int], np.ndarray]:  # noqa: ANN001
    """(position errors, NEES) of the joint solve's nodes (planar, 2 dof), the scene's joint
    NEES with its dof (:func:`fgloc.evaluate.joint_nees.joint_nees`), and the eigenvalues of
    its joint node covariance whitened by the nodes' marginals
    (:func:`fgloc.evaluate.anees_bounds.node_nees_eigenvalues`: the weights of the scene's
    summed per-node NEES as a generalized chi-square)."""
    result = solve_survey(survey)
    ids = list(result.nodes)
    e = np.array([result.nodes[n].position[:2] - truth.nodes[n][:2] for n in ids])
    cov = np.array([result.nodes[n].covariance for n in ids])
    value, dof, joint_cov, order = joint_nees_and_covariance(survey, result, truth.nodes)
    if sorted(order) != sorted(ids):
        raise RuntimeError("the joint covariance's nodes are not the result's nodes")
    return list(np.linalg.norm(e, axis=1)), list(nees(e, cov)), (value, dof), node_nees_eigenvalues(joint_cov, 2)


def run(seed: int, motes: int, width: int, mode: str, out: Path, fx: float | None = None,
        repeatability_deg: float = 0.0, coded: dict | None = None, field_boxes: bool = False,
        box_margin_deg: float = 5.0, video_seed: int | None = None) -> dict:
    rig = rig_for(seed, motes, width, mode, fx, repeatability_deg, coded, field_boxes, box_margin_deg, video_seed)
    sim = InProcessRig(rig)
    times: list[FieldTime] = []
    if mode == "sequential":
        sink, leds = ClockSink(rig.camera_ids), CountingLeds(sim.leds)
        timing = {c.id: rig_timing(c.model) for c in rig.cameras}
        sink.active = True
        count = [0]

        def per_node(_progress: object) -> None:
            ops = sink.take()
            if any(ops.values()) or leds.commands > count[0]:
                times.append(node_field_time(ops, leds.commands - count[0], rig.search.led_wait_s, timing))
            count[0] = leds.commands

        opened = OpenedRig(open_head=clocked_opener(sim.open_head, sink), leds=leds, simulated=sim)  # type: ignore[arg-type]
        t0 = time.perf_counter()
        survey, runner = run_survey(rig, out, opened=opened, on_progress=per_node)
        ft = sum_times(times)
    else:
        _PRICED.clear()
        CodedSurvey._visit.last.clear()  # type: ignore[attr-defined]
        t0 = time.perf_counter()
        survey, runner = run_survey(rig, out, opened=OpenedRig(open_head=sim.open_head, leds=sim.leds, simulated=sim))
        ft = runner.field_time
    wall = time.perf_counter() - t0
    state = read_journal(out / "journal.jsonl")
    decoded, wrong, far = labels(rig, sim.scene, state)
    truth = sim.scene.truth
    err, nv, joint, eig = errors(survey, truth)
    err_iv, nv_iv, joint_iv, eig_iv = errors(without_views(survey), truth)
    seen = {(c, n) for (n, c, _) in state.observations}
    extra: dict = {}
    if mode != "sequential":
        extra["breakdown"] = breakdown(rig, sim, state) | {"priced": {c: dict(v) for c, v in _PRICED.items()},
                                                           "wide_blobs": wide_blobs(rig, InProcessRig(rig), state)}
        stats = _STATS[-1]
        extra["rounds"] = (stats.rounds_s, stats.classes, stats.pause_updates, stats.round_views)
        first = sum(1 for key in state.views if key[2] == 0)
        q = (len(state.views) - first) / max(first, 1)
        extra["planner"] = planner_prediction(rig, InProcessRig(rig), q)
        extra["planner6"] = planner_prediction(rig, InProcessRig(rig), q, 6.0)
    return extra | {"field": ft, "wall": wall, "readings": len(state.observations), "decoded": decoded, "wrong": wrong,
            "far": far, "missing": len(sim.scene.visible_pairs() - seen), "rms": float(np.sqrt(np.mean(np.square(err)))),
            "views": len(state.views), "err": err, "nees": nv, "err_iv": err_iv, "nees_iv": nv_iv,
            "joint": joint, "joint_iv": joint_iv, "eig": eig, "eig_iv": eig_iv,
            "named_views": len({o.view for o in survey.observations if o.view is not None})}


def anees_line(name: str, err: list[float], values: list[float]) -> str:
    n = len(values)
    lo, hi = chi2.ppf([0.025, 0.975], 2 * n) / n
    a = float(np.mean(values))
    return (f"  {name}: RMS {float(np.sqrt(np.mean(np.square(err)))):.5f} over {n} nodes; ANEES {a:.2f} "
            f"(95 % bounds {lo:.2f}-{hi:.2f}: {'inside' if lo <= a <= hi else 'OUTSIDE'})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--motes", type=int, default=30)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--fx", type=float, default=None, help="focal length, px (default width / 2: 90 deg wide)")
    ap.add_argument("--repeatability-deg", type=float, default=0.0,
                    help="head repeatability (rig.json head_repeatability_deg, part of sigma_deg 0.1)")
    ap.add_argument("--coded", action="append", default=None,
                    help='rig.json "coded" levers as JSON, e.g. \'{"retry": "continue", "fallback": "predicted", '
                    '"separate": "radio"}\'; repeated: each set of levers is its own coded survey of the same '
                    'scenes, side by side against one sequential run per seed')
    ap.add_argument("--field-boxes", action="store_true",
                    help="each camera searches a box around its visible nodes (rig.json cameras[].search, 5 deg "
                         "margin; across the +-180 deg seam for a camera whose nodes lie across it), both surveys")
    ap.add_argument("--box-margin-deg", type=float, default=5.0,
                    help="with --field-boxes: the margin around the visible nodes' bearings (degrees, default 5)")
    ap.add_argument("--video-seeds", type=int, default=1,
                    help="record each scene's coded surveys this many times (rig.json simulation.video_seed: the "
                         "motes' start phases and clocks and the frame noise drawn anew, the scene kept; the first "
                         "recording is the scene seed's): per scene the field time's mean and spread, and the "
                         "speed-up of the mean (default 1)")
    args = ap.parse_args()
    if args.video_seeds < 1:
        ap.error(f"--video-seeds: at least 1 ({args.video_seeds})")
    if args.box_margin_deg < 0:
        ap.error(f"--box-margin-deg: degrees >= 0 ({args.box_margin_deg})")
    levers = [json.loads(c) for c in (args.coded or ["{}"])]
    names = ["coded"] if len(levers) == 1 else [f"coded {json.dumps(c, separators=(',', ':'))}" for c in levers]
    rows: dict[str, list[dict]] = {"sequential": [], **{n: [] for n in names}}
    again: dict[str, list[list[dict]]] = {n: [] for n in names}  # name -> per scene, every recording's run
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            rows["sequential"].append(run(seed, args.motes, args.width, "sequential", Path(tmp) / f"sequential{seed}",
                                          args.fx, args.repeatability_deg, None, args.field_boxes,
                                          args.box_margin_deg))
            for i, (name, coded) in enumerate(zip(names, levers)):
                rows[name].append(run(seed, args.motes, args.width, "coded", Path(tmp) / f"coded{i}-{seed}", args.fx,
                                      args.repeatability_deg, coded, args.field_boxes, args.box_margin_deg))
                again[name].append([rows[name][-1]])
                for v in range(1, args.video_seeds):
                    again[name][-1].append(run(seed, args.motes, args.width, "coded",
                                               Path(tmp) / f"coded{i}-{seed}-v{v}", args.fx, args.repeatability_deg,
                                               coded, args.field_boxes, args.box_margin_deg,
                                               video_seed=video_seed_of(seed, v)))
    for mode, rs in rows.items():
        med = statistics.median
        print(f"{mode}: field time median {med(r['field'].total for r in rs):.1f} s "
              f"(seed 1: {rs[0]['field'].describe()}); wall median {med(r['wall'] for r in rs):.2f} s; "
              f"readings {sum(r['readings'] for r in rs)} ({sum(r['decoded'] for r in rs)} decoded in "
              f"{sum(r['views'] for r in rs)} recordings), missing visible pairs {sum(r['missing'] for r in rs)}, "
              f"mislabelled {sum(r['wrong'] for r in rs)}, > 0.05 deg off {sum(r['far'] for r in rs)}; "
              f"RMS position error median {med(r['rms'] for r in rs):.5f}")
    for name in names:
        _report(name, rows, args)
    if args.video_seeds > 1:
        for name in names:
            print(recordings_line(name, again[name], [r["field"].total for r in rows["sequential"]]))


def video_seed_of(seed: int, recording: int) -> int:
    """rig.json ``simulation.video_seed`` of scene ``seed``'s recording ``recording`` >= 1 (recording 0
    is the scene seed's own)."""
    return 1000 * seed + recording


def recordings_line(name: str, runs: list[list[dict]], sequential: list[float]) -> str:
    """Per scene, the coded field time over its recordings (mean, sample sd, each), the
    speed-ups of the means (median over scenes, and each scene's), and the mislabelled readings
    and unread visible pairs summed over every recording."""
    times = [[r["field"].total for r in scene] for scene in runs]
    means = [statistics.mean(t) for t in times]
    speed = [s / m for s, m in zip(sequential, means)]
    scenes = "; ".join(f"seed {k}: mean {m:.2f} s, sd {statistics.stdev(t):.2f} ({' '.join(f'{x:.2f}' for x in t)})"
                       for k, (m, t) in enumerate(zip(means, times), start=1))
    return (f"{name}, {len(times[0])} recordings per scene: {scenes}; speed-up of the means median "
            f"{statistics.median(speed):.2f}x (per seed {' '.join(f'{x:.2f}x' for x in speed)}); over all "
            f"{sum(len(t) for t in runs)} recordings: mislabelled {sum(r['wrong'] for t in runs for r in t)}, "
            f"missing visible pairs {sum(r['missing'] for t in runs for r in t)}")


def joint_line(scenes: list[tuple[float, int]]) -> str:
    """The scenes' joint NEES (each chi-square with its dof when the covariance is honest,
    whatever the nodes share), per scene over its dof, and summed with two-sided 95 % bounds."""
    total, dof = sum(v for v, _ in scenes), sum(n for _, n in scenes)
    lo, hi = chi2.ppf([0.025, 0.975], dof) / dof
    outside = sum(not chi2.ppf(0.025, n) <= v <= chi2.ppf(0.975, n) for v, n in scenes)
    return (f"    joint NEES / dof per scene {' '.join(f'{v / n:.2f}' for v, n in scenes)} ({outside} of {len(scenes)} "
            f"outside its own 95 % bounds); all scenes {total / dof:.2f} over {dof} dof (95 % bounds {lo:.2f}-{hi:.2f}: "
            f"{'inside' if lo <= total / dof <= hi else 'OUTSIDE'})")


def correlated_anees_line(scenes: list[list[float]], eigenvalues: list[np.ndarray]) -> str:
    """The per-node ANEES (planar, 2 dof) against its two-sided 95 % bounds under the scenes'
    joint covariances (:func:`fgloc.evaluate.anees_bounds.anees_bounds_of_eigenvalues`: a
    scene's summed NEES is a generalized chi-square, the scenes independent), over all scenes
    and per scene from its own eigenvalues."""
    values = [v for scene in scenes for v in scene]
    a = float(np.mean(values))
    lo, hi = anees_bounds_of_eigenvalues(eigenvalues, 2)
    per_scene = [(float(np.mean(v)), *anees_bounds_of_eigenvalues([e], 2)) for v, e in zip(scenes, eigenvalues)]
    outside = sum(not s_lo <= s <= s_hi for s, s_lo, s_hi in per_scene)
    return (f"    ANEES {a:.2f} under the scenes' joint covariances: 95 % bounds {lo:.2f}-{hi:.2f} "
            f"({'inside' if lo <= a <= hi else 'OUTSIDE'}); per seed "
            f"{' '.join(f'{s:.2f} ({s_lo:.2f}-{s_hi:.2f})' for s, s_lo, s_hi in per_scene)} "
            f"({outside} of {len(per_scene)} outside its own bounds)")


def _report(name: str, rows: dict[str, list[dict]], args: argparse.Namespace) -> None:
    """Per-seed breakdown, speed-up, RMS ratio and accuracy of the coded survey ``name``."""
    print(f"{name}:")
    for k, r in enumerate(rows[name], start=1):
        b = r["breakdown"]
        priced = b.get("priced", {})
        cams = "; ".join(f"{c}: " + ", ".join(f"{kind} {n0}+{n1} ({fr} frames, {priced.get(c, {}).get(kind, 0.0):.1f} s)"
                                              for kind, (n0, n1, fr) in sorted(v.items()))
                         + (f", zoom back {priced[c]['zoom back']:.1f} s" if "zoom back" in priced.get(c, {}) else "")
                         for c, v in b["cameras"].items())
        blobs = "; ".join(f"{c} {n} ({at_read} at a reading, {at_crowd} at a mote within 4 px of another)"
                          for c, (n, at_read, at_crowd) in b.get("wide_blobs", {}).items())
        print(f"  seed {k}: wide-pass unexplained blobs: {blobs}")
        print(f"  seed {k}: coded {r['field'].describe()}; recordings first+again: {cams}; fallback nodes "
              f"{b['fallback_nodes']} ({b['fallback_s']:.1f} s summed); planner's price for this rig "
              f"{r['planner']:.1f} s (separation 4 px; 6 px: {r['planner6']:.1f} s)")
    rounds = [r["rounds"] for r in rows[name]]
    if any(classes for _, classes, _, _ in rounds):
        print(f"  radio rounds: priced median {statistics.median(t for t, *_ in rounds):.1f} s (seeds "
              f"{' '.join(f'{t:.1f}' for t, *_ in rounds)} s; rounds' lanes and pause updates); classes "
              f"{' '.join(str(k) for _, k, _, _ in rounds)}; pause updates {sum(u for _, _, u, _ in rounds)}; "
              f"round views {sum(v for *_, v in rounds)}")
    ratio = [c["rms"] / s["rms"] for c, s in zip(rows[name], rows["sequential"])]
    speed = [s["field"].total / c["field"].total for c, s in zip(rows[name], rows["sequential"])]
    print(f"coded / sequential: RMS ratio median {statistics.median(ratio):.3f} (range {min(ratio):.3f}-{max(ratio):.3f}); "
          f"field-time speed-up median {statistics.median(speed):.2f}x (range {min(speed):.2f}-{max(speed):.2f}); "
          f"per seed {' '.join(f'{x:.2f}x' for x in speed)}")
    print(f"accuracy over {args.seeds} seeds, head repeatability {args.repeatability_deg} deg "
          f"({sum(r['named_views'] for r in rows[name])} views named in the coded survey.json files):")
    for label, mode, key in (("sequential", "sequential", ""), ("coded, views solved", name, ""),
                             ("coded, views ignored", name, "_iv")):
        rs = rows[mode]
        print(anees_line(label, [e for r in rs for e in r["err" + key]], [v for r in rs for v in r["nees" + key]]))
        per_seed = [float(np.mean(r["nees" + key])) for r in rs]
        half = 1.96 * statistics.stdev(per_seed) / math.sqrt(len(per_seed)) if len(per_seed) > 1 else float("nan")
        print(f"    per-seed ANEES {' '.join(f'{a:.2f}' for a in per_seed)}; mean {statistics.mean(per_seed):.2f} "
              f"+- {half:.2f} (95 %, seeds as independent samples: a scene's nodes share its pose errors)")
        print(joint_line([r["joint" + key] for r in rs]))
        print(correlated_anees_line([r["nees" + key] for r in rs], [r["eig" + key] for r in rs]))
    print(f"  pooled RMS ratio coded / sequential: views solved {_ratio(rows, 'err', name):.3f}, "
          f"views ignored {_ratio(rows, 'err_iv', name):.3f}")


def _ratio(rows: dict[str, list[dict]], key: str, name: str = "coded") -> float:
    """Pooled RMS of the coded survey ``name``'s ``key`` errors over the sequential survey's."""
    def rms(errs: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(errs))))
    return rms([e for r in rows[name] for e in r[key]]) / rms([e for r in rows["sequential"] for e in r["err"]])


if __name__ == "__main__":
    main()
