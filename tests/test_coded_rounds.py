"""Short and view-major radio-separation rounds in the integrated coded survey
(fgloc/survey/coded_rounds.py, coded_view_major.py; docs/blink-codes.md "Short and view-major rounds").

* ``rounds "short"``: a round view records L + 2 samples (a retry continues by L) and labels
  its blobs against the lit class's predicted motes only; nothing is mislabelled, every
  visible pair is still read, and a lit mote that is no candidate is never labelled, even
  with a candidate predicted on top of it.
* ``round_order "view"``: the schedule records every (camera, view, class) job exactly once,
  each camera visiting its views in order and once; a camera records only the class lit at
  that moment, a pause update is sent exactly when the lit class changes, and the lanes price
  one move per view and never start a recording before every recording of the class lit
  before it has ended.
* After the rounds, a wide blob counts as explained only when the rounds read every crowded
  mote predicted at it and no mote the camera has still not read is predicted near it (a mote
  one camera read may be placed a degree off, outside every class): the 640 x 480 radio survey
  of scripts/coded_survey.py (seed 1) reads every visible pair, and resumes to the same readings.
* Both resume from a kill to the uncut run's readings, no reading twice; a lever that
  disagrees with the journal is refused in one line (exit 2); a journal whose header predates
  these levers resumes with full, class-major rounds.
"""

from __future__ import annotations

import json
import math
import random

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.camera.pixel_angles import pan_tilt_to_pixel
from fgloc.core.model import Gauge, NodeMode
from fgloc.files.journal import JournalError, JournalHeader, JournalState, read_journal
from fgloc.survey.clock import Frames, PositionRead, Slew, Wait, op_time
from fgloc.survey.coded import CodedSurvey
from fgloc.survey.coded_levers import LEGACY, coded_settings
from fgloc.survey.coded_rounds import ROUND_RADIUS_PX, decode_round, round_frames
from fgloc.survey.session import run_survey
from fgloc.survey.view_planner import Slot, view_major_schedule
from tests.test_survey_coded import (
    check_labels,
    check_lever_refused_on_resume,
    coded_rig,
    cut_and_resume,
    opened,
    parsed,
    view_records,
)
from tests.test_survey_coded_levers import lever_rig, survey_reads_every_visible_pair

L30 = code_book(30).length


def round_records(path) -> list[dict]:
    return [r for r in view_records(path) if r["view"].startswith("s")]


# ----- short rounds on the in-process rig
def test_short_rounds_record_l_plus_2_and_label_only_their_candidates(tmp_path):
    rig = parsed(lever_rig(30, separate="radio", rounds="short"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path, 0.2)
    rounds = round_records(tmp_path / "journal.jsonl")
    assert rounds and any(r["readings"] for r in rounds)
    for r in rounds:
        assert r["frames"] == (L30 if r["attempt"] else L30 + 2), r  # L + 2, a retry goes on by L
        assert bool(r.get("continued")) == (r["attempt"] > 0) and "probe" not in r
        assert r["candidates"] and set(r["candidates"]) <= set(r["lit"])
        assert {rd["node"] for rd in r["readings"]} <= set(r["candidates"])
    wide = {(r["camera"], rd["node"]) for r in view_records(tmp_path / "journal.jsonl") if r["view"].startswith("w")
            for rd in r["readings"]}
    assert not wide & {(r["camera"], rd["node"]) for r in rounds for rd in r["readings"]}
    check_labels(rig, sim.scene, state, max_error_deg=0.2)


def test_full_rounds_record_3l_plus_2_decoded_blind(tmp_path):
    """The other value of the lever (the old rounds): no candidates, 3L + 2 first recordings."""
    rig = parsed(lever_rig(30, separate="radio", rounds="full"))
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    rounds = round_records(tmp_path / "journal.jsonl")
    assert rounds and all("candidates" not in r for r in rounds)
    assert all(r["frames"] == 3 * L30 + 2 for r in rounds if r["attempt"] == 0)


def test_a_lit_non_candidate_is_never_labelled():
    """On the in-process rig, a round view where four motes blink and the others are paused:
    labelled against three of them plus a dark decoy predicted on the fourth, the fourth (lit,
    no candidate) is never labelled, as itself or as the decoy; the three are labelled only
    at their own blobs. Ten recordings (different noise)."""
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.drivers.tinyos.blink import BlinkBroadcast, pause_packets

    rig = parsed(coded_rig(30, width=640))
    sim = InProcessRig(rig)
    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    sim.leds.broadcast_codes(BlinkBroadcast(coded.book.length, coded.first, len(coded.book),
                                            coded.camera.frame_period_s))
    intr = coded.intrinsics_at("cam0", coded.survey_zoom["cam0"])
    scene, ids = sim.scene, rig.node_ids
    vis = [j for j in range(len(ids)) if scene.visible[0, j] and ids[j] not in scene.dead]
    app = scene.apparent[0]
    # four visible motes at least 20 px apart in a view centred on the first of them
    head = (float(app[vis[0], 0]), float(app[vis[0], 1]))
    uv, front = pan_tilt_to_pixel(intr, app[:, 0], app[:, 1], *head)
    inside = [j for j in vis if front[j] and 30 <= uv[j, 0] <= intr.width - 30 and 30 <= uv[j, 1] <= intr.height - 30]
    chosen: list[int] = []
    for j in inside:
        if all(np.hypot(*(uv[j] - uv[i])) >= 20 for i in chosen) and all(
                np.hypot(*(uv[j] - uv[i])) >= 20 for i in inside if i != j and i not in chosen):
            chosen.append(j)
        if len(chosen) == 4:
            break
    assert len(chosen) == 4, "the scene should show four separate motes in one view"
    lit = [ids[j] for j in chosen]
    paused = set(coded.addresses.values()) - {coded.addresses[n] for n in lit}
    for p in pause_packets(paused, range(coded.first, max(coded.addresses.values()) + 1)):
        sim.leds.broadcast_codes(p, set(), 0.0)
    h = sim.open_head("cam0")
    h.move_to(*head)
    stray = lit[3]
    decoy = next(n for n in ids if n not in lit and n not in scene.dead)
    # the three lit candidates where they are, and a dark decoy predicted right on the stray
    cands = [(n, (float(app[ids.index(n), 0]), float(app[ids.index(n), 1]))) for n in lit[:3]]
    cands.append((decoy, (float(app[ids.index(stray), 0]), float(app[ids.index(stray), 1]))))
    labelled = refused = 0
    for k in range(10):
        frames = sim.record_blinks("cam0", round_frames(coded), 10.0 * k, f"stray/{k}")
        dec = decode_round(coded, frames, intr, head, cands)
        got = {coded.node_of_code[r.index]: (r.u, r.v) for r in dec.readings}
        assert stray not in got and decoy not in got, got
        for n, (u, v) in got.items():
            assert math.hypot(u - uv[ids.index(n), 0], v - uv[ids.index(n), 1]) <= 2.0, (n, u, v)
        labelled += len(got)
        refused += any(math.hypot(r.u - uv[ids.index(stray), 0], r.v - uv[ids.index(stray), 1]) < 3
                       for r in dec.refused)
    assert labelled >= 15  # the three candidates are read in most of the 30 chances
    assert refused >= 5  # the stray's blob is seen, and refused with its reason
    assert ROUND_RADIUS_PX > 2.0


# ----- the wide pass's blobs after the rounds
def test_a_blob_an_unread_placed_mote_may_hide_in_is_not_explained_by_the_rounds():
    """A wide blob whose crowded mote ``a`` (predicted 2 px away) the rounds read is explained
    only when no mote the camera has still not read is predicted within PREDICTED_RADIUS
    (3 deg) of it: ``b`` predicted 9 px away (1.03 deg at fx 502; outside RADIUS_PX, so in no
    class) keeps it for the fallback; ``c`` at 4 deg does not. A blob whose crowded mote
    the rounds did not read, or with none predicted near, goes to the zoom refinement."""
    from fgloc.camera.intrinsics import CameraIntrinsics
    from fgloc.camera.pixel_angles import pixel_to_pan_tilt
    from fgloc.survey.coded_levers import PREDICTED_RADIUS
    from fgloc.survey.coded_separation import RADIUS_PX, SeparationPlan, sort_wide_blobs

    intr = CameraIntrinsics(502.0, 502.0, 320.0, 240.0, 640, 480)
    head = (0.3, -0.2)

    def at(du: float, dv: float = 0.0) -> tuple[float, float]:
        p, t = pixel_to_pan_tilt(intr, np.array([320.0 + du, 240.0 + dv]), *head)
        return float(p), float(t)

    c_dir = (head[0] + math.radians(4.0) / math.cos(head[1]), head[1])  # 4 deg right of the image centre
    assert RADIUS_PX < 9.0 and math.degrees(9.0 / 502.0) < math.degrees(PREDICTED_RADIUS) < 4.0 - 0.1
    blob = ((320.0, 240.0), head, 0.0)
    lone = ((100.0, 100.0), head, 0.0)  # no crowded mote predicted near
    dirs = np.array([at(0.0), at(-220.0, -140.0)])
    plan = SeparationPlan({"a": 0}, {"cam0": {"a": at(2.0)}}, {"cam0": set()},
                          {"cam0": {"a": at(2.0), "b": at(9.0), "c": c_dir}}, {"cam0": {"a", "b", "c"}})
    assert sort_wide_blobs(intr, [blob, lone], dirs, plan, "cam0", {"a"}) == ([lone], [], [blob])
    assert sort_wide_blobs(intr, [blob, lone], dirs, plan, "cam0", {"a", "b"}) == ([lone], [blob], [])
    assert sort_wide_blobs(intr, [blob, lone], dirs, plan, "cam0", set()) == ([blob, lone], [], [])
    assert sort_wide_blobs(intr, [blob, lone], dirs, plan, "cam0", {"a", "b", "c"}) == ([lone], [blob], [])


def test_a_mote_predicted_off_its_merged_blob_is_still_read(tmp_path):
    """The 640 x 480 rig of scripts/coded_survey.py, seed 1, fields, radio separation: cam0's
    wide views merge n002 with n066 and n091 (5.5 and 6.9 px away). Read by cam1 alone, n002
    is placed where cam1's bearing meets the ground, 8.7 px (1.0 deg) off in cam0: outside
    RADIUS_PX of the blob, so in no class. The rounds read n066 and n091; the blob must not
    count as explained (cam0 would have no blob left and n002 would be journaled not found
    without a search): every visible pair is read once, none mislabelled. Killed before,
    in the middle of and after the refinement (clean and torn), each resume ends with the
    uncut run's readings and not-found records (the blob rule reads the journal only). With
    explain "views": "crowds" leaves this scene one refinement tile, too few cuts to resume from."""
    from fgloc.drivers.inprocess_rig import InProcessRig
    from tests.conftest import load_script

    rig = load_script("coded_survey").rig_for(1, 100, 640, "coded", 502, 0.0,
                                              {"video": "fields", "separate": "radio", "explain": "views"}, True)
    _, resumed = cut_and_resume(rig, tmp_path, "r")
    state = read_journal(tmp_path / "full" / "journal.jsonl")
    scene = InProcessRig(rig).scene
    assert {(c, n) for (n, c, _) in state.observations} == scene.visible_pairs()
    assert ("n002", "cam0") not in state.not_found and state.duplicates_ignored == 0
    check_labels(rig, scene, state, max_error_deg=0.2)
    for st in resumed:
        assert {k: (o.pan, o.tilt) for k, o in st.observations.items()} == {
            k: (o.pan, o.tilt) for k, o in state.observations.items()}
        assert set(st.not_found) == set(state.not_found) and st.duplicates_ignored == 0


# ----- the view-major schedule
def replay(needs: dict[str, list[set[int]]], slots: list[Slot]) -> None:
    """Check the schedule's invariants by replaying it (module docstring of coded_view_major)."""
    left = {c: [set(v) for v in views] for c, views in needs.items()}
    at = {c: 0 for c in left}
    lit = None
    for slot in slots:
        for c in left:
            while at[c] < len(left[c]) and not left[c][at[c]]:
                at[c] += 1
        current = {c: left[c][at[c]] for c in left if at[c] < len(left[c])}
        served = {k: sum(k in v for v in current.values()) for v in current.values() for k in v}
        finishes = {k: sum(v == {k} for v in current.values()) for k in served}
        rank = {k: (finishes[k], served[k]) for k in served}
        # the lit class finishes the most views, then serves the most cameras; ties keep the class lit before
        assert rank[slot.lit] == max(rank.values())
        if lit in rank and rank[lit] == rank[slot.lit]:
            assert slot.lit == lit
        for c, j in slot.views.items():
            assert j == at[c] and slot.lit in left[c][j]  # at its current view, a class it asked for
            left[c][j].discard(slot.lit)
        for c, v in current.items():  # a camera waits only when its view does not need the lit class
            assert c in slot.views or slot.lit not in v
        lit = slot.lit
    assert all(not v for views in left.values() for v in views)  # every job recorded


@pytest.mark.parametrize("seed", range(40))
def test_view_major_schedule_records_every_job_once(seed):
    rnd = random.Random(seed)
    classes = rnd.randint(1, 5)
    needs = {c: [set(rnd.sample(range(classes), rnd.randint(0, classes))) for _ in range(rnd.randint(0, 6))]
             for c in ("cam0", "cam1", "cam2")[:rnd.randint(1, 3)]}
    slots = view_major_schedule(needs)
    jobs = sorted((c, j, k) for c, views in needs.items() for j, v in enumerate(views) for k in v)
    done = [(c, j, s.lit) for s in slots for c, j in s.views.items()]
    assert sorted(done) == jobs and len(set(done)) == len(done)
    for c in needs:
        seq = [s.views[c] for s in slots if c in s.views]
        assert seq == sorted(seq)  # views in plan order, each visited in one stay
    replay(needs, slots)
    assert view_major_schedule(needs) == slots  # deterministic: a resume re-plans it


def test_view_major_schedule_by_hand():
    """cam0's first view needs classes 0 and 1, its second 1; cam1's only view 1 and 2.
    Class 1 serves both cameras first; then 0 (cam0) and 2 (cam1) serve one camera each: the
    lower class, 0; cam0 moves on to its second view, which needs 1 (one camera, as 2 for
    cam1: the lower); then 2 for cam1."""
    slots = view_major_schedule({"cam0": [{0, 1}, {1}], "cam1": [{1, 2}]})
    assert [(s.lit, s.views) for s in slots] == [
        (1, {"cam0": 0, "cam1": 0}), (0, {"cam0": 0}), (1, {"cam0": 1}), (2, {"cam1": 0})]
    # at a tie, the class lit already stays lit (no pause update), though 0 is lower
    assert [s.lit for s in view_major_schedule({"cam0": [{1}, {1}], "cam1": [{0, 1}]})] == [1, 1, 0]


def test_view_major_schedule_lets_a_finished_camera_move_on():
    """Class 0 and 2 serve two cameras each, class 1 only cam2, but 1 is all cam2's first view
    needs: lit first, it lets cam2 move on to its second view, which needs 0 with the others.
    Three slots; lighting the most-served class first takes four (0, 2, 1, then 0 for cam2)."""
    slots = view_major_schedule({"cam0": [{0, 2}], "cam1": [{0, 2}], "cam2": [{1}, {0}]})
    assert [(s.lit, s.views) for s in slots] == [
        (1, {"cam2": 0}), (0, {"cam0": 0, "cam1": 0, "cam2": 1}), (2, {"cam0": 0, "cam1": 0})]


# ----- view-major on the in-process rig: recorded as scheduled, priced per view
@pytest.fixture(scope="module")
def view_major30(tmp_path_factory):
    """The 30-mote radio survey with short, view-major rounds: the journal, what was lit at
    each recording, the pause broadcasts, and the lanes of the rounds stage."""
    from fgloc.drivers.tinyos.blink import BlinkPause, parse_blink_command

    out = tmp_path_factory.mktemp("vm30")
    rig = parsed(lever_rig(30, separate="radio", rounds="short", round_order="view"))
    rig_opened, sim = opened(rig)
    lit_at: dict[str, set[str]] = {}
    record = sim.record_blinks

    def recording(camera, n, t, key, fields=False):  # what the motes' side has lit right now
        paused = set(sim.leds.blink.paused)
        lit_at[key] = {n_ for n_, a in sim.leds.addresses.items() if a not in paused and n_ not in sim.scene.dead}
        return record(camera, n, t, key, fields)

    sim.record_blinks = recording  # type: ignore[method-assign]
    stages: list[dict] = []
    original = CodedSurvey.next_stage

    def next_stage(self):
        stages.append({c: list(ops) for c, ops in self.lanes.items()} | {"timing": self.lane_timing})
        original(self)

    CodedSurvey.next_stage = next_stage  # type: ignore[method-assign]
    try:
        _, runner = run_survey(rig, out, opened=rig_opened)
    finally:
        CodedSurvey.next_stage = original  # type: ignore[method-assign]
    state = read_journal(out / "journal.jsonl")
    pauses = [c for c in map(parse_blink_command, sim.leds.received) if isinstance(c, BlinkPause)]
    return rig, sim, state, out, lit_at, pauses, stages


def test_view_major_rounds_read_the_crowded_motes_each_job_once(view_major30):
    rig, sim, state, out, lit_at, pauses, _ = view_major30
    assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
    assert state.duplicates_ignored == 0
    check_labels(rig, sim.scene, state, max_error_deg=0.2)
    rounds = round_records(out / "journal.jsonl")
    classes = {r["round"] for r in rounds}
    assert len(classes) >= 2, "the scene should need more than one class"
    jobs = [(r["camera"], r["view"]) for r in rounds if r["attempt"] == 0]
    assert len(jobs) == len(set(jobs))
    for r in rounds:
        assert r["view"].startswith(f"s{r['round']}-v")
        # the camera recorded while exactly its class was lit (the others paused)
        assert lit_at[f"{r['view']}/{r['attempt']}"] == set(r["lit"]), r["view"]
    # at least one view served two classes without moving (the point of view-major)
    by_view: dict[tuple[str, str], set[int]] = {}
    for r in rounds:
        by_view.setdefault((r["camera"], r["view"].split("-")[1]), set()).add(r["round"])
    assert any(len(v) > 1 for v in by_view.values())
    # one pause update (3 broadcasts) per change of the lit class in recording order, and the resume
    order = [r["round"] for r in rounds if r["attempt"] == 0]
    changes = 1 + sum(a != b for a, b in zip(order, order[1:]))
    assert len(pauses) == 3 * (changes + 1) and not pauses[-1].paused


def test_view_major_lanes_move_once_per_view_and_wait_for_the_class_before(view_major30):
    rig, _, _, out, _, _, stages = view_major30
    rounds = round_records(out / "journal.jsonl")
    lanes = stages[1]  # [wide pass, rounds]
    timing = lanes["timing"]
    intervals = []  # (start, end, class) of every round recording, in journal order per camera
    for c in rig.camera_ids:
        mine = [r for r in rounds if r["camera"] == c]
        views = {r["view"].split("-")[1] for r in mine}
        ops = lanes[c]
        assert sum(isinstance(o, Slew) for o in ops) == len(views)  # one move per view, not per job
        assert sum(isinstance(o, PositionRead) for o in ops) == len(views)
        frames = [o for o in ops if isinstance(o, Frames)]
        assert [o.count for o in frames] == [r["frames"] for r in mine]
        assert all(o.phase == "round_wait" for o in ops if isinstance(o, Wait))
        t, k = 0.0, 0
        for o in ops:
            dt = op_time(o, timing[c])
            if isinstance(o, Frames):
                intervals.append((t, t + dt, mine[k]["round"], c))
                k += 1
            t += dt
    for a in intervals:  # a recording of another class never overlaps: its pause came between
        for b in intervals:
            if a[2] != b[2]:
                assert a[1] <= b[0] + 1e-9 or b[1] <= a[0] + 1e-9, (a, b)


# ----- resume and levers
@pytest.mark.parametrize("order", ["class", "view"])
def test_short_rounds_resume_to_the_uncut_readings(tmp_path, order):
    """Killed before the first round view, in the middle of the rounds (between recordings, and
    torn) and after the last: each resume re-plans the same rounds and candidates and ends with
    the uncut run's readings, each recording once."""
    rig = parsed(lever_rig(30, separate="radio", rounds="short", round_order=order))
    records, states = cut_and_resume(rig, tmp_path, "s")
    for k in range(len(states)):
        cands = {(r["camera"], r["view"]): r["candidates"] for r in round_records(tmp_path / f"cut{k}" / "journal.jsonl")}
        assert cands == {(r["camera"], r["view"]): r["candidates"] for r in records if r["type"] == "view"
                         and r["view"].startswith("s")}


@pytest.mark.parametrize(("flag", "named"), [("rounds=full", "rounds"), ("round_order=class", "round_order")])
def test_a_round_lever_that_disagrees_with_the_journal_is_refused_in_one_line(tmp_path, capsys, flag, named):
    data = coded_rig(6, width=160, identification="coded")
    data["coded"] = {"separate": "radio", "rounds": "short", "round_order": "view"}
    check_lever_refused_on_resume(data, tmp_path, capsys, flag, named, "rounds=short")


def test_a_header_without_the_round_levers_resumes_with_full_class_major_rounds(monkeypatch):
    """A journal written before ``rounds``/``round_order`` existed records six levers: it resumes
    with the rounds its writer knew, whatever today's defaults are; a new survey takes today's."""
    import fgloc.survey.coded_levers as levers
    from fgloc.survey.coded_settings import CodedSettings

    monkeypatch.setattr(levers, "CodedSettings",
                        lambda **kw: CodedSettings(**({"rounds": "short", "round_order": "view"} | kw)))
    six = {k: v for k, v in LEGACY.items() if k not in ("rounds", "round_order")} | {"separate": "radio",
                                                                                    "levels": [0.5, 1.0]}
    state = JournalState(JournalHeader(NodeMode.PLANAR, Gauge("cam0", "cam1"), 0.001, ["cam0", "cam1"], ["n0"],
                                       coded=six))
    rig = parsed(coded_rig(4, width=160))
    s = coded_settings(rig, None, state)
    assert (s.rounds, s.round_order, s.separate) == ("full", "class", "radio")
    assert (coded_settings(rig).rounds, coded_settings(rig).round_order) == ("short", "view")
    from fgloc.core.errors import FglocError

    with pytest.raises(FglocError, match=r"--coded: rounds: j\.jsonl was started with rounds 'full', got 'short'"):
        coded_settings(rig, {"rounds": "short"}, state, "j.jsonl")


def test_candidates_and_round_levers_are_schema_checked(tmp_path):
    from fgloc.files.json_io import check
    from fgloc.files.rig_config import RigConfigError

    data = coded_rig(6, width=160)
    data["coded"] = {"rounds": "short", "round_order": "view"}
    check(data, "rig", "rig.json", RigConfigError)
    for key, bad in (("rounds", "half"), ("round_order", "views")):
        with pytest.raises(RigConfigError, match=f"coded.{key}: expected one of"):
            check(data | {"coded": {key: bad}}, "rig", "rig.json", RigConfigError)
    rig = parsed(lever_rig(16, width=160, separate="radio", rounds="short"))
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    lines = (tmp_path / "journal.jsonl").read_text().splitlines()
    k = next(i for i, x in enumerate(lines) if '"candidates"' in x)
    bad = json.loads(lines[k])
    bad["candidates"] = [""]
    (tmp_path / "bad.jsonl").write_text("\n".join(lines[:k] + [json.dumps(bad)] + lines[k + 1:]) + "\n")
    with pytest.raises(JournalError, match=r"view\.candidates\[0\]: expected a non-empty string id"):
        read_journal(tmp_path / "bad.jsonl")
