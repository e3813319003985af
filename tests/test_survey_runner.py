"""The survey runner against the in-process simulated rig: outcomes, resume, faults, live estimates."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import replace

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.drivers.inprocess_rig import InProcessRig
from fgloc.files.journal import read_journal
from fgloc.files.rig_config import parse_rig
from fgloc.survey.runner import Progress, format_progress
from fgloc.survey.session import OpenedRig, journal_survey, run_survey
from tests.test_rig_config import EXAMPLE


def small_rig(n_nodes: int = 8, **simulation):
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    sim = {"seed": 1, "heights": [0.1, 0.12], "occlusion": 0.1, "dead_nodes": ["n003"]}
    sim.update(simulation)
    data["simulation"] = sim
    data["retry"] = {"backoff_s": 0.0}
    return parse_rig(data, str(EXAMPLE), EXAMPLE.parent)


def opened(rig):
    sim = InProcessRig(rig)
    return OpenedRig(open_head=sim.open_head, leds=sim.leds, simulated=sim), sim


def obs_by_key(path):
    return {k: (o.pan, o.tilt) for k, o in read_journal(path).observations.items()}


def resume_from_cuts(rig, data: bytes, ends: list[int], tmp_path) -> list:
    """Cut ``data`` (a finished journal) after each of ``ends`` and 9 bytes into the next
    record (a torn line), resume each cut, and check it ends with exactly the uninterrupted
    run's observations and no duplicate; returns the resumed journal states."""
    full = tmp_path / "uncut.jsonl"
    full.write_bytes(data)
    reference = obs_by_key(full)
    states = []
    for k, cut in enumerate(ends + [e + 9 for e in ends[:-1]]):
        d = tmp_path / f"cut{k}"
        d.mkdir()
        (d / "journal.jsonl").write_bytes(data[:cut])
        run_survey(rig, d, resume=True, opened=opened(rig)[0])
        state = read_journal(d / "journal.jsonl")
        assert state.duplicates_ignored == 0, cut
        assert obs_by_key(d / "journal.jsonl") == reference, cut
        states.append(state)
    return states


def test_survey_observes_every_visible_pair_and_records_the_rest(tmp_path):
    rig = small_rig(10)
    rig_opened, sim = opened(rig)
    survey, runner = run_survey(rig, tmp_path, opened=rig_opened)
    state = read_journal(tmp_path / "journal.jsonl")
    seen = {(c, n) for (n, c, _) in state.observations}
    assert seen == sim.scene.visible_pairs()
    assert set(state.led_failed) == {"n003"}
    occluded = {(n, c) for i, c in enumerate(rig.camera_ids) for j, n in enumerate(rig.node_ids)
                if not sim.scene.visible[i, j] and n != "n003"}
    assert occluded and set(state.not_found) == occluded
    assert state.done == set(rig.node_ids)
    for (n, c, _), o in state.observations.items():
        want = sim.scene.apparent[rig.camera_ids.index(c), rig.node_ids.index(n)]
        assert abs(math.remainder(o.pan - want[0], 2 * math.pi)) < 1e-4
        assert abs(o.tilt - want[1]) < 1e-4
    assert (tmp_path / "survey.json").exists()
    assert survey.truth is not None and set(survey.truth.nodes) == set(rig.node_ids)


def test_resume_from_any_kill_point_gives_the_same_observations(tmp_path):
    """Cut the uninterrupted run's journal after every record (and mid-record), resume:
    the observations are exactly those of the uninterrupted run, none lost or duplicated."""
    rig = small_rig(6)
    full_dir = tmp_path / "full"
    run_survey(rig, full_dir, opened=opened(rig)[0])
    data = (full_dir / "journal.jsonl").read_bytes()
    ends = [i + 1 for i, b in enumerate(data) if b == ord("\n")]
    for state in resume_from_cuts(rig, data, ends, tmp_path):
        assert state.done == set(rig.node_ids)


def test_resume_refuses_another_rig_and_new_run_refuses_existing_journal(tmp_path):
    rig = small_rig(5)
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    with pytest.raises(FglocError, match="journal already exists"):
        run_survey(rig, tmp_path, opened=opened(rig)[0])
    other = small_rig(5, seed=2)  # another simulated scene: other truth, other readings
    with pytest.raises(FglocError, match=r"simulation\.seed: changes what the readings recorded in .* mean "
                                         r"\(was 1, now 2\)"):
        run_survey(other, tmp_path, resume=True, opened=opened(other)[0])


def test_faults_are_retried_and_a_disconnect_reconnected(tmp_path):
    rig = small_rig(12, drop_rate=0.05, garble_rate=0.01, disconnect_after=40, disconnect_camera="cam1")
    rig_opened, sim = opened(rig)
    _, runner = run_survey(rig, tmp_path, opened=rig_opened)
    assert sim.faults.injected["disconnects"] == 1 and sim.faults.injected["dropped"] > 0
    assert runner.stats.reconnects >= 1 and runner.stats.head_errors >= sim.faults.injected["dropped"]
    state = read_journal(tmp_path / "journal.jsonl")
    assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()


def test_a_dead_camera_is_recorded_not_fatal(tmp_path, caplog):
    rig = small_rig(5)
    rig_opened, sim = opened(rig)

    def open_head(cid):
        if cid == "cam1":
            raise ConnectionError("no such port")
        return sim.open_head(cid)

    with caplog.at_level(logging.INFO, logger="fgloc"):
        run_survey(rig, tmp_path, opened=replace(rig_opened, open_head=open_head))
    state = read_journal(tmp_path / "journal.jsonl")
    assert all(c == "cam0" for (_, c, _) in state.observations)
    assert all("camera error" in r for (n, c), r in state.not_found.items() if c == "cam1")
    # Each outcome is a log record: a failing camera is a warning, an occluded pair only information.
    logged = {(r.levelname, r.getMessage()) for r in caplog.records if r.name == "fgloc.survey.runner"}
    assert {m for lvl, m in logged if lvl == "WARNING" and "not found by cam1" in m} == {
        f"{n}: not found by cam1: {r}" for (n, c), r in state.not_found.items() if c == "cam1"}
    assert {m for lvl, m in logged if lvl == "INFO"} == {
        f"{n}: not found by cam0: {r}" for (n, c), r in state.not_found.items() if c == "cam0"}
    assert ("WARNING", f"n003: LED failed: {state.led_failed['n003']}") in logged
    assert state.done == set(rig.node_ids)


class CountingEstimator:
    """A stand-in for an incremental estimator: records what it was given, solves in batch."""

    def __init__(self):
        self.sizes = []

    def update(self, survey):
        from fgloc.solve.joint import solve_survey

        self.sizes.append(len(survey.observations))
        return solve_survey(survey)


def test_live_estimates_and_progress(tmp_path):
    rig = small_rig(10, occlusion=0.0, dead_nodes=[])
    est = CountingEstimator()
    estimates, progress = [], []
    survey, runner = run_survey(rig, tmp_path, opened=opened(rig)[0], estimator=est,
                                on_estimate=estimates.append, on_progress=progress.append)
    # Estimates start once five nodes are seen by both cameras, then follow every node.
    assert est.sizes == [10, 12, 14, 16, 18, 20]
    assert [e.nodes_done for e in estimates] == [5, 6, 7, 8, 9, 10]
    final = estimates[-1].result
    assert set(final.nodes) == set(rig.node_ids)
    truth = survey.truth
    err = max(np.linalg.norm(final.nodes[n].position - truth.nodes[n]) for n in rig.node_ids)
    assert err < 0.05  # sigma 0.1 deg, 10 nodes: errors are ~1e-2
    assert [p.nodes_done for p in progress] == list(range(11))
    assert progress[-1].eta_s == 0.0 and (tmp_path / "estimate.json").exists()
    line = format_progress(Progress(3, 10, 6, 1, 75.0))
    assert "3/10 nodes" in line and "6 obs" in line and "left 01:15" in line


def test_journal_survey_reads_a_directory(tmp_path):
    rig = small_rig(4, occlusion=0.0, dead_nodes=[])
    survey, _ = run_survey(rig, tmp_path, opened=opened(rig)[0])
    assert journal_survey(tmp_path).observations == survey.observations


def test_open_hardware_reaches_every_transport_through_rig_json(tmp_path):
    """rig.json port strings for VISCA serial, VISCA-IP, Sony CGI and a TinyOS base station open
    the real drivers (here against the issue-7a twins) and answer."""
    from fgloc.drivers.twins.rig import TwinCamera, TwinRig
    from fgloc.survey.session import open_hardware

    cams = [TwinCamera("cam0", "serial"), TwinCamera("cam1", "udp", model="VISCA-IP"),
            TwinCamera("cam2", "http", model="SNC-RZ25N")]
    with TwinRig(cams) as twins:
        data = json.loads(EXAMPLE.read_text())
        k = data["cameras"][0]["intrinsics"]
        drivers = {"cam0": "visca-serial", "cam1": "visca-ip", "cam2": "sony-cgi"}
        data["cameras"] = [{"id": c.camera_id, "driver": drivers[c.camera_id], "port": twins.ports[c.camera_id],
                            "model": c.model, "intrinsics": k} for c in cams]
        data["motes"] = {"driver": "tinyos-serial", "port": twins.mote_port, "addresses": {"n000": 5}}
        data["node_ids"] = ["n000"]
        del data["simulation"]
        rig = parse_rig(data, "rig.json", EXAMPLE.parent)
        opened_rig = open_hardware(rig)
        try:
            for cid in rig.camera_ids:
                head = opened_rig.open_head(cid)
                head.move_to(0.2, 0.1)
                pan, tilt = head.position()
                assert abs(pan - 0.2) < 0.01 and abs(tilt - 0.1) < 0.01
                head.close()
            assert opened_rig.leds.set_led("n000", True)
            assert twins.field.led_on.get(5) is True
        finally:
            opened_rig.close()


def test_cli_survey_over_the_visca_twins_and_resume(tmp_path, capsys):
    """fgloc survey --simulate with simulation.twin = visca: real VISCA and TinyOS bytes end to end."""
    from fgloc.cli import main
    from tests.test_survey_acceptance import visca_rig

    rig = visca_rig(tmp_path / "rig.json", 8, occlusion=0.0)
    out = tmp_path / "out"
    assert main(["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "estimate after 8 nodes: 8 localized" in text and "16 observations" in text
    survey = read_survey_file(out / "survey.json")
    assert len(survey.observations) == 16 and survey.truth is not None

    assert main(["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "journal already exists (use --resume" in err and err.count("\n") == 1
    assert main(["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--resume", "--quiet"]) == 0
    assert "(8 nodes already done" in capsys.readouterr().out
    assert read_survey_file(out / "survey.json").observations == survey.observations


def read_survey_file(path):
    from fgloc.files.survey_result import read_survey

    return read_survey(path)


@pytest.mark.slow
def test_on_off_detection_on_rendered_frames_with_background_and_a_static_light(tmp_path):
    """Against the camera pipeline's renderer (drivers/rendered_camera.py: textured background,
    sensor noise, an always-on bright light in view of both cameras) the survey finds every
    node with on/off frame pairs and fgloc.camera.led_detection. Truth here is noise-free geometry, so
    each reading must equal the true bearing to within the centroid error of a noisy spot
    (~0.05 px at ~400 px focal length: 1e-4 rad; tolerance 3e-4 rad). With "single" detection
    the same survey reads the background or the static light (errors of radians)."""
    from fgloc.camera.intrinsics import CameraIntrinsics
    from fgloc.core.geometry import project_pan_tilt
    from fgloc.drivers.rendered_camera import simulated_rig
    from fgloc.sim.scenes import PaperScenario, paper_scenario

    truth_survey = paper_scenario(PaperScenario(n_nodes=6, heights=(0.3, 0.35), seed=5))
    truth = truth_survey.truth
    intr = CameraIntrinsics.from_fov(320, 240, 40.0)
    heads, leds = simulated_rig(truth.cameras, truth.nodes, intr, seed=3,
                                distractors=np.array([[0.5, 0.5, 0.02]]))
    data = json.loads(EXAMPLE.read_text())
    for cam in data["cameras"]:
        cam["intrinsics"] = {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy,
                             "width": intr.width, "height": intr.height}
    data["node_ids"] = list(truth_survey.node_ids)
    data["search"] = {"detection": "on-off", "tilt_min_deg": -85, "tilt_max_deg": 10}
    data["retry"] = {"backoff_s": 0.0}
    del data["simulation"]
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    survey, runner = run_survey(rig, tmp_path, opened=OpenedRig(open_head=lambda cid: heads[cid], leds=leds))
    assert len(survey.observations) == 12
    for o in survey.observations:
        pose = truth.cameras[o.camera]
        pan, tilt = project_pan_tilt(pose.rotation, pose.position, truth.nodes[o.node][None, :])
        assert abs(math.remainder(o.pan - float(pan[0]), 2 * math.pi)) < 3e-4
        assert abs(o.tilt - float(tilt[0])) < 3e-4


class FakeLocalizer:
    """Records what an incremental localizer is fed; estimates by batch-solving all of it."""

    instances = []

    def __init__(self, camera_ids, gauge, sigma):
        self.args = (camera_ids, gauge, sigma)
        self.fed = []
        FakeLocalizer.instances.append(self)

    def add_observations(self, observations):
        self.fed.append(list(observations))

    def estimate(self):
        from fgloc.core.model import NodeMode, Survey
        from fgloc.solve.joint import solve_survey

        obs = [o for batch in self.fed for o in batch]
        nodes = sorted({o.node for o in obs})
        return solve_survey(Survey(NodeMode.PLANAR, self.args[1], self.args[2], self.args[0], nodes, obs))


def test_incremental_estimator_feeds_each_reading_once(tmp_path):
    from fgloc.survey.live import IncrementalEstimator

    FakeLocalizer.instances.clear()
    rig = small_rig(8, occlusion=0.0, dead_nodes=[])
    est = IncrementalEstimator(FakeLocalizer)
    survey, runner = run_survey(rig, tmp_path, opened=opened(rig)[0], estimator=est)
    (loc,) = FakeLocalizer.instances
    fed = [o for batch in loc.fed for o in batch]
    assert sorted(fed, key=repr) == sorted(survey.observations, key=repr)  # each exactly once
    assert [len(b) for b in loc.fed] == [10, 2, 2, 2]  # first estimate at 5 shared nodes, then per node
    assert runner.latest is not None and set(runner.latest.result.nodes) == set(rig.node_ids)


def test_incremental_estimator_with_isam2_tracks_the_batch_solve(tmp_path):
    """The default live estimator: batch estimates until iSAM2 bootstraps (12 shared nodes),
    then iSAM2's. Truth: the batch solve of the same journal; the live estimate may differ
    only by linearization error, a fraction of each node's sigma."""
    from fgloc.solve.joint import SolverOptions, solve_survey
    from fgloc.survey.live import IncrementalEstimator

    rig = small_rig(20, occlusion=0.0, dead_nodes=[])
    est = IncrementalEstimator()
    seen = []
    survey, runner = run_survey(rig, tmp_path, opened=opened(rig)[0], estimator=est,
                                on_estimate=lambda live: seen.append((live.nodes_done, live.result.stats.method)))
    methods = dict(seen)
    assert methods[min(methods)] != "isam2" and methods[20] == "isam2"
    batch = solve_survey(survey, SolverOptions(gauge_sigma=est.localizer.gauge_sigma))
    live = runner.latest.result
    assert set(live.nodes) == set(batch.nodes) == set(rig.node_ids)
    for nid, b in batch.nodes.items():
        sigma = np.sqrt(np.trace(b.covariance))
        assert np.abs(live.nodes[nid].position - b.position).max() < 0.5 * sigma
        assert np.abs(live.nodes[nid].covariance - b.covariance).max() < 0.2 * np.abs(b.covariance).max()


def test_cli_survey_logs_live_estimates_to_rerun(tmp_path, capsys):
    """--rerun: every live estimate lands on the 'survey' timeline (step = observations so
    far), and the last one logged is the estimate.json the survey wrote."""
    from fgloc.cli import main
    from fgloc.files.survey_result import read_result
    from tests.rrd_reading import load_rrd

    rig = EXAMPLE  # examples/rig-simulated.json: 20 nodes, 2 cameras
    rrd, out = tmp_path / "live.rrd", tmp_path / "out"
    assert main(["survey", "--rig", str(rig), "-o", str(out), "--simulate", "--quiet", "--rerun", str(rrd)]) == 0
    shown = capsys.readouterr().out.count("estimate after")
    rows = load_rrd(rrd)["world/nodes/estimate"].timed["survey"]["Points3D:positions"]
    assert shown >= 3 and len(rows) == shown
    steps = [t for t, _ in rows]
    assert steps == sorted(steps) and steps[-1] == len(read_survey_file(out / "survey.json").observations)
    final = read_result(out / "estimate.json")
    logged = np.asarray(rows[-1][1], float)
    expected = np.array([final.nodes[n].position for n in final.nodes])
    assert logged.shape == expected.shape
    assert np.abs(np.sort(logged, axis=0) - np.sort(expected, axis=0)).max() < 1e-6


def test_incremental_estimator_solves_3d_surveys_in_batch():
    """IncrementalLocalizer is planar only; a 3d journal (a real rig with "nodes": "3d") must
    get 3d estimates, the batch solve's, never planar ones."""
    from fgloc.core.model import NodeMode
    from fgloc.sim.scenes import RandomScene, random_scene
    from fgloc.solve.joint import solve_survey
    from fgloc.survey.live import IncrementalEstimator

    survey = random_scene(RandomScene(n_cameras=3, n_nodes=40, mode=NodeMode.THREE_D, seed=3))
    est = IncrementalEstimator()
    live = est.update(survey)
    batch = solve_survey(survey)
    assert live.mode is NodeMode.THREE_D and est.localizer is None
    for nid, b in batch.nodes.items():
        assert np.abs(live.nodes[nid].position - b.position).max() < 1e-9


class FailingOnceLocalizer(FakeLocalizer):
    """Raises like GTSAM does (RuntimeError) on its second batch of readings."""

    def add_observations(self, observations):
        super().add_observations(observations)
        if len(FakeLocalizer.instances) == 1 and len(self.fed) == 2:
            raise RuntimeError("Indeterminant linear system detected while working near variable 7")


def test_a_failing_live_estimate_never_stops_the_survey(tmp_path, caplog):
    """A GTSAM failure inside the incremental estimator is one logged line; the survey goes
    on, and the next estimate starts a new localizer fed every reading once."""
    from fgloc.survey.live import IncrementalEstimator

    FakeLocalizer.instances.clear()
    rig = small_rig(8, occlusion=0.0, dead_nodes=[])
    est = IncrementalEstimator(FailingOnceLocalizer)
    with caplog.at_level(logging.INFO, logger="fgloc"):
        survey, runner = run_survey(rig, tmp_path, opened=opened(rig)[0], estimator=est)
    failed = [r for r in caplog.records if "live estimate failed" in r.getMessage()]
    assert len(failed) == 1 and failed[0].levelno == logging.WARNING and failed[0].name == "fgloc.survey.runner"
    assert "Indeterminant linear system" in failed[0].getMessage() and "\n" not in failed[0].getMessage()
    assert len(survey.observations) == 16  # every node surveyed despite the failure
    assert len(runner.stats.estimate_errors) == 1 and "Indeterminant" in runner.stats.estimate_errors[0]
    first, second = FakeLocalizer.instances
    fed = [o for batch in second.fed for o in batch]
    assert sorted(fed, key=repr) == sorted(survey.observations, key=repr)  # each exactly once, from scratch
    assert runner.latest is not None and set(runner.latest.result.nodes) == set(rig.node_ids)


class DegenerateStartLocalizer(FakeLocalizer):
    """Raises what a degenerate early subset raises inside the closed-form start (a ValueError)."""

    def add_observations(self, observations):
        super().add_observations(observations)
        if len(FakeLocalizer.instances) == 1 and len(self.fed) == 2:
            raise ValueError("RANSAC found no consistent model")


def test_any_exception_in_a_live_estimate_is_logged_and_the_survey_goes_on(tmp_path, caplog):
    """Only FglocError used to be caught: a ValueError from the start ended the survey (and every resume)."""
    from fgloc.survey.live import IncrementalEstimator

    FakeLocalizer.instances.clear()
    rig = small_rig(8, occlusion=0.0, dead_nodes=[])
    with caplog.at_level(logging.WARNING, logger="fgloc.survey"):
        survey, runner = run_survey(rig, tmp_path, opened=opened(rig)[0],
                                    estimator=IncrementalEstimator(DegenerateStartLocalizer))
    assert [r.getMessage() for r in caplog.records] == [
        "live estimate failed: incremental estimate: RANSAC found no consistent model"]
    assert len(survey.observations) == 16
    assert len(runner.stats.estimate_errors) == 1 and "RANSAC" in runner.stats.estimate_errors[0]
    assert len(FakeLocalizer.instances) == 2  # a fresh localizer after the failure
    assert runner.latest is not None and set(runner.latest.result.nodes) == set(rig.node_ids)


def test_worker_forgets_the_rest_on_any_other_operation_and_repeats_move():
    """Through the worker: a node searched from where the head rests grabs at once; any other
    operation of the head (a coded view, a zoom, a reconnect) makes the next search move; and a
    repeat reading points the head anew (its own settle), never re-reads the same frame."""
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.files.rig_config import load_rig
    from fgloc.survey.runner import CameraWorker, RunnerStats
    from tests.test_led_search import _CountingHead, _visible_node
    from tests.test_rig_config import EXAMPLE

    rig = load_rig(EXAMPLE)
    sim = InProcessRig(rig)
    heads = []

    def open_head():
        heads.append(_CountingHead(sim.open_head("cam0")))
        return heads[-1]

    worker = CameraWorker("cam0", open_head, rig, RunnerStats())
    near = _visible_node(sim)
    readings: list[tuple[float, float]] = []

    def record(_index, pan, tilt):
        readings.append((pan, tilt))

    sim.scene.lit = {near}
    assert worker.measure(near, [0], None, record) is None
    head = heads[-1]
    head.ops.clear()
    assert worker.measure(near, [0], readings[-1], record) is None
    assert head.ops[0] == "grab" and "move" not in head.ops
    worker.call(lambda h: h.position())  # another operation: the rest is forgotten
    head.ops.clear()
    assert worker.measure(near, [0], readings[-1], record) is None
    assert head.ops[0] == "move"
    head.ops.clear()
    assert worker.measure(near, [0, 1], readings[-1], record) is None
    # the first reading grabs where the head rests; the repeat moves before its own grab
    assert head.ops[0] == "grab" and head.ops.count("move") == 1
    assert head.ops.index("move") > head.ops.index("position") and len(readings) == 5
