"""Head errors injected from rig.json: the simulated heads (in process, rendered, VISCA bytes) are imperfect heads."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing, world_to_base, wrap_angle
from fgloc.core.head_model import HEAD_PARAMETERS, head_pan_tilt
from fgloc.core.model import CameraPose
from fgloc.drivers.imperfect_head import ideal_equivalent_directions
from fgloc.files.rig_config import load_rig, parse_rig, rig_meaning
from fgloc.sim.scenes import random_base_rotation
from tests.test_rig_config import EXAMPLE

#: cam0's head: the typical sizes of issue 17 with a tilt index of exactly 0.3 degree
CAM0_ERRORS = {"tilt_index_deg": 0.3, "collimation_deg": 0.2, "trunnion_deg": -0.2, "pan_scale_percent": 0.5,
               "tilt_scale_percent": -0.5, "lever_y_baseline": 0.0004, "lever_z_baseline": -0.0003}


def head_rig_data(n_nodes: int = 60, twin: str = "inprocess", sigma_deg: float = 0.03, cameras: int = 3,
                  head_errors: dict | None = None, seed: int = 1) -> dict:
    """A planar rig of ``cameras`` cameras with head errors; VISCA twins are ceiling EVI-D70s."""
    data = json.loads(EXAMPLE.read_text())
    data["sigma_deg"] = sigma_deg
    while len(data["cameras"]) < cameras:
        data["cameras"].append(dict(data["cameras"][0], id=f"cam{len(data['cameras'])}"))
    if twin == "visca":
        for cam in data["cameras"]:
            cam["model"], cam["mounting"] = "EVI-D70", "ceiling"
        data["search"] = {"pan_min_deg": -170, "pan_max_deg": 170, "tilt_min_deg": -88, "tilt_max_deg": 25,
                          "method": "pixel-offset"}
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    if head_errors is None:
        # a copy: callers edit the returned data, and CAM0_ERRORS is shared with other test modules
        head_errors = {"cam0": dict(CAM0_ERRORS)} | {f"cam{i}": "typical" for i in range(1, cameras)}
    data["simulation"] = {"seed": seed, "heights": [0.1, 0.12, 0.15, 0.1][:cameras], "twin": twin,
                          "head_errors": head_errors}
    data["retry"] = {"backoff_s": 0.0}
    return data


def head_rig(tmp_path: Path, **kw):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(head_rig_data(**kw)))
    return load_rig(path)


def expected_reading(scene, i: int, j: int) -> tuple[float, float]:
    """What camera i's imperfect head reads for node j: the head model at the point at the node's
    range along the pair's apparent (noisy ideal) bearing."""
    cam = scene.cameras[i]
    q = np.linalg.norm(scene.nodes[j] - cam.position) * pan_tilt_bearing(*scene.apparent[i, j])
    pan, tilt, _, _ = head_pan_tilt(q, scene.heads[i], jacobians=False)
    return float(pan), float(tilt)


# -- rig.json ------------------------------------------------------------------------------------

def test_rig_json_head_errors_parse_in_model_units(tmp_path):
    rig = head_rig(tmp_path)
    p = np.array(rig.simulation.head_errors["cam0"])
    want = [math.radians(0.3), math.radians(0.2), math.radians(-0.2), 0.005, -0.005, 0.0004, -0.0003]
    np.testing.assert_allclose(p, want, rtol=1e-12)
    for cid in ("cam1", "cam2"):  # "typical": the typical magnitudes, random signs, |lever| = 0.0005
        t = np.abs(rig.simulation.head_errors[cid])
        np.testing.assert_allclose(t[:5], np.radians([0.3, 0.2, 0.2]).tolist() + [0.005, 0.005], rtol=1e-12)
        assert math.hypot(t[5], t[6]) == pytest.approx(0.0005)
    assert rig.simulation.head_errors["cam1"] != rig.simulation.head_errors["cam2"]
    assert head_rig(tmp_path).simulation.head_errors == rig.simulation.head_errors  # seeded
    assert rig_meaning(rig, simulated=True)["simulation.head_errors"]["cam0"] == list(p)
    # version-1 files without the field: no head errors, and the meaning a journal stores is unchanged
    plain = parse_rig(json.loads(EXAMPLE.read_text()), str(EXAMPLE), EXAMPLE.parent)
    assert plain.simulation.head_errors == {} and "simulation.head_errors" not in rig_meaning(plain, True)


@pytest.mark.parametrize("value, message", [
    ({"cam0": {"tilt_index_deg": "0.3"}},
     "rig.json: simulation.head_errors.cam0.tilt_index_deg: expected a finite number, got \"0.3\""),
    ({"cam0": {"tilt_index_deg": 45}}, "rig.json: simulation.head_errors.cam0.tilt_index_deg: must lie in [-5, 5], got 45"),
    ({"cam0": {"tilt_index": 0.3}}, "rig.json: simulation.head_errors.cam0: expected one of tilt_index_deg, "
     "collimation_deg, trunnion_deg, pan_scale_percent, tilt_scale_percent, lever_y_baseline, lever_z_baseline, lever_by_zoom, "
     "got 'tilt_index'"),
    ({"cam0": "large"}, "rig.json: simulation.head_errors.cam0: expected \"typical\" or an object of head errors, "
     "got 'large'"),
    ({"camX": "typical"}, "rig.json: simulation.head_errors.camX: camera 'camX' is not in cameras"),
])
def test_bad_head_errors_are_refused_in_one_line(value, message):
    data = head_rig_data(cameras=2, head_errors=value)
    with pytest.raises(FglocError) as exc:
        parse_rig(data, "rig.json", EXAMPLE.parent)
    assert str(exc.value) == message and "\n" not in str(exc.value)


def test_cli_refuses_a_bad_head_error_with_exit_2(tmp_path, capsys):
    from fgloc.cli import main

    path = tmp_path / "rig.json"
    path.write_text(json.dumps(head_rig_data(cameras=2, head_errors={"cam1": {"trunnion_deg": float("nan")}})
                               ).replace("NaN", "1e999"))
    assert main(["survey", "--rig", str(path), "-o", str(tmp_path / "out"), "--simulate", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "simulation.head_errors.cam1.trunnion_deg" in err[0] and str(path) in err[0]


# -- the imperfect head's geometry ------------------------------------------------------------------

def test_ideal_head_centres_a_point_exactly_at_the_head_models_readings():
    """The renderers' contract: at the head model's (pan, tilt) for q, the ideal head at those
    readings shows q straight ahead (so a centred LED reads what the imperfect head reads);
    anywhere else it does not."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        p = rng.normal(size=7) * np.array([0.01, 0.01, 0.01, 0.01, 0.01, 0.002, 0.002])
        q = rng.normal(size=3) * np.array([1.0, 1.0, 0.3])
        pan, tilt, _, _ = head_pan_tilt(q, p, jacobians=False)
        d = ideal_equivalent_directions(p, float(pan), float(tilt), q)[0]
        shown_pan, shown_tilt = bearing_pan_tilt(d)
        assert abs(float(wrap_angle(shown_pan - pan))) < 1e-12 and abs(float(shown_tilt - tilt)) < 1e-12
        ideal_pan, ideal_tilt = bearing_pan_tilt(q)
        d0 = ideal_equivalent_directions(p, float(ideal_pan), float(ideal_tilt), q)[0]
        assert np.degrees(np.arccos(np.clip(d0 @ pan_tilt_bearing(ideal_pan, ideal_tilt) / np.linalg.norm(d0),
                                            -1, 1))) > 1e-3


def test_rendered_simulated_head_with_errors_centres_at_the_head_models_readings():
    """drivers/rendered_camera.py's SimulatedHead: the LED's truth pixel is the principal point
    exactly when the head is at the head model's readings for it."""
    from fgloc.camera.intrinsics import CameraIntrinsics
    from fgloc.drivers.rendered_camera import simulated_rig

    intr = CameraIntrinsics(fx=400.0, fy=400.0, cx=159.5, cy=119.5, width=320, height=240)
    pose = CameraPose(np.array([0.0, 0.0, 0.2]), random_base_rotation(np.random.default_rng(2), 3.0))
    node = np.array([0.6, 0.4, 0.0])
    p = np.array([math.radians(0.3), math.radians(0.2), math.radians(-0.2), 0.005, -0.005, 0.001, 0.0])
    heads, _ = simulated_rig({"c": pose}, {"n": node}, intr, head_errors={"c": p})
    pan, tilt, _, _ = head_pan_tilt(world_to_base(pose.rotation, pose.position, node), p, jacobians=False)
    head = heads["c"]
    head.move_to(float(pan), float(tilt))
    u, v = head.visible_leds()["n"]
    assert (u, v) == pytest.approx((intr.cx, intr.cy), abs=1e-9)
    ideal, _ = simulated_rig({"c": pose}, {"n": node}, intr)
    ideal["c"].move_to(float(pan), float(tilt))
    u0, v0 = ideal["c"].visible_leds()["n"]
    assert math.hypot(u0 - intr.cx, v0 - intr.cy) > 2.0  # 0.3 degree is ~2 px at this focal length


# -- surveys: readings and the self-calibrating solve ----------------------------------------------

# The VISCA twin runs on a compressed clock (as in tests/test_survey_acceptance.py, TWIN_TIMING):
# on a loaded 2-core machine a reading was once missing (35 of 36, seen once in a fresh-clone run,
# never when re-run); the re-run keeps the assertions, and the message names the journal's reasons.
@pytest.mark.parametrize("twin", ["inprocess", pytest.param("visca", marks=pytest.mark.flaky(reruns=2, reruns_delay=1))])
def test_survey_readings_are_the_imperfect_heads(tmp_path, twin):
    """Through the survey runner (and for ``visca`` the real VISCA driver reading Pan-tiltPosInq
    bytes from the pty twin), every reading is what the imperfect head reads, to within the
    measurement chain's own error (10 % of sigma); the ideal head's reading is far from it."""
    from fgloc.survey.session import open_simulated, run_survey

    rig = head_rig(tmp_path, n_nodes=12, twin=twin)
    opened = open_simulated(rig)
    try:
        survey, _ = run_survey(rig, tmp_path / "s", opened=opened)
        scene = opened.simulated.scene  # type: ignore[attr-defined]
    finally:
        opened.close()
    if len(survey.observations) != 36:
        from fgloc.files.journal import read_journal

        state = read_journal(tmp_path / "s" / "journal.jsonl")
        pytest.fail(f"{len(survey.observations)} of 36 readings; not_found: {state.not_found}")
    far, worst, checked = 0, 0.0, 0
    for o in survey.observations:
        i, j = rig.camera_ids.index(o.camera), rig.node_ids.index(o.node)
        pan, tilt = expected_reading(scene, i, j)
        if abs(pan) > math.radians(168.0):
            # beyond an EVI-D70's +-170 degree range the LED is read far off the image centre (see below)
            continue
        checked += 1
        worst = max(worst, abs(float(wrap_angle(o.pan - pan))), abs(o.tilt - tilt))
        ideal = scene.apparent[i, j]
        far += math.hypot(float(wrap_angle(o.pan - ideal[0])), o.tilt - ideal[1]) > 3 * rig.sigma
    # pixel-offset readings convert the LED's offset from the image centre with the ideal head's
    # geometry: the imperfect head's scale error and image roll leave ~1 % of that offset
    print(f"worst reading error {worst / rig.sigma:.3f} sigma")
    assert worst < 0.1 * rig.sigma, worst / rig.sigma
    assert checked >= 30 and far >= checked - 3  # the head errors (several sigma) show in nearly every reading


def _anees(result, truth) -> float:
    v = []
    for n, e in result.nodes.items():
        d = (e.position - truth.nodes[n])[:2]
        v.append(float(d @ np.linalg.solve(np.asarray(e.covariance)[:2, :2], d)))
    return float(np.mean(v)) / 2.0


def test_visca_twin_survey_solved_with_the_full_head_model_recovers_the_tilt_index(tmp_path, capsys):
    """A 60-node, 3-camera survey over VISCA bytes with typical head errors (cam0: tilt index
    0.3 degree), sigma 0.03 degree, solved by ``fgloc solve --head-model full``: cam0's tilt
    index comes out within 3 sigma of 0.3 degree with a sigma small enough (< 0.1 degree) that
    an estimate of zero would be refused; the ideal solve of the same survey is far from
    consistent (ANEES > 20, measured 1559) while the self-calibrated one is not
    overconfident (ANEES < 1.5, measured 0.46: prior-dominated, see docs/head-calibration.md);
    cam0's tilt index measured 0.285 +- 0.054 degree."""
    from fgloc.cli import main
    from fgloc.files.survey_result import read_result, read_survey
    from fgloc.survey.session import open_simulated, run_survey

    rig = head_rig(tmp_path, n_nodes=60, twin="visca")
    opened = open_simulated(rig)
    try:
        run_survey(rig, tmp_path / "s", opened=opened)
    finally:
        opened.close()
    survey_path = tmp_path / "s" / "survey.json"
    assert main(["solve", str(survey_path), "-o", str(tmp_path / "ideal.json")]) in (0, 3)
    assert main(["solve", str(survey_path), "--head-model", "full", "-o", str(tmp_path / "full.json")]) in (0, 3)
    out = capsys.readouterr().out
    assert "head model full: all parameters estimated" in out
    block = json.loads((tmp_path / "full.json").read_text())["head_calibration"]
    cam0 = block["cameras"]["cam0"]
    k = HEAD_PARAMETERS.index("tilt_index")
    est, std = math.degrees(cam0["values"][k]), math.degrees(cam0["std"][k])
    assert std < 0.1 and abs(est - 0.3) < 3 * std, (est, std)
    truth = read_survey(survey_path).truth
    assert truth is not None
    ideal_anees = _anees(read_result(tmp_path / "ideal.json"), truth)
    full_anees = _anees(read_result(tmp_path / "full.json"), truth)
    assert ideal_anees > 20 and full_anees < 1.5, (ideal_anees, full_anees)


def test_resuming_a_simulated_survey_with_other_head_errors_is_refused(tmp_path):
    """Head errors fix what a simulated survey's readings mean: the journal records them."""
    from fgloc.survey.session import run_survey

    rig = head_rig(tmp_path, n_nodes=4, cameras=2)
    run_survey(rig, tmp_path / "s", simulate=True)
    data = head_rig_data(n_nodes=4, cameras=2)
    data["simulation"]["head_errors"]["cam0"]["tilt_index_deg"] = 0.4
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.raises(FglocError, match="simulation.head_errors"):
        run_survey(load_rig(tmp_path / "rig.json"), tmp_path / "s", simulate=True, resume=True)


def test_sony_cgi_twin_reads_an_imperfect_heads_encoders():
    """The Sony CGI twin (HTTP) with the scene's frames: the real sony-cgi driver's read-back
    position plus the LED's pixel offset (ideal pinhole conversion) is the imperfect head's
    reading, not the ideal head's."""
    from fgloc.camera.led_search import PinholePixelModel
    from fgloc.drivers.inprocess_rig import build_scene, frame_renderer
    from fgloc.drivers.twins.rig import TwinCamera, TwinRig

    rig = parse_rig(head_rig_data(n_nodes=12, cameras=2), str(EXAMPLE), EXAMPLE.parent)
    scene = build_scene(rig)
    frames = frame_renderer(scene, 0, rig)
    pixels = PinholePixelModel(rig.cameras[0].intrinsics)
    j = next(j for j in range(12) if abs(scene.apparent[0, j, 0]) < math.radians(150))
    model_pan, model_tilt = expected_reading(scene, 0, j)
    scene.lit.add(rig.node_ids[j])
    with TwinRig([TwinCamera("cam0", "http", "SNC-RZ25N", "desk")],
                 render=lambda cid, pan, tilt, zoom: frames(pan, tilt)) as twins:
        head = twins.open_head("cam0")
        head.move_to(model_pan + math.radians(0.3), model_tilt - math.radians(0.2))  # LED off centre
        pan, tilt = head.position()
        frame = np.asarray(head.grab_frame(), dtype=float)
    ys, xs = np.nonzero(frame > 20)
    w = frame[ys, xs]
    read_pan, read_tilt = pixels.pixel_to_pan_tilt(pan, tilt, float(xs @ w / w.sum()), float(ys @ w / w.sum()))
    sigma = rig.sigma
    # (the ideal conversion of the offset misses ~1 % of it: the head's scale error and image roll)
    assert abs(read_pan - model_pan) < 0.1 * sigma and abs(read_tilt - model_tilt) < 0.1 * sigma
    ideal_pan, ideal_tilt = scene.apparent[0, j]
    assert math.hypot(read_pan - ideal_pan, read_tilt - ideal_tilt) > 5 * sigma
