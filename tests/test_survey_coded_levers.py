"""The planner's levers in the integrated coded survey (issue 16 follow-up): a retry that goes
on recording (sliding windows), radio separation of crowded motes by pause-by-bitmap, their
rig.json switches, and crash safety in each mode (resume never duplicates a reading)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.files.journal import read_journal
from fgloc.survey.clock import CameraTiming
from fgloc.survey.coded import coded_settings
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_labels, coded_rig, opened, parsed, view_records

PERIOD = CameraTiming().frame_period_s


def lever_rig(n_nodes: int = 30, width: int = 320, **coded):
    data = coded_rig(n_nodes, width)
    data["coded"] = coded
    return data


def test_continued_retry_goes_on_recording_and_reads_what_the_burst_missed(tmp_path):
    """retry "continue": a view with curable refusals records L more frames from where its
    recording ended (the survey clock continues, no new burst) and decodes the whole recording
    in sliding windows; what it reads is new (no mote twice) and correctly labelled."""
    rig = parsed(lever_rig(30, retry="continue"))
    rig_opened, sim = opened(rig)
    _, runner = run_survey(rig, tmp_path, opened=rig_opened)
    state = read_journal(tmp_path / "journal.jsonl")
    assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
    assert state.duplicates_ignored == 0
    check_labels(rig, sim.scene, state, max_error_deg=0.2)
    recs = view_records(tmp_path / "journal.jsonl")
    first = {(r["camera"], r["view"]): r for r in recs if r["attempt"] == 0}
    again = [r for r in recs if r["attempt"] > 0]
    assert again and all(r.get("continued") for r in again)
    book_length = runner_book_length(rig)
    for r in again:
        prev = first[(r["camera"], r["view"])]
        assert r["frames"] == book_length and r["head"] == prev["head"]  # no re-slew, L more frames
        # the recording continues: its first frame period follows the previous recording's last
        assert r["clock_s"] == pytest.approx(prev["clock_s"] + prev["frames"] * PERIOD, abs=1e-9)
    # the continued windows read motes the first recording of those views had missed
    assert sum(len(r["readings"]) for r in again) > 0
    # priced as a continuation: cheaper on the clock than the same survey retrying in bursts
    burst = parsed(lever_rig(30, retry="burst"))
    _, burst_runner = run_survey(burst, tmp_path / "burst", opened=opened(burst)[0])
    assert runner.field_time.phases["frames"] < burst_runner.field_time.phases["frames"]


def runner_book_length(rig) -> int:
    from fgloc.camera.blink_codes import code_book

    return code_book(len(rig.node_ids)).length


def test_continued_retry_resumes_without_duplicates(tmp_path):
    """A kill between a view's first recording and its continuation: the video is gone, so the
    resumed survey records that retry as a new burst (not continued); nothing is read twice,
    every view is recorded once, every visible pair is read, and what was journaled stays."""
    rig = parsed(lever_rig(12, width=160, retry="continue"))
    full = tmp_path / "full"
    run_survey(rig, full, opened=opened(rig)[0])
    data = (full / "journal.jsonl").read_bytes()
    lines = data.splitlines(keepends=True)
    recs = [json.loads(x) for x in lines]
    again = [k for k, r in enumerate(recs) if r["type"] == "view" and r["attempt"] > 0]
    assert again, "the scene should retry a view"
    n_views = sum(r["type"] == "view" for r in recs)
    for k, cut in enumerate([again[0], again[-1]]):
        d = tmp_path / f"cut{k}"
        d.mkdir()
        (d / "journal.jsonl").write_bytes(b"".join(lines[:cut]) + lines[cut][:9])  # torn continuation
        kept = read_journal(d / "journal.jsonl").observations
        rig_opened, sim = opened(rig)
        run_survey(rig, d, resume=True, opened=rig_opened)
        state = read_journal(d / "journal.jsonl")
        assert state.duplicates_ignored == 0
        assert all(state.observations[key] == o for key, o in kept.items())
        assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
        check_labels(rig, sim.scene, state, max_error_deg=0.4)
        resumed = view_records(d / "journal.jsonl")
        keys = [(r["camera"], r["view"], r["attempt"]) for r in resumed]
        assert len(keys) == len(set(keys))
        redo = next(r for r in resumed if (r["camera"], r["view"], r["attempt"]) ==
                    (recs[cut]["camera"], recs[cut]["view"], recs[cut]["attempt"]))
        assert not redo.get("continued") and redo["frames"] == recs[cut]["frames"] * 3 + 2
        assert len(resumed) >= n_views - 2  # later retries may differ; every planned view is there


@pytest.mark.parametrize(("coded", "problem"), [({"retry": "again"}, "coded.retry"), ({"separate": 3}, "coded.separate"),
                                                ("radio", "coded: expected an object")])
def test_bad_coded_settings_are_one_line_and_exit_2(tmp_path, capsys, coded, problem):
    data = coded_rig(4, width=160)
    data["coded"] = coded
    with pytest.raises(FglocError, match=problem):
        coded_settings(parsed(data))
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o"), "--simulate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and problem in err[0], err


def test_coded_settings_defaults_and_rig_values():
    s = coded_settings(parsed(coded_rig(4, width=160)))
    assert (s.retry, s.separate) == ("burst", "zoom")
    s = coded_settings(parsed(lever_rig(4, width=160, retry="continue", separate="radio")))
    assert (s.retry, s.separate) == ("continue", "radio")
    assert coded_settings(parsed(lever_rig(4, width=160, retry="continue")), retry="burst").retry == "burst"
    assert np.isfinite(PERIOD)
