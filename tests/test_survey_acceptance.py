"""Issue 7 acceptance: a survey survives SIGKILL at random moments; a faulty rig matches a clean one.

(a) runs the real CLI against the in-process simulated rig (drivers/inprocess_rig.py); (b) runs
the session against VISCA pty twins driven by the real serial driver (drivers/twin_rig.py).
Both scenes fix each (camera, node) measurement error by the seed, so the same rig gives the
same readings, which makes "exactly the observations of an uninterrupted run" checkable with ==.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fgloc.drivers.inprocess_rig import InProcessRig
from fgloc.files.journal import read_journal
from fgloc.files.rig_config import load_rig
from fgloc.files.survey_result import read_survey
from fgloc.survey.session import OpenedRig, run_survey
from tests.test_rig_config import EXAMPLE

ROOT = Path(__file__).resolve().parent.parent
CLI = [sys.executable, "-c", "import sys; from fgloc.cli import main; sys.exit(main(sys.argv[1:]))"]


def write_rig(path: Path, n_nodes: int, **simulation) -> Path:
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": 4, "heights": [0.1, 0.12]} | simulation
    data["retry"] = {"backoff_s": 0.0}
    path.write_text(json.dumps(data))
    return path


def observations(journal: Path) -> dict:
    return {k: (o.pan, o.tilt) for k, o in read_journal(journal).observations.items()}


def _complete_lines(path: Path) -> int:
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


# Time-compressed byte twins on a shared 2-core machine: a rare scheduling stall can outlast the
# shortened driver timeouts (seen about once in 30 full-suite runs, never when re-run). The
# assertions stay exact; a failure is re-run up to twice before it counts.
TWIN_TIMING = pytest.mark.flaky(reruns=2, reruns_delay=1)


def _kill_and_resume(tmp_path: Path, rig_path: Path, reference_journal: Path, n_kills: int, seed: int) -> list[int]:
    """Start the CLI survey, SIGKILL it when the journal reaches a random target length (+0-30 ms),
    resume, n_kills times; then finish it. Returns the journal lengths seen after each kill."""
    reference = observations(reference_journal)
    total_records = _complete_lines(reference_journal)
    out = tmp_path / "killed"
    journal = out / "journal.jsonl"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    rng = np.random.default_rng(seed)
    # Targets stop 4 records short of the end, so that on a loaded machine the random extra
    # delay cannot let the survey finish before the kill lands.
    targets = np.sort(rng.integers(0, max(total_records - 4, 1), size=n_kills))
    kills, seen_lengths = 0, []
    for attempt, target in enumerate(targets):
        args = CLI + ["survey", "--rig", str(rig_path), "-o", str(out), "--simulate", "--no-live", "--quiet"]
        if attempt > 0:
            args.append("--resume")
        proc = subprocess.Popen(args, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while _complete_lines(journal) < target and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.003)
        time.sleep(rng.uniform(0.0, 0.03) if target < total_records - 8 else 0.0)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills += 1
        proc.wait()
        if journal.exists() and journal.stat().st_size:
            try:
                seen_lengths.append(read_journal(journal).records)  # never crashes, whatever the kill hit
            except Exception as exc:  # noqa: BLE001 - only a journal torn inside its header is unreadable
                assert "no complete header" in str(exc)
    print(f"\n{kills} kills; journal records after each kill: {seen_lengths} of {total_records}")
    assert kills == n_kills, f"only {kills} of {n_kills} processes were still running when killed"
    assert len(set(seen_lengths)) >= n_kills // 2 and max(seen_lengths) < total_records  # spread over the survey
    final = subprocess.run(CLI + ["survey", "--rig", str(rig_path), "-o", str(out), "--simulate", "--resume",
                                  "--no-live", "--quiet"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert final.returncode == 0, final.stderr
    state = read_journal(journal)
    assert state.duplicates_ignored == 0 and state.done == set(read_journal(reference_journal).header.node_ids)
    assert observations(journal) == reference
    assert read_survey(out / "survey.json").observations == read_survey(reference_journal.parent / "survey.json").observations
    return seen_lengths


@pytest.mark.slow
@TWIN_TIMING
def test_sigkill_at_20_random_moments_loses_and_duplicates_nothing(tmp_path):
    """Acceptance (a). 20 kill moments are drawn at random over the survey's progress: a
    target journal length uniform over the uninterrupted journal's records (sorted, so the
    survey advances), plus a random 0-30 ms. Each (re)started CLI process is SIGKILLed once the
    journal reaches its target (at once during start-up when it already has), which lands
    kills during start-up, between records and between an observation and its node_done.
    The twin is time-compressed (time_scale 0.2: ~0.06 s of head motion per node). The
    reference is the same rig run uninterrupted (without time compression: the scene does
    not depend on it)."""
    rig_path = write_rig(tmp_path / "rig.json", 40, occlusion=0.1, dead_nodes=["n005"], time_scale=0.2)
    fast = load_rig(write_rig(tmp_path / "fast.json", 40, occlusion=0.1, dead_nodes=["n005"]))
    sim = InProcessRig(fast)
    run_survey(fast, tmp_path / "reference", opened=OpenedRig(sim.open_head, sim.leds, sim))
    _kill_and_resume(tmp_path, rig_path, tmp_path / "reference" / "journal.jsonl", 20, seed=20)


@pytest.mark.slow
@TWIN_TIMING
def test_sigkill_over_the_visca_twins_loses_and_duplicates_nothing(tmp_path):
    """Acceptance (a) again with real bytes: the CLI process hosts VISCA pty twins and a
    base-station twin and drives them through the serial drivers; 8 random kills. The readings
    still come out bit for bit those of an uninterrupted run (the head state, counts and
    frames are a deterministic function of the commands sent)."""
    rig_path = visca_rig(tmp_path / "rig.json", 20, occlusion=0.1, dead_nodes=["n005"])
    ref = subprocess.run(CLI + ["survey", "--rig", str(rig_path), "-o", str(tmp_path / "reference"), "--simulate",
                                "--no-live", "--quiet"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                         capture_output=True, text=True)
    assert ref.returncode == 0, ref.stderr
    _kill_and_resume(tmp_path, rig_path, tmp_path / "reference" / "journal.jsonl", 8, seed=8)


def visca_rig(path: Path, n_nodes: int, **simulation) -> Path:
    """A rig of two ceiling-mounted EVI-D70s (pan +-170 deg, tilt -90..+30 deg in the spec's
    convention) simulated by VISCA pty twins, over the paper-like planar scene."""
    data = json.loads(EXAMPLE.read_text())
    for cam in data["cameras"]:
        cam["model"], cam["mounting"] = "EVI-D70", "ceiling"
    data["search"] = {"pan_min_deg": -170, "pan_max_deg": 170, "tilt_min_deg": -88, "tilt_max_deg": 25}
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": 4, "heights": [0.1, 0.12], "twin": "visca"} | simulation
    data["retry"] = {"backoff_s": 0.05}
    path.write_text(json.dumps(data))
    return path


@pytest.mark.slow
@TWIN_TIMING
def test_faulty_100_node_survey_matches_the_fault_free_one(tmp_path):
    """Acceptance (b), over real bytes: each camera is the VISCA serial driver (drivers/visca/)
    talking to a pty twin (drivers/twins/visca_camera.py) that drops 5% of its replies, garbles
    1% (one random byte), and for cam1 disconnects once after 500 requests (the port returns
    0.2 s later). The LEDs go through the real TinyOS serial driver (drivers/tinyos/) to
    a base-station pty twin with the same drop and garble rates; node n042 never answers.
    The twins are time-compressed (heads 100x faster, driver timeouts shortened).

    Checks: every visible (camera, node) pair is observed exactly once, and the solve on the
    faulty run's survey.json matches the fault-free run's within noise: each node moves by
    less than 0.05 of its own marginal 1-sigma (in fact the readings come out identical: faults
    only cost retries), and the faulty solve is consistent with the truth (ANEES < 4 for 2-dof
    positions; this scene gives 3.65 with ideal readings too, the solver's own spread over
    scenes being ~1.2-3.7)."""
    from fgloc.drivers.twin_rig import ViscaTwinRig
    from fgloc.solve.joint import solve_survey

    common = {"occlusion": 0.05, "dead_nodes": ["n042"]}
    clean_rig = load_rig(visca_rig(tmp_path / "clean.json", 100, **common))
    faulty_rig = load_rig(visca_rig(tmp_path / "faulty.json", 100, **common, drop_rate=0.05, garble_rate=0.01,
                                    disconnect_after=500, disconnect_camera="cam1"))
    surveys, twins_faults, visible, apparent = {}, {}, None, None
    for name, rig in (("clean", clean_rig), ("faulty", faulty_rig)):
        with ViscaTwinRig(rig) as twins:
            run_survey(rig, tmp_path / name, opened=OpenedRig(twins.open_head, twins.leds, twins))
            twins_faults[name] = twins.injected()
            visible, apparent = twins.scene.visible_pairs(), twins.scene.apparent
        surveys[name] = read_survey(tmp_path / name / "survey.json")
    injected = twins_faults["faulty"]
    assert injected.get("disconnect") == 1 and injected.get("drop", 0) > 50 and injected.get("garble", 0) > 5
    assert not twins_faults["clean"]
    faulty = surveys["faulty"]
    seen = [(o.camera, o.node) for o in faulty.observations]
    state = read_journal(tmp_path / "faulty" / "journal.jsonl")
    assert set(seen) == visible and len(seen) == len(visible), (
        f"missing {sorted(visible - set(seen))}; not_found records: {dict(state.not_found)}")
    # Each reading is the scene's bearing (truth + the pair's N(0, sigma) error) to within the
    # measurement chain's own error (8-bit spot centroid, head counts): < 2% of sigma.
    for o in faulty.observations:
        want = apparent[faulty_rig.camera_ids.index(o.camera), faulty_rig.node_ids.index(o.node)]
        assert abs(np.remainder(o.pan - want[0] + np.pi, 2 * np.pi) - np.pi) < 0.02 * faulty_rig.sigma
        assert abs(o.tilt - want[1]) < 0.02 * faulty_rig.sigma

    clean_result = solve_survey(surveys["clean"])
    faulty_result = solve_survey(faulty)
    assert set(clean_result.nodes) == set(faulty_result.nodes)
    worst = 0.0
    for nid, est in clean_result.nodes.items():
        d = faulty_result.nodes[nid].position[:2] - est.position[:2]
        worst = max(worst, float(np.sqrt(d @ np.linalg.solve(est.covariance, d))))
    assert worst < 0.05, worst
    truth = faulty.truth
    nees = [float((e.position[:2] - truth.nodes[n][:2]) @ np.linalg.solve(e.covariance, e.position[:2] - truth.nodes[n][:2]))
            for n, e in faulty_result.nodes.items()]
    print(f"\nfaults injected {injected}; worst node shift {worst:.2e} sigma; ANEES {np.mean(nees):.2f}; "
          f"{len(seen)} observations of {len(visible)} visible pairs")
    assert np.mean(nees) < 4.0
