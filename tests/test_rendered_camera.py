"""The rendered PTZ camera twin: its truth agrees with the spec geometry, spots are exact."""

import math

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pan_tilt_to_pixel
from fgloc.core.geometry import base_rotation, project_pan_tilt
from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.core.model import CameraPose
from fgloc.drivers.rendered_camera import LedScene, RenderSettings, SimulatedHead, SimulatedLedController, add_spot

INTR = CameraIntrinsics.from_fov(640, 480, 65.0, k1=-0.2, k2=0.05)
POSE = CameraPose(position=np.array([0.3, -0.2, 2.0]), rotation=base_rotation(0.4, 0.03, -0.02))


def _scene(n=60, seed=0):
    rng = np.random.default_rng(seed)
    pts = {f"n{i:03d}": np.array([rng.uniform(2, 6), rng.uniform(-3, 3), rng.uniform(-1, 1)]) for i in range(n)}
    return LedScene(pts)


@pytest.mark.parametrize("u,v,sigma", [(10.0, 20.0, 1.2), (33.37, 17.81, 0.8), (50.5, 40.25, 2.0)])
def test_spot_is_exact_integrated_gaussian(u, v, sigma):
    """Integrated-Gaussian spots conserve flux and have their centroid exactly at (u, v), the
    property that makes the renderer's pixel truth exact for centroiding."""
    img = np.zeros((80, 90))
    add_spot(img, u, v, 1000.0, sigma)
    jj, ii = np.meshgrid(np.arange(90), np.arange(80))
    assert img.sum() == pytest.approx(1000.0, rel=1e-6)
    assert (img * jj).sum() / img.sum() == pytest.approx(u, abs=1e-6)
    assert (img * ii).sum() / img.sum() == pytest.approx(v, abs=1e-6)


def test_simulated_twins_implement_the_rig_protocols():
    scene = _scene()
    assert isinstance(SimulatedHead(POSE, scene, INTR), PanTiltHead)
    ctl = SimulatedLedController(scene)
    assert isinstance(ctl, LedController)
    assert ctl.set_led("n001", True) and scene.lit == {"n001"}
    assert ctl.set_led("n001", False) and scene.lit == set()
    assert not ctl.set_led("unknown", True)


def test_led_truth_pixels_agree_with_spec_geometry():
    """The renderer places each LED where the spec's (pan, tilt) of the node, seen through the
    head's pan/tilt, projects: both paths must give the same pixel."""
    scene = _scene()
    head = SimulatedHead(POSE, scene, INTR)
    head.move_to(0.1, -0.25)
    visible = head.visible_leds()
    assert len(visible) > 10
    for nid, (u, v) in visible.items():
        pan, tilt = project_pan_tilt(POSE.rotation, POSE.position, scene.positions[nid])
        uv, front = pan_tilt_to_pixel(INTR, pan, tilt, *head.position())
        assert front and np.allclose(uv, (u, v), atol=1e-9)


def test_frames_are_seeded_and_noisy():
    a = SimulatedHead(POSE, _scene(), INTR, seed=5)
    b = SimulatedHead(POSE, _scene(), INTR, seed=5)
    fa1, fb1, fa2 = a.grab_frame(), b.grab_frame(), a.grab_frame()
    assert fa1.dtype == np.uint8 and fa1.shape == (480, 640)
    assert np.array_equal(fa1, fb1)
    diff = fa2.astype(float) - fa1
    s = RenderSettings()
    expected = math.sqrt(2 * (s.read_noise**2 + s.shot_gain * s.background_mean))
    assert 0.7 * expected < diff.std() < 1.3 * expected


def test_lit_led_appears_at_its_truth_pixel():
    scene = _scene()
    head = SimulatedHead(POSE, scene, INTR, seed=1)
    head.move_to(0.1, -0.25)
    nid, (u, v) = next(iter(head.visible_leds(margin=20).items()))
    off = head.grab_frame().astype(float)
    scene.lit.add(nid)
    on = head.grab_frame().astype(float)
    peak = np.unravel_index(np.argmax(on - off), on.shape)
    assert abs(peak[0] - v) <= 1 and abs(peak[1] - u) <= 1


def test_head_quantises_and_reads_back_exactly():
    step = math.radians(1 / 14.4)
    head = SimulatedHead(POSE, _scene(), INTR, angle_step=step)
    head.move_to(0.123456, -0.0654321)
    pan, tilt = head.position()
    assert pan / step == pytest.approx(round(pan / step), abs=1e-9)
    assert abs(pan - 0.123456) <= step / 2 and abs(tilt + 0.0654321) <= step / 2
    head.set_zoom(0.5)
    assert head.zoom() == 0.5 and head.current_intrinsics().fx == pytest.approx(5.5 * INTR.fx)
    head.home()
    assert head.position() == (0.0, 0.0)


def test_background_is_fixed_to_the_world():
    """Turning the head shifts the texture across the image (by ~fx * angle pixels)."""
    head = SimulatedHead(POSE, LedScene({}), INTR)
    cam = head.camera
    bg0 = cam.background(INTR, 0.0, 0.0)
    shift_px = 10
    bg1 = cam.background(INTR, -math.atan(shift_px / INTR.fx), 0.0)  # pan right by 10 px at the centre
    centre0 = bg0[200:280, 300:340]
    centre1 = bg1[200:280, 300 - shift_px : 340 - shift_px]
    assert np.abs(centre0 - centre1).mean() < 0.1 * np.abs(centre0 - bg0[200:280, 300 - shift_px : 340 - shift_px]).mean()


def test_simulated_rig_shares_one_scene_between_cameras():
    """Two cameras of a simulated rig see the same LED switched by one controller, each where
    the spec geometry puts it."""
    from fgloc.drivers.rendered_camera import simulated_rig

    node = np.array([3.0, 1.0, 0.0])
    cams = {"cam0": POSE, "cam1": CameraPose(position=np.array([4.0, -3.0, 1.5]), rotation=base_rotation(1.9))}
    heads, leds = simulated_rig(cams, {"n0": node}, INTR, seed=3)
    assert heads["cam0"].scene is heads["cam1"].scene
    for cam_id, head in heads.items():
        head.move_to(*project_pan_tilt(cams[cam_id].rotation, cams[cam_id].position, node))
        off = head.grab_frame().astype(float)
        leds.set_led("n0", True)
        on = head.grab_frame().astype(float)
        leds.set_led("n0", False)
        v, u = np.unravel_index(np.argmax(on - off), on.shape)
        assert abs(u - INTR.cx) <= 1 and abs(v - INTR.cy) <= 1
    assert not np.array_equal(heads["cam0"].grab_frame(), heads["cam1"].grab_frame())
