"""The survey journal: lossless conversion, torn tails, idempotent replay, clear errors."""

from __future__ import annotations

import json
import os
from dataclasses import replace

import numpy as np
import pytest

from fgloc.core.model import Gauge, NodeMode, Observation
from fgloc.files.journal import (
    JournalError,
    JournalHeader,
    JournalObservation,
    JournalWriter,
    journal_to_survey,
    read_journal,
    survey_to_journal,
)
from fgloc.files.survey_result import read_survey, survey_to_json, write_survey
from fgloc.sim.scenes import PaperScenario, paper_scenario


def _survey_with_overrides():
    survey = paper_scenario(PaperScenario(n_nodes=12, seed=3))
    obs = list(survey.observations)
    # A per-observation sigma, a dropped reading (occlusion) and awkward floats must all survive.
    obs[3] = replace(obs[3], sigma=0.0035)
    obs[5] = replace(obs[5], pan=float(np.nextafter(np.pi, 0)), tilt=-1.0e-17)
    del obs[8]
    return replace(survey, observations=obs)


def test_journal_round_trip_is_lossless(tmp_path):
    """survey -> journal -> survey.json -> survey gives back every field bit for bit."""
    survey = _survey_with_overrides()
    survey_to_journal(survey, tmp_path / "j.jsonl", rig_hash_value="abc")
    state = read_journal(tmp_path / "j.jsonl")
    assert state.header.rig_hash == "abc"
    back = journal_to_survey(state)
    write_survey(back, tmp_path / "survey.json")
    again = read_survey(tmp_path / "survey.json")
    assert survey_to_json(again) == survey_to_json(survey)
    assert again.observations == survey.observations  # exact floats, sigma overrides, order
    assert state.done == set(survey.node_ids)


def test_repeated_readings_keep_their_index(tmp_path):
    survey = paper_scenario(PaperScenario(n_nodes=5, repeats=3, seed=1))
    survey_to_journal(survey, tmp_path / "j.jsonl")
    back = journal_to_survey(read_journal(tmp_path / "j.jsonl"))
    assert sorted(back.observations, key=repr) == sorted(survey.observations, key=repr)
    assert len(back.observations) == 3 * 2 * 5


def _header() -> JournalHeader:
    return JournalHeader(NodeMode.PLANAR, Gauge("a", "b"), 0.001, ["a", "b"], ["n1", "n2"], "h")


def test_torn_last_line_is_ignored_and_cut_before_appending(tmp_path):
    path = tmp_path / "j.jsonl"
    with JournalWriter.create(path, _header()) as w:
        w.node_started("n1")
        w.observation(JournalObservation("n1", "a", 0, 0.5, -0.25))
    full = path.read_bytes()
    # Simulate a kill in the middle of writing the next record.
    with open(path, "ab") as f:
        f.write(b'{"t":1.0,"type":"observation","node":"n1","camera":"b","index":0,"pan":0.1')
    state = read_journal(path)
    assert state.torn_tail_bytes > 0
    assert list(state.observations) == [("n1", "a", 0)]
    writer, state2 = JournalWriter.open_existing(path)
    with writer:
        writer.observation(JournalObservation("n1", "b", 0, 0.75, -0.5))
    assert path.read_bytes().startswith(full)
    final = read_journal(path)
    assert final.torn_tail_bytes == 0
    assert final.observations[("n1", "b", 0)].pan == 0.75
    assert len(final.observations) == 2


def test_replay_is_idempotent(tmp_path):
    """Records repeated by a resumed run (same key) do not duplicate observations."""
    path = tmp_path / "j.jsonl"
    with JournalWriter.create(path, _header()) as w:
        for _ in range(2):
            w.node_started("n1")
            w.observation(JournalObservation("n1", "a", 0, 0.5, -0.25))
            w.not_found("n1", "b", "occluded")
            w.node_done("n1")
    state = read_journal(path)
    assert len(state.observations) == 1 and state.duplicates_ignored == 1
    assert state.started == ["n1"] and state.done == {"n1"}
    assert journal_to_survey(state).observations == [Observation("a", "n1", 0.5, -0.25)]


def test_every_prefix_of_a_journal_reads(tmp_path):
    """A kill at any byte leaves a journal that reads: the complete records, never a crash."""
    path = tmp_path / "j.jsonl"
    survey_to_journal(paper_scenario(PaperScenario(n_nodes=3, seed=2)), path)
    data = path.read_bytes()
    cut = tmp_path / "cut.jsonl"
    header_end = data.index(b"\n") + 1
    for n in range(header_end, len(data) + 1, 7):
        cut.write_bytes(data[:n])
        state = read_journal(cut)
        complete = data[:n].count(b"\n")
        assert state.records == complete


@pytest.mark.parametrize(
    "lines, message",
    [
        ([], "no complete header"),
        (['{"type":"node_started","node":"n1"}'], "line 1: first record must be the header"),
        (["HEADER", "not json"], "line 2: not valid JSON"),
        (["HEADER", '{"type":"observation","node":"zz","camera":"a","index":0,"pan":0,"tilt":0}'],
         'line 2: observation.node: unknown node "zz"'),
        (["HEADER", '{"type":"observation","node":"n1","camera":"a","index":0,"pan":"x","tilt":0}'],
         "line 2: observation.pan: expected a finite number"),
        (["HEADER", '{"type":"observation","node":"n1","camera":"a","index":-1,"pan":0,"tilt":0}'],
         "line 2: observation.index"),
        (["HEADER", '{"type":"rig_changed","rig_hash":"x","changed":"port","rig_operational":{}}'],
         "line 2: rig_changed.changed: expected an array"),
        (["HEADER", '{"type":"rig_changed","rig_hash":"x","changed":[]}'],
         "line 2: rig_changed.rig_operational: missing required field"),
    ],
)
def test_bad_journals_fail_with_one_line(tmp_path, lines, message):
    header = json.dumps(_header().to_record())
    path = tmp_path / "j.jsonl"
    path.write_text("".join((header if line == "HEADER" else line) + "\n" for line in lines))
    with pytest.raises(JournalError) as err:
        read_journal(path)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert str(path) in str(err.value)


def test_create_refuses_to_overwrite_a_journal(tmp_path):
    path = tmp_path / "j.jsonl"
    JournalWriter.create(path, _header()).close()
    with pytest.raises(JournalError, match="already exists"):
        JournalWriter.create(path, _header())
    # ...but a header torn by a kill during creation is started over.
    path.write_bytes(b'{"type":"header","form')
    JournalWriter.create(path, _header()).close()
    assert read_journal(path).records == 1


def test_records_are_fsynced(tmp_path, monkeypatch):
    calls = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (calls.append(fd), real(fd))[1])
    with JournalWriter.create(tmp_path / "j.jsonl", _header()) as w:
        before = len(calls)
        w.observation(JournalObservation("n1", "a", 0, 0.1, 0.2))
        assert len(calls) == before + 1


def test_rig_records_replay_and_older_readers_ignore_them(tmp_path):
    """The header's rig_meaning / rig_operational and rig_changed records (docs/file-format.md)
    read back as written; survey_stopped is informational; the survey they record is unchanged."""
    path = tmp_path / "j.jsonl"
    header = replace(_header(), rig_hash="h0", rig_meaning={"sigma_deg": 0.1, "cameras": ["a", "b"]},
                     rig_operational={"cameras[a].port": "http://***@h", "retry.backoff_s": 0.05})
    with JournalWriter.create(path, header) as w:
        w.observation(JournalObservation("n1", "a", 0, 0.1, -0.2))
        w.rig_changed("h1", ["retry.backoff_s"], {"cameras[a].port": "http://***@h", "retry.backoff_s": 0.2})
        w.append({"type": "survey_stopped", "camera": "b", "misses": 25, "reason": "camera error: x"})
        w.observation(JournalObservation("n1", "b", 0, 0.3, -0.4))
    state = read_journal(path)
    assert state.header.rig_meaning == header.rig_meaning and state.header.rig_operational == header.rig_operational
    assert state.rig_hash == "h1" and state.rig_operational == {"cameras[a].port": "http://***@h",
                                                                "retry.backoff_s": 0.2}
    assert [c["changed"] for c in state.rig_changes] == [["retry.backoff_s"]]
    assert len(journal_to_survey(state).observations) == 2
    # a journal without them (as older fgloc versions wrote) reads with the header's hash
    plain = tmp_path / "plain.jsonl"
    JournalWriter.create(plain, replace(_header(), rig_hash="h0")).close()
    old = read_journal(plain)
    assert old.rig_hash == "h0" and old.rig_operational is None and old.header.rig_meaning is None
    assert "rig_meaning" not in plain.read_text()
