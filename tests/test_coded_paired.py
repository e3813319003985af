"""The ``searches`` lever (fgloc/survey/coded_paired.py; docs/blink-codes.md "A head already
there only grabs, and searches in pairs").

* A camera searching its node while another node is lit masks the other's light where it read
  it: on the example rig, with two LEDs in one frame, the unmasked search reads the wrong LED
  for some pair, the masked one reads its own LED for every pair, exactly as alone.
* With on-off detection a camera blinks only its own LED, so the other's steady light cancels.
* Two nodes share a batch only when each camera read the other node, far from the predicted
  disk of its own; otherwise each is searched alone.
* On a seeded occluded scene, ``paired`` lights a pair together: the same pairs read and not
  found, the paired nodes read exactly as one at a time, in less fallback time.
* A journal whose header predates the lever resumes with ``"one"``; the lever is schema-checked.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import PinholePixelModel
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.drivers.inprocess_rig import InProcessRig
from fgloc.files.journal import JournalObservation, read_journal
from fgloc.files.rig_config import load_rig
from fgloc.survey.coded_levers import LEGACY, PREDICTED_RADIUS
from fgloc.survey.coded_paired import CLEARANCE_PX, clear_of
from fgloc.survey.runner import CameraWorker, RunnerStats
from fgloc.survey.session import run_survey
from tests.test_rig_config import EXAMPLE
from tests.test_survey_coded import check_lever_in_schema, coded_rig, opened, parsed, resumed_and_new


def _read(worker: CameraWorker, node: str, start: tuple[float, float], ignore: list[np.ndarray]) -> tuple[float, float]:
    got: list[tuple[float, float]] = []
    assert worker.measure(node, [0], start, lambda _i, p, t: got.append((p, t)), None, ignore) is None
    return got[0]


def test_a_camera_masks_the_other_lit_led_where_it_read_it():
    rig = load_rig(EXAMPLE)
    sim = InProcessRig(rig)
    worker = CameraWorker("cam0", lambda: sim.open_head("cam0"), rig, RunnerStats())
    k = rig.cameras[0].intrinsics
    half = 0.4 * min(PinholePixelModel(k).field_of_view())
    seen = [j for j in range(len(sim.scene.node_ids)) if sim.scene.visible[0, j]]
    alone: dict[int, tuple[float, float]] = {}
    for j in seen:
        sim.scene.lit = {sim.scene.node_ids[j]}
        alone[j] = _read(worker, sim.scene.node_ids[j], tuple(sim.scene.apparent[0, j]), [])
    wrong_unmasked = tried = 0
    for a in seen:
        for b in seen:
            bearing_a, bearing_b = pan_tilt_bearing(*alone[a]), pan_tilt_bearing(*alone[b])
            apart = math.acos(min(1.0, float(bearing_a @ bearing_b)))
            if a == b or not CLEARANCE_PX / k.fx < apart < half:
                continue  # one frame holds both, far enough apart to mask one
            tried += 1
            sim.scene.lit = {sim.scene.node_ids[a], sim.scene.node_ids[b]}
            start = tuple(sim.scene.apparent[0, a])
            masked = _read(worker, sim.scene.node_ids[a], start, [bearing_b])
            assert masked == pytest.approx(alone[a], abs=1e-9)
            unmasked = _read(worker, sim.scene.node_ids[a], start, [])
            wrong_unmasked += unmasked != pytest.approx(alone[a], abs=1e-4)
    assert tried >= 5 and wrong_unmasked >= 1, (tried, wrong_unmasked)
    assert worker.locator.ignore == []  # measure leaves no mask behind


def test_on_off_detection_blinks_only_the_cameras_own_led_so_the_other_cancels():
    """Rendered frames (textured background, sensor noise) with on-off detection: a camera
    blinking only its own LED while another LED in the same frame stays lit reads its own LED
    as alone (within the noisy centroid's error), with no mask."""
    rig = load_rig(EXAMPLE.parent / "rig-rendered.json")
    sim = InProcessRig(rig)
    worker = CameraWorker("cam0", lambda: sim.open_head("cam0"), rig, RunnerStats())
    half = 0.4 * min(PinholePixelModel(rig.cameras[0].intrinsics).field_of_view())
    seen = [j for j in range(len(sim.scene.node_ids)) if sim.scene.visible[0, j]]

    def blink_only(node: str):
        def blink(grab):
            sim.scene.lit.discard(node)
            off = grab()
            sim.scene.lit.add(node)
            return grab(), off
        return blink

    def read(node: str, start: tuple[float, float]) -> tuple[float, float]:
        got: list[tuple[float, float]] = []
        assert worker.measure(node, [0], start, lambda _i, p, t: got.append((p, t)), blink_only(node)) is None
        return got[0]

    tried = 0
    for a in seen:
        b = next((b for b in seen if b != a and 0.05 < math.acos(min(1.0, float(
            pan_tilt_bearing(*sim.scene.apparent[0, a]) @ pan_tilt_bearing(*sim.scene.apparent[0, b])))) < half), None)
        if b is None:
            continue
        start = tuple(sim.scene.apparent[0, a])
        sim.scene.lit = {sim.scene.node_ids[a]}
        alone = read(sim.scene.node_ids[a], start)
        sim.scene.lit = {sim.scene.node_ids[a], sim.scene.node_ids[b]}
        together = read(sim.scene.node_ids[a], start)
        assert together == pytest.approx(alone, abs=3e-4)
        tried += 1
        if tried == 3:
            break
    assert tried == 3


def _runner_with(readings: dict[tuple[str, str], tuple[float, float]], fx: float = 500.0) -> SimpleNamespace:
    observations = {key: [JournalObservation(key[0], key[1], 0, *value)] for key, value in readings.items()}
    k = CameraIntrinsics(fx=fx, fy=fx, cx=320.0, cy=240.0, width=640, height=480)
    locator = SimpleNamespace(pixels=PinholePixelModel(k))
    return SimpleNamespace(state=SimpleNamespace(observations_of=lambda n, c: observations.get((n, c), [])),
                           workers={"cam0": SimpleNamespace(locator=locator)})


def test_a_pair_needs_the_other_node_read_and_clear_of_the_predicted_disk():
    need = PREDICTED_RADIUS + CLEARANCE_PX / 500.0
    runner = _runner_with({("B", "cam0"): (0.0, 0.0)})
    assert clear_of(runner, "cam0", (need + 0.002, 0.0), "B")
    assert clear_of(runner, "cam0", (0.0, -need - 0.002), "B")
    assert not clear_of(runner, "cam0", (need - 0.002, 0.0), "B")  # B's reading inside A's disk + clearance
    assert not clear_of(runner, "cam0", (0.3, 0.0), "D")  # cam0 never read D: never lit beside its node


def _scene(searches: str, tmp_path: Path):
    """100 motes, 30 % of the pairs occluded (seed 3): after the round, cam0 and cam1 each
    search one node the other read (zooms apart from moves: the recordings start at the clock
    times this scene was chosen at; explain "views": with "crowds" the ladder leaves this scene no
    pair to search; tiling "greedy": with the fewest views the fallback lights no pair). Returns the readings ((camera, node) -> (pan, tilt)), the
    pairs journaled not found, the fallback's field-time records, the rig and the journal."""
    data = coded_rig(100, 320, occlusion=0.3, seed=3)
    data["coded"] = {"searches": searches, "zoom_moves": "apart", "explain": "views", "tiling": "greedy"}
    rig = parsed(data)
    rig_opened, sim = opened(rig)
    out = tmp_path / searches
    run_survey(rig, out, opened=rig_opened)
    st = read_journal(out / "journal.jsonl")
    read = {(c, n): (o.pan, o.tilt) for (n, c, _), o in st.observations.items()}
    assert not sim.scene.visible_pairs() - set(read), "every visible pair is read"
    fallback = [r for r in st.field_times if str(r.get("scope", "")).startswith("fallback")]
    return read, set(st.not_found), fallback, rig, out / "journal.jsonl"


def test_paired_searches_read_the_same_pairs_in_less_time(tmp_path: Path):
    """... and a kill after a pair was lit, resumed with both LEDs still on (motes keep their
    LED), reads exactly the same: the partner is switched off before the other's search."""
    one = _scene("one", tmp_path)
    paired = _scene("paired", tmp_path)
    assert set(paired[0]) == set(one[0]) and paired[1] == one[1]
    pairs = [r for r in paired[2] if r["scope"] == "fallback_pair"]
    assert pairs and not any(r["scope"] == "fallback_pair" for r in one[2])
    for r in pairs:
        for node in r["nodes"]:
            for (c, n), value in paired[0].items():
                if n == node:
                    assert value == pytest.approx(one[0][(c, n)], abs=1e-12)
    assert sum(r["total_s"] for r in paired[2]) < sum(r["total_s"] for r in one[2])

    lines = paired[4].read_bytes().splitlines(keepends=True)
    pair = pairs[0]["nodes"]
    cut = max(k for k, line in enumerate(lines) if b'"node_started"' in line
              and any(f'"{n}"'.encode() in line for n in pair))
    resumed = tmp_path / "cut"
    resumed.mkdir()
    (resumed / "journal.jsonl").write_bytes(b"".join(lines[:cut + 1]))
    rig_opened, sim = opened(paired[3])
    sim.scene.lit = set(pair)  # the killed batch's LEDs
    run_survey(paired[3], resumed, resume=True, opened=rig_opened)
    st = read_journal(resumed / "journal.jsonl")
    assert {(c, n): (o.pan, o.tilt) for (n, c, _), o in st.observations.items()} == paired[0]
    assert st.duplicates_ignored == 0 and not sim.scene.lit


def test_an_old_header_resumes_one_at_a_time_and_the_lever_is_schema_checked():

    assert LEGACY["searches"] == "one"
    assert resumed_and_new("searches", fallback="round", levels=[2 / 9, 1.0]) == ("one", "paired")
    check_lever_in_schema("searches", "one", "all")
