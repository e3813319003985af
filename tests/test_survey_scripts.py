"""The example scripts run end to end: a live survey against the simulated twin, then its replay."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

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


def test_coded_survey_labels_judge_a_pair_decoded_blob_by_both_readings() -> None:
    """scripts/coded_survey.py's label check: one camera, motes a and b 0.06 deg apart in tilt
    and c far away. A pair read of a and b shifted together by 0.035 deg (noise common to the
    blob) puts a's reading nearer b: not mislabelled, the labels fit better as they are. The
    same readings with the labels swapped are both mislabelled; a lone reading nearer another
    mote is mislabelled; "far" is measured from the reading's own mote."""
    from types import SimpleNamespace

    from tests.conftest import load_script

    labels = load_script("coded_survey").labels
    d = math.radians(1.0)
    apparent = np.radians(np.array([[[10.0, -5.0], [10.0, -5.06], [20.0, -5.0]]]))
    rig = SimpleNamespace(camera_ids=["cam0"], node_ids=["a", "b", "c"])
    scene = SimpleNamespace(visible=np.ones((1, 3), bool), dead=set(), apparent=apparent)

    def state(readings: list[tuple[str, float, float, str | None]]):  # noqa: ANN202 - (node, pan, tilt deg, partner)
        code = {"a": 0, "b": 1, "c": 2}
        obs = {(n, "cam0", k): SimpleNamespace(camera="cam0", view="r1-000", node=n, pan=p * d, tilt=t * d)
               for k, (n, p, t, _) in enumerate(readings)}
        rec = {"readings": [{"node": n, "code": code[n]} | ({"partner": code[m]} if m else {})
                            for n, _, _, m in readings]}
        return SimpleNamespace(observations=obs, views={("cam0", "r1-000", 0): rec})

    shifted = [("a", 10.0, -5.035, "b"), ("b", 10.0, -5.095, "a")]
    assert labels(rig, scene, state(shifted)) == (2, 0, 0)
    swapped = [("b", 10.0, -5.0, "a"), ("a", 10.0, -5.06, "b")]
    assert labels(rig, scene, state(swapped)) == (2, 2, 2)
    assert labels(rig, scene, state([("a", 10.0, -5.035, None)])) == (1, 1, 0)
    assert labels(rig, scene, state([("c", 20.0, -5.06, None)])) == (1, 0, 1)
