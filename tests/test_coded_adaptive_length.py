"""Lever ``length: adaptive``: a view's first recording stops at 2L + 2 frames when another L
samples could read nothing new (:func:`fgloc.survey.coded_recording.record_adaptive`)."""

from __future__ import annotations

import json

import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.files.journal import read_journal
from fgloc.survey.session import run_survey
from tests import test_survey_coded as sc
from tests.test_survey_coded_levers import survey_reads_every_visible_pair

L = code_book(30).length  # the 30-mote scene's book (15 bits)
L12 = code_book(12).length


def _rig(length: str, n: int = 30, width: int = 320, **levers: str) -> dict:
    data = sc.coded_rig(n, width)
    data["coded"] = {"length": length} | levers
    return data


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The 30-mote scene surveyed with each length: (records, runner) per lever value."""
    out = {}
    for length in ("fixed", "adaptive"):
        path = tmp_path_factory.mktemp(length)
        runner, _, _ = survey_reads_every_visible_pair(sc.parsed(_rig(length)), path)
        out[length] = (sc.view_records(path / "journal.jsonl"), runner)
    return out


def test_adaptive_views_stop_at_2l_plus_2_and_read_every_visible_pair(both):
    fixed, fixed_runner = both["fixed"]
    adaptive, runner = both["adaptive"]
    assert not any(r.get("stopped") for r in fixed)
    stopped = [r for r in adaptive if r.get("stopped")]
    assert stopped and all(r["frames"] == 2 * L + 2 and r["attempt"] == 0 for r in stopped)
    going_on = [r for r in adaptive if r["attempt"] == 0 and not r.get("stopped") and r["frames"] != L + 2]
    assert all(r["frames"] == 3 * L + 2 for r in going_on)  # went on as one recording
    # priced as recorded: fewer frames on the clock than the fixed survey's
    assert runner.field_time.phases["frames"] < fixed_runner.field_time.phases["frames"]


def test_a_stopped_view_left_no_blob_unexplained(both):
    """Every stopped view, wide or refinement tile, journaled no blob a longer recording could
    read (only border refusals)."""
    from fgloc.survey.coded_views import unexplained_blob

    adaptive, _ = both["adaptive"]
    stopped = [r for r in adaptive if r.get("stopped")]
    assert len(stopped) >= 2
    for r in stopped:
        assert not any(unexplained_blob(x) for x in r["refused"]), r["view"]


def test_adaptive_views_that_go_on_show_the_fixed_recording(tmp_path):
    """On the simulated rig a view that goes on to 3L + 2 decodes the very frames the fixed length
    records: the first such wide view's readings are the fixed survey's, reading for reading
    (with the first 2L + 2 frames' readings dropped; ``first_window`` keeps them:
    tests/test_coded_first_window.py)."""
    recs = {}
    for length in ("fixed", "adaptive"):
        # tiling "greedy": the fewest views put no first wide view of this scene past 2L + 2 frames
        rig = sc.parsed(_rig(length, 12, 160, first_window="dropped", tiling="greedy"))
        run_survey(rig, tmp_path / length, opened=sc.opened(rig)[0])
        recs[length] = {(r["camera"], r["view"], r["attempt"]): r for r in sc.view_records(tmp_path / length / "journal.jsonl")}
    went_on = [k for k, r in recs["adaptive"].items() if r["view"] == "w000" and r["frames"] == 3 * L12 + 2]
    assert went_on, "the scene should have a first wide view that goes on"
    for k in went_on:
        assert recs["adaptive"][k]["readings"] == recs["fixed"][k]["readings"]


def test_an_adaptive_survey_resumes_to_the_uncut_readings(tmp_path):
    records, states = sc.cut_and_resume(sc.parsed(_rig("adaptive", 12, 160)), tmp_path, "w")
    assert any(r.get("stopped") for r in records if r["type"] == "view")
    uncut = read_journal(tmp_path / "full" / "journal.jsonl").observations
    for st in states:
        assert {k: (o.pan, o.tilt) for k, o in st.observations.items()} == {k: (o.pan, o.tilt) for k, o in uncut.items()}


def test_the_length_is_kept_on_resume(tmp_path, capsys):
    sc.check_lever_refused_on_resume(_rig("adaptive", 12, 160), tmp_path, capsys, "length=fixed", "length", "length=adaptive")


def test_the_journal_records_the_length_and_a_stopped_view_validates(both, tmp_path):
    rig = sc.parsed(_rig("adaptive", 12, 160))
    run_survey(rig, tmp_path, opened=sc.opened(rig)[0])
    header = json.loads((tmp_path / "journal.jsonl").read_text().splitlines()[0])
    assert header["coded"]["length"] == "adaptive"
    state = read_journal(tmp_path / "journal.jsonl")  # validates every record against the schema
    assert any(v.get("stopped") for v in state.views.values())
