"""Per-camera search boxes (rig.json ``cameras[].search``): parsed, refused in one line when
empty, and obeyed by the sequential locator and the coded survey's view plan."""

from __future__ import annotations

import json
import math

import pytest

from fgloc.cli import main
from fgloc.drivers.inprocess_rig import InProcessRig
from fgloc.files.journal import read_journal
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_labels, coded_rig, opened, parsed, view_records


def test_a_camera_box_overrides_the_rig_search_field_by_field():
    data = coded_rig(10)
    data["search"] = {"tilt_min_deg": -80, "tilt_max_deg": 5}
    data["cameras"][1]["search"] = {"pan_min_deg": -30, "pan_max_deg": 60}
    rig = parsed(data)
    own, shared = rig.search_for("cam1"), rig.search_for("cam0")
    assert shared is rig.search
    assert (math.degrees(own.pan_min), math.degrees(own.pan_max)) == pytest.approx((-30, 60))
    assert (own.tilt_min, own.tilt_max) == (rig.search.tilt_min, rig.search.tilt_max)  # from the rig's search
    assert own.method == rig.search.method


@pytest.mark.parametrize("box, field", [({"pan_min_deg": 40, "pan_max_deg": 10}, "cameras[1].search.pan_max_deg"),
                                        ({"tilt_min_deg": 20}, "cameras[1].search.tilt_max_deg"),
                                        ({"pan_maxdeg": 10}, "cameras[1].search")])
def test_a_bad_camera_box_is_one_line_naming_the_field(tmp_path, capsys, box, field):
    data = coded_rig(10)
    data["search"] = {"tilt_min_deg": -80, "tilt_max_deg": 5}
    data["cameras"][1]["search"] = box
    (tmp_path / "rig.json").write_text(json.dumps(data))
    rc = main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "out"), "--simulate", "--no-live"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and field in err[0], err
    assert not (tmp_path / "out" / "journal.jsonl").exists()


def test_sequential_cameras_search_their_own_box(tmp_path):
    data = coded_rig(6, identification="sequential")
    data["cameras"][0]["search"] = {"pan_min_deg": -20, "pan_max_deg": 95, "tilt_min_deg": -60, "tilt_max_deg": 0}
    rig = parsed(data)
    _, runner = run_survey(rig, tmp_path / "s", opened=opened(rig)[0])
    assert runner.workers["cam0"].locator.search == rig.search_for("cam0") != rig.search
    assert runner.workers["cam1"].locator.search == rig.search
    assert runner.workers["cam0"].home == (0.0, math.radians(-30.0))


def test_coded_views_stay_in_each_camera_s_field_box_and_read_every_visible_pair(tmp_path):
    """Boxes around each camera's visible nodes (``SimScene.field_search_boxes``): every wide
    view is planned inside its camera's box, every visible pair is still read, and the survey
    records fewer wide views and less field time than with the rig's all-pan box."""
    data = coded_rig(30, width=320)
    full_rig = parsed(data)
    boxes = InProcessRig(full_rig).scene.field_search_boxes()
    assert all("pan_min_deg" in b for b in boxes.values())  # seed 1: neither camera sees across the seam
    for cam in data["cameras"]:
        cam["search"] = boxes[cam["id"]]
    rig = parsed(data)
    survey, runner = run_survey(rig, tmp_path / "box", opened=(o := opened(rig))[0])
    _, full_runner = run_survey(full_rig, tmp_path / "all", opened=opened(full_rig)[0])
    wide = [r for r in view_records(tmp_path / "box" / "journal.jsonl") if r["view"].startswith("w") and r["attempt"] == 0]
    for r in wide:
        b = boxes[r["camera"]]
        assert b["pan_min_deg"] - 1e-9 <= math.degrees(r["target"][0]) <= b["pan_max_deg"] + 1e-9
        assert b["tilt_min_deg"] - 1e-9 <= math.degrees(r["target"][1]) <= b["tilt_max_deg"] + 1e-9
    full_wide = [r for r in view_records(tmp_path / "all" / "journal.jsonl") if r["view"].startswith("w")
                 and r["attempt"] == 0]
    assert len(wide) < len(full_wide)
    assert {(x.camera, x.node) for x in survey.observations} == o[1].scene.visible_pairs()
    assert runner.field_time.total < full_runner.field_time.total
    assert read_journal(tmp_path / "box" / "journal.jsonl").duplicates_ignored == 0


def test_a_box_across_the_pan_seam_is_searched_as_one_box(tmp_path):
    """Seed 3: cam0's visible nodes lie across the +-180 deg pan seam, so its field box runs
    from -209 to -116 deg (``field_search_boxes``). The coded survey plans its wide views inside
    that box (pans taken mod 360), needs fewer of them than the all-pan box, and the coded and
    the sequential survey both read every visible pair, the coded readings on their motes."""
    data = coded_rig(30, width=320, seed=3)
    full_rig = parsed(data)
    boxes = InProcessRig(full_rig).scene.field_search_boxes()
    box = boxes["cam0"]
    assert box["pan_min_deg"] < -180.0 < box["pan_max_deg"]
    assert box["pan_max_deg"] - box["pan_min_deg"] < 120.0
    for cam in data["cameras"]:
        cam["search"] = boxes[cam["id"]]
    rig = parsed(data)
    rig_opened, sim = opened(rig)
    survey, _ = run_survey(rig, tmp_path / "coded", opened=rig_opened)
    assert {(x.camera, x.node) for x in survey.observations} == sim.scene.visible_pairs()
    state = read_journal(tmp_path / "coded" / "journal.jsonl")
    assert state.duplicates_ignored == 0
    check_labels(rig, sim.scene, state, max_error_deg=0.2)
    wide = [r for r in view_records(tmp_path / "coded" / "journal.jsonl")
            if r["camera"] == "cam0" and r["view"].startswith("w") and r["attempt"] == 0]
    for r in wide:
        pan = math.degrees(r["target"][0])
        assert any(box["pan_min_deg"] - 1e-9 <= pan + k <= box["pan_max_deg"] + 1e-9 for k in (-360, 0, 360))
    _, full_runner = run_survey(full_rig, tmp_path / "all", opened=opened(full_rig)[0])
    full_wide = [r for r in view_records(tmp_path / "all" / "journal.jsonl")
                 if r["camera"] == "cam0" and r["view"].startswith("w") and r["attempt"] == 0]
    assert len(wide) < len(full_wide)
    data["identification"] = "sequential"
    seq_rig = parsed(data)
    seq_opened, seq_sim = opened(seq_rig)
    seq, _ = run_survey(seq_rig, tmp_path / "sequential", opened=seq_opened)
    assert {(x.camera, x.node) for x in seq.observations} == seq_sim.scene.visible_pairs()
