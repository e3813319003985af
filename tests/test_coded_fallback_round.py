"""The fallback round (lever ``fallback: "round"``): the motes left to the fallback blink alone,
recorded at the survey zoom, before any sequential search; it runs only where it pays."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import fgloc.survey.coded_fallback_round as fallback_round
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.files.journal import read_journal
from fgloc.survey.coded import CodedSurvey
from fgloc.survey.coded_fallback_round import (
    ROUND_PREFIX,
    blobs_after_round,
    darkened_lamps,
    radius_px,
    round_pays,
    round_views,
)
from fgloc.survey.session import run_survey
from fgloc.survey.view_planner import coverage
from tests.test_survey_coded import (
    check_labels,
    check_lever_in_schema,
    coded_rig,
    cut_and_resume,
    opened,
    parsed,
    view_records,
)

K = CameraIntrinsics(fx=160.0, fy=160.0, cx=160.0, cy=120.0, width=320, height=240)


def test_blobs_after_round_keeps_what_no_round_view_saw_and_adds_the_rounds_own() -> None:
    before = np.array([(0.05, 0.02), (1.2, 0.0), (-0.1, -0.05), (0.0, 0.6)])
    after = np.array([(0.07, 0.01)])
    out = blobs_after_round(K, before, [(0.0, 0.0)], 16.0, after)
    # (0.05, 0.02) and (-0.1, -0.05) lie well inside the view at (0, 0); 1.2 rad of pan and
    # 0.6 rad of tilt lie outside its 90 x 74 deg
    assert out.tolist() == [[1.2, 0.0], [0.0, 0.6], [0.07, 0.01]]
    assert blobs_after_round(K, before, [], 16.0, after).shape == (5, 2)  # no round view: nothing replaced


def test_round_views_hold_every_predicted_direction_with_the_radius_inside_the_image() -> None:
    rng = np.random.default_rng(4)
    for trial in range(10):
        pts = np.column_stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-0.6, 0.1, 40)])
        views = round_views(K, pts, 16.0, (0.0, 0.0), (-1.2, 0.4))
        seen = coverage(K, pts, np.array(views), 16.0 + radius_px(K)).any(axis=0)
        assert seen.all(), (trial, pts[~seen])
        assert len(views) < 40  # views, not one per mote


def _coded(tmp_path: Path) -> CodedSurvey:
    rig = parsed(coded_rig(30, 320))
    _opened, sim = opened(rig)
    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    coded.here = {c: (0.0, -0.3) for c in rig.camera_ids}
    return coded


def _searches_at_spots(tmp_path: Path) -> tuple[CodedSurvey, list[tuple[float, float]], dict, dict]:
    """A survey's pricing state, 20 spots across cam0's box with one search look each, and one round view."""
    coded = _coded(tmp_path)
    rng = np.random.default_rng(5)
    spots = [(float(p), float(t)) for p, t in zip(rng.uniform(-1.0, 1.0, 20), rng.uniform(-0.5, -0.1, 20))]
    looks = {"cam0": {f"n{k:03d}": [spots[k]] for k in range(20)}, "cam1": {}}
    return coded, spots, looks, {"cam0": [(0.0, -0.3)]}


def test_the_round_pays_by_the_searches_it_saves_and_lamps_are_not_saved(tmp_path: Path) -> None:
    coded, spots, looks, one_view = _searches_at_spots(tmp_path)
    assert round_pays(coded, one_view, looks, 1)  # 20 searches across the box against one view
    assert not round_pays(coded, {"cam0": [(0.0, -0.3)] * 6}, looks, 1)  # six recordings cost more
    few = {"cam0": {"n000": [spots[0]], "n001": [spots[1]]}, "cam1": {}}
    assert not round_pays(coded, one_view, few, 1)  # two searches cost less than a recording
    coded.final_lamps = {"cam0": np.array(spots), "cam1": np.zeros((0, 2))}
    assert not round_pays(coded, one_view, looks, 1)  # every look is at a lamp: the searches stay


def test_the_searches_are_priced_with_the_frames_each_look_grabs(tmp_path: Path) -> None:
    """Every look of a search grabs a frame (two with on-off detection): a cost the round saves
    for sure, so it is in the searches' price (leaving it out declined a round that saved 20 s
    at 1000 motes in frames, docs/blink-codes.md "Blobs another view resolved")."""
    from dataclasses import replace

    from fgloc.survey.clock import Frames, price

    coded, _spots, looks, _one_view = _searches_at_spots(tmp_path)
    single = fallback_round._searches_s(coded, looks)
    one, two = (price([Frames(n)], coded.timing["cam0"]).total for n in (1, 2))
    assert single > 20 * one
    coded.rig = replace(coded.rig, search=replace(coded.rig.search, detection="on-off"))
    assert fallback_round._searches_s(coded, looks) == pytest.approx(single + 20 * (two - one))  # 20 looks


def test_a_lamp_at_two_read_motes_the_round_pauses_is_darkened() -> None:
    lamps = np.array([(0.10, -0.20), (0.30, -0.20), (0.50, -0.20), (0.70, -0.20), (0.90, -0.20)])
    radii = np.full(5, 0.004)  # rad
    near = {  # node -> bearing: two motes 0.002 rad either side of lamps 0-3, one beside lamp 4
        "a0": (0.098, -0.20), "b0": (0.102, -0.20),
        "a1": (0.298, -0.20), "b1": (0.302, -0.20),
        "a2": (0.498, -0.20), "b2": (0.502, -0.20),
        "a3": (0.690, -0.20), "b3": (0.710, -0.20),  # 0.01 rad off: outside the lamp's radius
        "a4": (0.899, -0.20),
    }
    readings = {n: pan_tilt_bearing(p, t) for n, (p, t) in near.items()}
    lit = {"a1", "a2", "b2", "a4"}
    # lamp 0: both paused; lamp 1: one stays lit (it blinks alone); lamp 2: both lit (still merged);
    # lamp 3: no reading inside; lamp 4: one read mote inside (a lamp beside a mote stays lit)
    assert darkened_lamps(lamps, radii, readings, lit) == [True, True, False, False, False]
    assert darkened_lamps(lamps, radii, {}, lit) == [False] * 5
    assert darkened_lamps(lamps, np.full(5, 0.012), readings, set())[3]  # a wider radius holds lamp 3's pair


def test_the_round_pays_where_the_ladders_lamps_are_crowds_it_darkens(tmp_path: Path) -> None:
    coded, spots, looks, one_view = _searches_at_spots(tmp_path)
    coded.final_lamps = {"cam0": np.array(spots), "cam1": np.zeros((0, 2))}
    coded.final_lamp_radii = {"cam0": np.full(20, 0.004), "cam1": np.zeros(0)}
    pairs = {f"{side}{k:03d}": pan_tilt_bearing(p + d, t) for k, (p, t) in enumerate(spots)
             for side, d in (("a", -0.002), ("b", 0.002))}  # two read motes in every lamp
    assert round_pays(coded, one_view, looks, 1, {"cam0": pairs}, set())  # all paused: the looks are saved
    assert not round_pays(coded, one_view, looks, 1, {"cam0": pairs}, set(pairs))  # all lit: merged still
    assert not round_pays(coded, one_view, looks, 1)  # no readings: lamps, as before


def _scene(fallback: str, seed: int = 1) -> dict:
    """60 motes, 30 % of the pairs occluded: the predicted fallback searches (tests/test_coded_fallback_order.py).
    Seed 4's forced round records four views over both cameras and reads a mote there, with
    the level decoder, the fixed length and the three-rung ladder (with the default fit,
    adaptive length and two-rung ladder it reads nothing new in this scene). Zooms apart from
    moves: the recordings start at the clock times this scene was chosen at."""
    data = coded_rig(60, 320, occlusion=0.3, seed=seed)
    data["coded"] = {"fallback": fallback, "decode": "levels", "length": "fixed", "levels": [1 / 9, 3 / 9, 1.0],
                     "zoom_moves": "apart"}
    return data


def _force_round(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(fallback_round, "round_pays", lambda *args: True)


def test_the_round_lights_the_unread_motes_alone_and_every_visible_pair_is_read(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _force_round(monkeypatch)
    rig = parsed(_scene("round", seed=4))
    rig_opened, sim = opened(rig)
    out = tmp_path / "o"
    run_survey(rig, out, opened=rig_opened)
    records = view_records(out / "journal.jsonl")
    before = [r for r in records if not r["view"].startswith(ROUND_PREFIX)]
    rounds = [r for r in records if r["view"].startswith(ROUND_PREFIX)]
    assert rounds, "the forced round records views"
    starts = [r for r in map(json.loads, (out / "journal.jsonl").read_text().splitlines())
              if r["type"] == "codes" and r["action"] == "start"]
    silent = set().union(*(r.get("silent", []) for r in starts))
    read = {c: {rd["node"] for r in before if r["camera"] == c for rd in r["readings"]} for c in rig.camera_ids}
    unread = sorted(n for n in rig.node_ids if n not in silent and any(n not in read[c] for c in rig.camera_ids))
    assert all(r["lit"] == unread for r in rounds)
    # paused motes are dark: a round view reads lit motes only; here it reads one the camera had not
    st = read_journal(out / "journal.jsonl")
    round_obs = [o for o in st.observations.values() if o.view is not None and o.view.startswith(ROUND_PREFIX)]
    assert round_obs and all(o.node in unread and o.node not in read[o.camera] for o in round_obs)
    assert all(r["zoom"] == rig.cameras[rig.camera_ids.index(r["camera"])].zoom for r in rounds)
    assert not sim.scene.visible_pairs() - {(c, n) for (n, c, _) in st.observations}
    assert check_labels(rig, sim.scene, st, 0.5) > 50


def test_the_round_resumes_to_the_uncut_readings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _force_round(monkeypatch)
    records, states = cut_and_resume(parsed(_scene("round", seed=4)), tmp_path, ROUND_PREFIX)
    lit = {tuple(r["lit"]) for r in records if r["type"] == "view" and r["view"].startswith(ROUND_PREFIX)}
    assert len(lit) == 1  # one round, the same lit motes in every view
    for st in states:  # resume_from_cuts checked the readings; the round was recorded once, as planned
        assert {v for (_c, v, _a) in st.views if v.startswith(ROUND_PREFIX)} == {
            r["view"] for r in records if r["type"] == "view" and r["view"].startswith(ROUND_PREFIX)}


def test_where_the_round_does_not_pay_the_survey_is_the_predicted_one(tmp_path: Path) -> None:
    results = {}
    for fallback in ("predicted", "round"):
        rig = parsed(_scene(fallback))
        rig_opened, _sim = opened(rig)
        _survey, runner = run_survey(rig, tmp_path / fallback, opened=rig_opened)
        st = read_journal(tmp_path / fallback / "journal.jsonl")
        results[fallback] = (runner.field_time.total, sorted((k, (o.pan, o.tilt)) for k, o in st.observations.items()))
    assert not [r for r in view_records(tmp_path / "round" / "journal.jsonl") if r["view"].startswith(ROUND_PREFIX)]
    assert results["round"] == results["predicted"]
    assert math.isfinite(results["round"][0])


def test_the_fallback_lever_is_schema_checked_and_a_disagreeing_flag_refused_on_resume(tmp_path: Path, capsys) -> None:
    from fgloc.core.errors import FglocError
    from fgloc.survey.coded_levers import coded_settings
    from tests.test_survey_coded import check_lever_refused_on_resume

    check_lever_in_schema("fallback", "round", "rounds")
    assert coded_settings(parsed(coded_rig(6, width=160))).fallback == "round"  # the default
    with pytest.raises(FglocError, match=r"--coded: fallback: expected one of blobs, predicted, round, got 'x'"):
        coded_settings(parsed(coded_rig(6, width=160)), {"fallback": "x"})
    check_lever_refused_on_resume(coded_rig(6, width=160), tmp_path, capsys, "fallback=predicted", "fallback",
                                  "fallback=round")


def _round_with(covers: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[int, int, dict, bool]:
    """The forced round of seed 4 with lever ``covers``: (directions its views were planned over,
    round views recorded, the survey's readings, whether every visible pair was read)."""
    planned: list[int] = []
    plan = fallback_round.round_views

    def counted(intr, predicted, *args):  # type: ignore[no-untyped-def]
        planned.append(len(np.asarray(predicted).reshape(-1, 2)))
        return plan(intr, predicted, *args)

    monkeypatch.setattr(fallback_round, "round_views", counted)
    data = _scene("round", seed=4)
    data["coded"]["covers"] = covers
    rig = parsed(data)
    rig_opened, sim = opened(rig)
    run_survey(rig, tmp_path / covers, opened=rig_opened)
    st = read_journal(tmp_path / covers / "journal.jsonl")
    views = [r for r in view_records(tmp_path / covers / "journal.jsonl") if r["view"].startswith(ROUND_PREFIX)]
    readings = {k: (o.pan, o.tilt) for k, o in st.observations.items()}
    return sum(planned), len(views), readings, not sim.scene.visible_pairs() - {(c, n) for (n, c, _) in st.observations}


def test_the_round_covers_only_the_motes_the_fallback_would_search_and_reads_the_same(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Lever ``covers``: ``searched`` (the default) plans the round over the placed motes with
    a blob where the fallback looks for them; ``placed`` over every placed mote. In this scene
    some placed motes have no such blob: fewer directions, fewer views, the same motes read
    (the round's one reading from another view, so within a few hundredths of a degree)."""
    _force_round(monkeypatch)
    placed = _round_with("placed", tmp_path, monkeypatch)
    searched = _round_with("searched", tmp_path, monkeypatch)
    assert searched[0] < placed[0]
    assert 0 < searched[1] < placed[1]
    assert searched[2].keys() == placed[2].keys() and searched[3] and placed[3]
    assert max(max(abs(a - b) for a, b in zip(searched[2][k], placed[2][k])) for k in placed[2]) < math.radians(0.05)


def test_an_old_header_covers_every_placed_mote_and_the_lever_is_schema_checked() -> None:
    from fgloc.survey.coded_levers import LEGACY
    from tests.test_survey_coded import resumed_and_new

    assert LEGACY["covers"] == "placed"
    assert resumed_and_new("covers", fallback="round", levels=[2 / 9, 1.0]) == ("placed", "searched")
    check_lever_in_schema("covers", "placed", "all")
