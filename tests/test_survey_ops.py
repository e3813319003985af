"""Survey operations (issue 15, items 6-7): one writer per directory, debris of killed writes,
the consecutive-miss rule, and resuming after a rig.json edit."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.files.journal import read_journal, survey_to_journal
from fgloc.files.json_io import write_json_atomic
from fgloc.files.rig_config import parse_rig
from fgloc.survey.lock import SurveyLock, SurveyLocked
from fgloc.survey.resume import UNSEEN_CHANGE
from fgloc.survey.runner import SurveyStopped
from fgloc.survey.session import journal_survey, run_survey
from tests.test_rig_config import EXAMPLE
from tests.test_survey_acceptance import CLI, ROOT, write_rig
from tests.test_survey_runner import opened, small_rig

ENV = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")


def _lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def _wait_for_lines(path: Path, n: int, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while _lines(path) < n and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, "the survey ended before the test could act on it"
    assert _lines(path) >= n


def _survey(rig: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(CLI + ["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--no-live",
                                   "--quiet", *extra], cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


# -- one writer per survey directory ---------------------------------------------------------------

def test_a_held_lock_refuses_a_second_survey_naming_the_holder(tmp_path):
    rig = small_rig(4)
    with SurveyLock(tmp_path):
        with pytest.raises(SurveyLocked) as err:
            run_survey(rig, tmp_path, opened=opened(rig)[0])
    message = str(err.value)
    assert f"pid {os.getpid()} on {socket.gethostname()}" in message and "\n" not in message
    assert not (tmp_path / "journal.jsonl").exists()  # refused before the journal was touched
    run_survey(rig, tmp_path, opened=opened(rig)[0])  # released: the next survey runs
    assert read_journal(tmp_path / "journal.jsonl").done == set(rig.node_ids)
    with SurveyLock(tmp_path):  # and releases the lock when it ends
        pass


def test_a_second_cli_survey_is_refused_and_a_killed_one_resumes(tmp_path):
    """The issue's case: two `fgloc survey` on one directory. The second (with or without
    --resume) exits 2 with one line naming the first by pid and host. The first is then
    SIGKILLed: its lock goes with it, and a resume (with a faster twin: an operational
    rig.json change) completes exactly the readings of an uninterrupted run, none repeated."""
    slow = write_rig(tmp_path / "slow.json", 12, occlusion=0.1, time_scale=3.0)  # ~1 s per node
    fast = write_rig(tmp_path / "fast.json", 12, occlusion=0.1)
    reference = tmp_path / "reference"
    assert main(["survey", "--rig", str(fast), "-o", str(reference), "--simulate", "--no-live", "--quiet"]) == 0
    out = tmp_path / "out"
    first = _survey(slow, out)
    _wait_for_lines(out / "journal.jsonl", 3, first)
    seconds = [_survey(slow, out, *extra) for extra in ((), ("--resume",))]
    for second in seconds:
        out_text, err = second.communicate(timeout=60)
        assert first.poll() is None, "the first survey ended too soon for this test"
        assert second.returncode == 2, (out_text, err)
        assert err.count("\n") == 1 and "a survey is already running in this directory" in err
        assert f"pid {first.pid} on {socket.gethostname()}" in err
    first.send_signal(signal.SIGKILL)
    first.communicate()
    assert (out / "survey.lock").exists()  # the file stays; its lock went with the process
    resumed = _survey(fast, out, "--resume")
    _, err = resumed.communicate(timeout=120)
    assert resumed.returncode == 0, err
    state = read_journal(out / "journal.jsonl")
    records = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()]
    assert state.duplicates_ignored == 0 and state.done == set(state.header.node_ids)
    assert sum(r["type"] == "observation" for r in records) == len(state.observations)
    assert sum(r["type"] == "node_done" for r in records) == 12
    assert [c["changed"] for c in state.rig_changes] == [["simulation.time_scale"]]
    assert journal_survey(out).observations == journal_survey(reference).observations


# -- temporary files of killed atomic writes -------------------------------------------------------

def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _killed_mid_write(target: Path) -> Path:
    """SIGKILL a process inside write_json_atomic (after the data, before the rename); its temp file."""
    code = ("import os, sys, time; import fgloc.files.json_io as j; j.os.fsync = lambda fd: time.sleep(60); "
            "j.write_json_atomic({'x': list(range(1000))}, sys.argv[1])")
    proc = subprocess.Popen([sys.executable, "-c", code, str(target)], cwd=ROOT, env=ENV)
    deadline = time.monotonic() + 30
    while not list(target.parent.glob(f".{target.name}.*.tmp")) and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    (tmp,) = target.parent.glob(f".{target.name}.*.tmp")
    return tmp


def test_a_killed_atomic_write_leaves_a_temp_file_that_the_next_write_removes(tmp_path):
    target = tmp_path / "result.json"
    write_json_atomic({"old": True}, target)
    tmp = _killed_mid_write(target)
    assert json.loads(target.read_text()) == {"old": True}  # the file itself is the old one
    live = tmp_path / f".result.json.{os.getpid()}.abcd.tmp"  # a writer that is still running
    live.write_text("{")
    other = tmp_path / f".other.json.{_dead_pid()}.abcd.tmp"  # another file's debris stays
    other.write_text("{")
    write_json_atomic({"new": True}, target)
    assert not tmp.exists() and live.exists() and other.exists()
    assert json.loads(target.read_text()) == {"new": True}


def test_the_next_survey_run_removes_debris_of_killed_writes(tmp_path):
    rig = small_rig(4)
    debris = [_killed_mid_write(tmp_path / "survey.json"),
              tmp_path / f".estimate.json.{_dead_pid()}.k3j_x.tmp"]
    debris[1].write_text("{")
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    assert not any(p.exists() for p in debris)
    assert not list(tmp_path.glob(".*.tmp"))


# -- a camera that finds nothing for many nodes in a row --------------------------------------------

def _dead_cam1(rig):
    rig_opened, sim = opened(rig)

    def open_head(cid):
        if cid == "cam1":
            raise ConnectionError("no such port")
        return sim.open_head(cid)

    return replace(rig_opened, open_head=open_head)


def test_a_camera_missing_max_consecutive_misses_nodes_stops_the_survey_resumably(tmp_path):
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(10)]
    data["simulation"] = {"seed": 1, "heights": [0.1, 0.12]}
    data["retry"] = {"backoff_s": 0.0, "max_consecutive_misses": 3}
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    with pytest.raises(SurveyStopped) as err:
        run_survey(rig, tmp_path, opened=_dead_cam1(rig))
    message = str(err.value)
    assert "\n" not in message and "retry.max_consecutive_misses: camera cam1 found nothing for 3 nodes" in message
    assert "survey stopped after node n002" in message and "--resume" in message
    state = read_journal(tmp_path / "journal.jsonl")
    assert state.done == {"n000", "n001", "n002"}  # stopped right after the third miss
    assert all(c == "cam0" for (_, c, _) in state.observations) and len(state.observations) == 3
    records = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    assert [r for r in records if r["type"] == "survey_stopped"][0]["misses"] == 3
    assert journal_survey(tmp_path).observations == run_survey_json(tmp_path)  # survey.json written too
    # fixed camera: the resume completes the rest with both cameras
    _, runner = run_survey(rig, tmp_path, resume=True, opened=opened(rig)[0])
    state = read_journal(tmp_path / "journal.jsonl")
    assert state.done == set(rig.node_ids) and runner.stats.nodes_skipped == 3
    assert {n for (n, c, _) in state.observations if c == "cam1"} == {f"n{j:03d}" for j in range(3, 10)}


def run_survey_json(out):
    from fgloc.files.survey_result import read_survey

    return read_survey(out / "survey.json").observations


def test_misses_must_be_consecutive_and_zero_turns_the_rule_off(tmp_path):
    rig = small_rig(10, occlusion=0.0, dead_nodes=[])
    assert rig.retry.max_consecutive_misses == 25  # the documented default
    run_survey(replace(rig, retry=replace(rig.retry, max_consecutive_misses=0)), tmp_path / "off",
               opened=_dead_cam1(rig))
    assert read_journal(tmp_path / "off" / "journal.jsonl").done == set(rig.node_ids)
    # a camera that misses every other node never reaches 2 misses in a row
    rig2 = replace(rig, retry=replace(rig.retry, max_consecutive_misses=2, head_attempts=1, reconnects=0))
    rig_opened, sim = opened(rig2)
    lit: dict[str, str] = {}

    class Leds:  # remembers the lit node
        def set_led(self, node, on):
            if on:
                lit["node"] = node
            return sim.leds.set_led(node, on)

    def open_head(cid):
        head = sim.open_head(cid)
        if cid == "cam1":
            grab = head.grab_frame

            def flaky():
                if int(lit["node"][1:]) % 2:
                    raise ConnectionError("flaky")
                return grab()

            head.grab_frame = flaky
        return head

    _, runner = run_survey(rig2, tmp_path / "flaky", opened=replace(rig_opened, open_head=open_head, leds=Leds()))
    state = read_journal(tmp_path / "flaky" / "journal.jsonl")
    assert state.done == set(rig.node_ids)
    assert {n for (n, c) in state.not_found if c == "cam1"} == {f"n{j:03d}" for j in range(1, 10, 2)}


def test_cli_reports_a_stopped_survey_in_one_line(tmp_path, capsys, monkeypatch):
    from fgloc.drivers.inprocess_rig import InProcessRig

    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(6)]
    data["simulation"] = {"seed": 1, "heights": [0.1, 0.12]}
    data["retry"] = {"backoff_s": 0.0, "max_consecutive_misses": 2, "reconnects": 0}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    real_open = InProcessRig.open_head

    def open_head(self, cid):
        if cid == "cam0":
            raise ConnectionError("link down")
        return real_open(self, cid)

    monkeypatch.setattr(InProcessRig, "open_head", open_head)
    out = tmp_path / "out"
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(out), "--simulate", "--quiet"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if line.startswith("fgloc: error:")] == [err[-1]]
    assert "retry.max_consecutive_misses: camera cam0 found nothing for 2 nodes in a row" in err[-1]
    assert (out / "survey.json").exists()


# -- resuming after a rig.json edit ----------------------------------------------------------------

def _rig_data(n_nodes: int = 8) -> dict:
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": 3, "heights": [0.1, 0.12], "occlusion": 0.1}
    data["retry"] = {"backoff_s": 0.0}
    data["cameras"][0]["port"] = "http://admin:oldsecret@10.0.0.5"
    return data


def _half_journal(tmp_path: Path, data: dict) -> tuple[Path, list]:
    """A complete reference survey and a copy of its journal cut at half its records (a kill)."""
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    ref, out = tmp_path / "ref", tmp_path / "out"
    survey, _ = run_survey(rig, ref, opened=opened(rig)[0])
    lines = (ref / "journal.jsonl").read_text().splitlines(keepends=True)
    out.mkdir()
    (out / "journal.jsonl").write_text("".join(lines[:len(lines) // 2]))
    return out, survey.observations


def test_resume_accepts_operational_changes_and_journals_them_without_credentials(tmp_path):
    data = _rig_data()
    out, reference = _half_journal(tmp_path, data)
    data["cameras"][0]["port"] = "http://admin:newsecret@10.0.0.6"  # new address and password
    data["cameras"][1]["address"] = 2
    data["retry"] |= {"backoff_s": 0.2, "head_attempts": 6}
    data["search"]["settle_s"] = 0.0
    data["simulation"]["drop_rate"] = 0.0
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    survey, _ = run_survey(rig, out, resume=True, opened=opened(rig)[0])
    assert survey.observations == reference  # the readings mean the same: the survey completes
    state = read_journal(out / "journal.jsonl")
    assert len(state.rig_changes) == 1 and state.rig_hash == rig.hash
    change = state.rig_changes[0]
    assert sorted(change["changed"]) == ["cameras[cam0].port", "cameras[cam1].address", "retry.backoff_s",
                                         "retry.head_attempts", "search.settle_s", "simulation.drop_rate"]
    assert change["rig_operational"]["cameras[cam0].port"] == "http://***@10.0.0.6"
    text = (out / "journal.jsonl").read_text()
    assert "oldsecret" not in text and "newsecret" not in text

    # a password rotation alone: accepted, journaled without naming a value
    data["cameras"][0]["port"] = "http://admin:third@10.0.0.6"
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    run_survey(rig, out, resume=True, opened=opened(rig)[0])
    state = read_journal(out / "journal.jsonl")
    assert [c["changed"] for c in state.rig_changes][-1] == [UNSEEN_CHANGE] and "third" not in \
        (out / "journal.jsonl").read_text()
    # the same rig again: nothing new journaled
    run_survey(rig, out, resume=True, opened=opened(rig)[0])
    assert len(read_journal(out / "journal.jsonl").rig_changes) == 2


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d["cameras"][1].update(mounting="ceiling"), "cameras[cam1].mounting"),
    (lambda d: d["cameras"][0].update(model="EVI-D70"), "cameras[cam0].model"),
    (lambda d: d["cameras"][0]["intrinsics"].update(fx=450.0), "cameras[cam0].intrinsics.fx"),
    (lambda d: d["cameras"][1].update(zoom=0.5), "cameras[cam1].zoom"),
    (lambda d: d.update(sigma_deg=0.2), "sigma_deg"),
    (lambda d: d.update(gauge={"origin": "cam1", "baseline": "cam0"}), "gauge.origin"),
    (lambda d: d.update(nodes="3d"), "nodes"),
    (lambda d: d.update(repeats=2), "repeats"),
    (lambda d: d["motes"].update(addresses={"n000": 9}), "motes.addresses"),
    (lambda d: d["search"].update(method="centre"), "search.method"),
    (lambda d: d["simulation"].update(occlusion=0.3), "simulation.occlusion"),
])
def test_resume_refuses_changes_of_meaning_naming_the_field(tmp_path, capsys, edit, field):
    data = _rig_data()
    out, _ = _half_journal(tmp_path, data)
    before = (out / "journal.jsonl").read_bytes()
    edit(data)
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(out), "--simulate", "--resume",
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f": {field}: changes what the readings recorded in" in err
    assert "oldsecret" not in err
    assert (out / "journal.jsonl").read_bytes() == before  # refused before anything was written


def test_a_journal_from_before_the_split_accepts_only_the_identical_rig(tmp_path):
    data = _rig_data(4)
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    survey, _ = run_survey(rig, tmp_path / "ref", opened=opened(rig)[0])
    survey_to_journal(survey, tmp_path / "old" / "journal.jsonl", rig.hash)  # header without rig_meaning
    run_survey(rig, tmp_path / "old", resume=True, opened=opened(rig)[0])
    data["retry"]["backoff_s"] = 0.1
    other = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    with pytest.raises(FglocError, match="header.rig_hash: journal was recorded with a different"):
        run_survey(other, tmp_path / "old", resume=True, opened=opened(other)[0])


def test_resume_refuses_switching_between_simulated_and_hardware(tmp_path):
    data = _rig_data(4)
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    with pytest.raises(FglocError, match="--simulate: .* was recorded with --simulate"):
        run_survey(rig, tmp_path, resume=True)  # without --simulate: the hardware path
