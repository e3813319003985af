"""`fgloc survey --simulate` with ``simulation.frames = "rendered"``: the camera pipeline's
renderer (textured background, static bright lights, sensor noise) behind both twins."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fgloc.camera.led_search import brightest_spot
from fgloc.camera.pixel_angles import base_to_pixel, in_image
from fgloc.cli import main
from fgloc.core.geometry import pan_tilt_bearing, world_to_base
from fgloc.drivers.inprocess_rig import build_scene, frame_renderer
from fgloc.files.journal import read_journal
from fgloc.files.rig_config import load_rig, parse_rig
from tests.test_rig_config import EXAMPLE

WIDTH, HEIGHT, FOCAL_PX = 160, 120, 220.0  # small frames, 40 x 30 deg field of view
#: 2-D RMS centroid error of fgloc.camera.led_detection on the renderer's default LED spot (1500 DN,
#: PSF 1.2 px, read noise 1.5 DN, shot 0.05 DN per DN): docs/camera-model.md, "Accuracy".
CENTROID_RMS_PX = 0.070


def rendered_rig(path: Path, twin: str, detection: str, n_nodes: int = 10, seed: int = 1) -> Path:
    """A two-camera rig simulated with rendered frames: desk EVI-D100s in process, or ceiling
    EVI-D70s (pan +-170, tilt -90..+30 deg) behind VISCA pty twins."""
    data = json.loads(EXAMPLE.read_text())
    for cam in data["cameras"]:
        cam["intrinsics"] = {"fx": FOCAL_PX, "fy": FOCAL_PX, "cx": (WIDTH - 1) / 2, "cy": (HEIGHT - 1) / 2,
                             "width": WIDTH, "height": HEIGHT}
        if twin == "visca":
            cam["model"], cam["mounting"] = "EVI-D70", "ceiling"
    data["search"] = {"tilt_min_deg": -85, "tilt_max_deg": 10, "detection": detection}
    if twin == "visca":
        data["search"] |= {"pan_min_deg": -170, "pan_max_deg": 170}
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": seed, "heights": [0.1, 0.12], "occlusion": 0.1, "dead_nodes": ["n003"],
                          "twin": twin, "frames": "rendered"}
    data["retry"] = {"backoff_s": 0.0}
    path.write_text(json.dumps(data))
    return path


def _angle(pan_a: float, tilt_a: float, pan_b: float, tilt_b: float) -> float:
    """Great-circle angle (rad) between two (pan, tilt) bearings."""
    cos = float(pan_tilt_bearing(pan_a, tilt_a) @ pan_tilt_bearing(pan_b, tilt_b))
    return math.acos(min(1.0, max(-1.0, cos)))


@pytest.mark.parametrize("twin", ["inprocess", "visca"])
def test_rendered_survey_with_on_off_detection_reads_every_visible_led(tmp_path, twin):
    """Every unoccluded pair of a working node is observed, the rest recorded, and each reading
    agrees with the bearing at which its frame shows the LED (the pair's ``apparent`` bearing:
    truth plus the scene's fixed N(0, sigma) reading error) to within 5 x the centroid noise.

    Why that tolerance: with the pixel-offset method the reading is the head's read-back (exact:
    it reads its quantised angles back) composed exactly with the LED's pixel, and the renderer
    draws the spot exactly at the apparent bearing; the textured background cancels in the
    on/off difference. What is left is the centroid error of a noisy spot, 0.070 px RMS in 2-D
    (docs/camera-model.md), i.e. 0.070 / f rad of bearing. A 2-D Gaussian error exceeds 5x its
    RMS with probability exp(-25); a wrong blob or a one-pixel mistake is 0.0045 rad here.
    (Measured over seeds 1-3 and both twins: 0.05-0.08 px RMS, at most 0.18 px.)"""
    rig_path = rendered_rig(tmp_path / "rig.json", twin, "on-off")
    out = tmp_path / "out"
    assert main(["survey", "--rig", str(rig_path), "-o", str(out), "--simulate", "--quiet", "--no-live"]) == 0
    rig = load_rig(rig_path)
    scene = build_scene(rig)  # the same scene the survey saw (deterministic by seed)
    state = read_journal(out / "journal.jsonl")

    assert {(c, n) for (n, c, _) in state.observations} == scene.visible_pairs()
    occluded = {(n, c) for i, c in enumerate(rig.camera_ids) for j, n in enumerate(rig.node_ids)
                if not scene.visible[i, j] and n not in scene.dead}
    assert occluded and set(state.not_found) == occluded
    assert set(state.led_failed) == {"n003"}

    tolerance = 5 * CENTROID_RMS_PX / FOCAL_PX  # 1.6e-3 rad
    errors = []
    for (n, c, _), o in state.observations.items():
        i, j = rig.camera_ids.index(c), rig.node_ids.index(n)
        errors.append(_angle(o.pan, o.tilt, *scene.apparent[i, j]))
    assert max(errors) < tolerance, sorted(errors)[-3:]

    # The scene has static bright lights, and some were in the frame an LED was measured in.
    with_light = 0
    for (n, c, _), o in state.observations.items():
        i = rig.camera_ids.index(c)
        light_dirs = world_to_base(scene.cameras[i].rotation, scene.cameras[i].position, scene.lights)
        uv, front = base_to_pixel(rig.cameras[i].intrinsics, light_dirs, o.pan, o.tilt)
        with_light += bool((front & in_image(rig.cameras[i].intrinsics, uv)).any())
    assert with_light >= 1


def test_rendered_survey_resumed_mid_node_repeats_the_same_readings(tmp_path):
    """Frame noise is seeded by the rig's state (camera, head angles, lit LEDs), so a survey
    killed between a node's first reading and its node_done resumes to the very same floats."""
    from fgloc.survey.session import run_survey

    rig = load_rig(rendered_rig(tmp_path / "rig.json", "inprocess", "on-off", n_nodes=6))
    run_survey(rig, tmp_path / "full", simulate=True)
    lines = (tmp_path / "full" / "journal.jsonl").read_bytes().splitlines(keepends=True)
    first_obs = next(k for k, line in enumerate(lines) if b'"observation"' in line and b'"n004"' in line)
    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "journal.jsonl").write_bytes(b"".join(lines[:first_obs + 1]))
    run_survey(rig, tmp_path / "cut", simulate=True, resume=True)
    full, cut = (read_journal(tmp_path / d / "journal.jsonl") for d in ("full", "cut"))
    assert {k: (o.pan, o.tilt) for k, o in cut.observations.items()} == \
        {k: (o.pan, o.tilt) for k, o in full.observations.items()}
    assert cut.duplicates_ignored == 0 and cut.done == set(rig.node_ids)


def test_single_frame_detection_reads_the_textured_background(tmp_path, capsys):
    """The brightest-spot detector of ``"detection": "single"`` suits dark scenes only: on the
    rendered frames the texture alone exceeds its threshold, so it "finds" an LED in a frame with
    no LED lit, and the same survey as above returns readings that are far off and readings of
    occluded pairs (measured at these settings for seeds 1-3: every reading 0.50 rad or more
    from its LED; readings of occluded pairs with seeds 1 and 3). So ``fgloc survey --simulate``
    refuses that rig in one line (exit 2); the survey below is run through the library."""
    rig_path = rendered_rig(tmp_path / "rig.json", "inprocess", "single")
    rig = load_rig(rig_path)
    scene = build_scene(rig)
    frame = frame_renderer(scene, 0, rig)(0.0, math.radians(-20.0))  # no LED lit
    assert brightest_spot(rig.search.threshold)(frame) is not None

    out = tmp_path / "out"
    assert main(["survey", "--rig", str(rig_path), "-o", str(out), "--simulate", "--quiet", "--no-live"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "search.detection: 'single' with simulation.frames 'rendered'" in err
    assert not out.exists() or not (out / "journal.jsonl").exists()

    from fgloc.survey.session import open_simulated, run_survey

    run_survey(rig, out, opened=open_simulated(rig))
    state = read_journal(out / "journal.jsonl")
    errors = [_angle(o.pan, o.tilt, *scene.apparent[rig.camera_ids.index(c), rig.node_ids.index(n)])
              for (n, c, _), o in state.observations.items()]
    assert len(errors) >= 10 and np.mean(np.array(errors) > 0.1) >= 0.9
    seen = {(c, n) for (n, c, _) in state.observations}
    assert seen - scene.visible_pairs()  # a reading where no LED is visible


def test_rendered_frames_show_texture_static_lights_and_the_led_at_its_apparent_bearing():
    """One frame of each kind from the same scene: "spot" is black but for the LED; "rendered"
    has a textured background, and its LED (the on/off difference) sits at the same pixel."""
    data = json.loads(EXAMPLE.read_text())
    data["simulation"] = {"seed": 1, "heights": [0.1, 0.12], "frames": "rendered"}
    rendered = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    del data["simulation"]["frames"]
    spot = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    assert spot.simulation.frames == "spot"
    a, b = build_scene(spot), build_scene(rendered)
    # Same geometry and reading errors either way; only rendered scenes have static lights.
    assert np.array_equal(a.apparent, b.apparent) and np.array_equal(a.visible, b.visible)
    assert len(a.lights) == 0 and len(b.lights) == 3

    j = next(j for j in range(len(b.node_ids)) if b.visible[0, j])
    pan, tilt = b.apparent[0, j]
    intr = rendered.cameras[0].intrinsics
    (u, v), _ = base_to_pixel(intr, pan_tilt_bearing(pan, tilt), pan, tilt)  # the principal point
    draw = {"spot": frame_renderer(a, 0, spot), "rendered": frame_renderer(b, 0, rendered)}
    off = {k: f(pan, tilt).astype(float) for k, f in draw.items()}
    a.lit.add(b.node_ids[j])
    b.lit.add(b.node_ids[j])
    on = {k: f(pan, tilt).astype(float) for k, f in draw.items()}
    assert off["spot"].max() == 0 and off["rendered"].std() > 5  # black vs textured
    for kind in draw:
        diff = on[kind] - off[kind]
        row, col = np.unravel_index(np.argmax(diff), diff.shape)
        assert abs(col - u) <= 1 and abs(row - v) <= 1, kind

    # A static light is in view of camera 0 somewhere in its search range, and it saturates.
    lights = world_to_base(b.cameras[0].rotation, b.cameras[0].position, b.lights)
    k = int(np.argmax(lights[:, 0] ** 2 + lights[:, 1] ** 2))  # any light; aim the head at it
    lpan = math.atan2(lights[k, 1], lights[k, 0])
    ltilt = math.atan2(lights[k, 2], math.hypot(lights[k, 0], lights[k, 1]))
    assert draw["rendered"](lpan, ltilt).max() == 255


def test_bad_frames_value_is_one_line_through_the_cli(tmp_path, capsys):
    data = json.loads(EXAMPLE.read_text())
    data["simulation"]["frames"] = "textured"
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "out"), "--simulate"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{tmp_path / 'rig.json'}: simulation.frames: expected one of spot, rendered, got 'textured'" in err
    assert not (tmp_path / "out" / "journal.jsonl").exists()
