"""The example scripts run end to end: a live survey against the simulated twin, then its replay."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from fgloc.files.survey_result import read_result, read_survey
from tests.test_survey_acceptance import write_rig

ROOT = Path(__file__).resolve().parent.parent


def _run(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)


def test_live_survey_then_replay(tmp_path):
    rig = write_rig(tmp_path / "rig.json", 15, occlusion=0.05)
    out = tmp_path / "survey"
    # --batch: the replay re-solves in batch, so the live run does too and both must agree exactly.
    live = _run("scripts/live_survey.py", "--rig", str(rig), "-o", str(out), "--simulate", "--every", "5", "--batch")
    assert live.returncode == 0, live.stderr
    assert "estimate after 10 nodes" in live.stdout and "estimate after 15 nodes" in live.stdout
    assert "15/15 nodes" in live.stderr
    survey = read_survey(out / "survey.json")
    assert len(survey.observations) >= 25 and survey.truth is not None

    # Replay a copy with a torn last line, as a crash would leave it.
    journal = (out / "journal.jsonl").read_bytes()
    (tmp_path / "torn.jsonl").write_bytes(journal + b'{"t":1,"type":"observ')
    result_path = tmp_path / "replayed.json"
    replay = _run("scripts/replay_survey.py", str(tmp_path / "torn.jsonl"), "--every", "5", "-o", str(result_path))
    assert replay.returncode == 0, replay.stderr
    assert "estimate after 15 nodes" in replay.stdout
    replayed = read_result(result_path)
    live_final = read_result(out / "estimate.json")
    for nid, est in live_final.nodes.items():
        assert abs(replayed.nodes[nid].position - est.position).max() < 1e-9


def test_replay_reports_a_bad_journal_in_one_line(tmp_path):
    (tmp_path / "j.jsonl").write_text(json.dumps({"type": "node_started"}) + "\n")
    replay = _run("scripts/replay_survey.py", str(tmp_path / "j.jsonl"))
    assert replay.returncode == 2
    assert replay.stderr.count("\n") == 1 and "first record must be the header" in replay.stderr


def test_live_survey_rerun_hook(tmp_path):
    """--rerun records the live estimates with fgloc.viz (when that module is in the build),
    otherwise it refuses in one line before touching the rig."""
    import importlib.util

    rig = write_rig(tmp_path / "rig.json", 8)
    out = tmp_path / "survey"
    run = _run("scripts/live_survey.py", "--rig", str(rig), "-o", str(out), "--simulate", "--every", "2",
               "--rerun", str(tmp_path / "live.rrd"))
    if importlib.util.find_spec("fgloc.viz") is None:
        assert run.returncode == 2 and "needs fgloc.viz" in run.stderr and not out.exists()
    else:
        assert run.returncode == 0, run.stderr
        assert (tmp_path / "live.rrd").stat().st_size > 10_000
