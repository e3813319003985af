"""A sequential survey is priced on the survey clock: per node, per phase, and in total."""

from __future__ import annotations

import json

import pytest

from fgloc.cli import main
from fgloc.files.journal import read_journal
from fgloc.survey.clock import FieldTime, sum_times
from tests.test_head_rig import head_rig_data


def test_sequential_survey_reports_its_predicted_field_time(tmp_path, capsys) -> None:
    data = head_rig_data(n_nodes=12, sigma_deg=0.1)
    data["simulation"].pop("head_errors", None)
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["-q", "survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "s"), "--simulate",
                 "--no-live"]) == 0
    out = capsys.readouterr().out
    state = read_journal(tmp_path / "s" / "journal.jsonl")
    nodes = [r for r in state.field_times if r["scope"] == "node"]
    survey = [r for r in state.field_times if r["scope"] == "survey"]
    # one priced record per node done, and a survey total that is their sum, phase by phase
    assert sorted(r["node"] for r in nodes) == sorted(state.done) and len(survey) == 1
    total = sum_times(FieldTime(r["phases"]) for r in nodes)
    assert survey[0]["phases"] == pytest.approx(dict(total.phases))
    # every node moved a head and read it back: slews, settling and position reads are priced
    assert all(r["phases"]["slew"] > 0 and r["phases"]["settle"] > 0 and r["phases"]["position"] > 0 for r in nodes)
    assert f"predicted field time: total {total.total:.1f} s" in out


def test_a_resumed_survey_counts_the_nodes_of_earlier_runs(tmp_path, capsys) -> None:
    data = head_rig_data(n_nodes=12, sigma_deg=0.1)
    data["simulation"].pop("head_errors", None)
    (tmp_path / "rig.json").write_text(json.dumps(data))
    args = ["-q", "survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "s"), "--simulate", "--no-live"]
    assert main(args) == 0
    journal = tmp_path / "s" / "journal.jsonl"
    lines = journal.read_text().splitlines(keepends=True)
    priced = [k for k, line in enumerate(lines) if '"scope":"node"' in line.replace(" ", "")]
    journal.write_text("".join(lines[: priced[4] + 1]))  # killed after the fifth node was priced
    (tmp_path / "s" / "survey.json").unlink()
    capsys.readouterr()
    assert main(args + ["--resume"]) == 0
    state = read_journal(journal)
    nodes = [r for r in state.field_times if r["scope"] == "node"]
    assert len(nodes) == 12 and len({r["node"] for r in nodes}) == 12
    total = sum_times(FieldTime(r["phases"]) for r in nodes)
    assert [r for r in state.field_times if r["scope"] == "survey"][-1]["phases"] == pytest.approx(dict(total.phases))
    assert f"predicted field time: total {total.total:.1f} s" in capsys.readouterr().out
