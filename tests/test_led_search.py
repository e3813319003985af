"""Pixel <-> pan/tilt conversion, the search grid, and finding an LED on the simulated head."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import (
    LedLocator,
    PinholePixelModel,
    SearchConfig,
    brightest_spot,
    nearest_first,
    search_cells,
)
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.drivers.inprocess_rig import InProcessRig
from fgloc.files.rig_config import load_rig
from tests.test_rig_config import EXAMPLE

K = CameraIntrinsics(fx=100.0, fy=100.0, cx=0.0, cy=0.0, width=320, height=240)


def test_pixel_offset_matches_the_worked_numbers():
    """protocols.md 5.4: at tilt 25 deg, xn = 0.1 to the right is 6.30 deg azimuth, 24.87 deg elevation.

    Right in the image is clockwise seen from above, i.e. negative pan in the spec's convention.
    """
    m = PinholePixelModel(K)
    pan, tilt = m.pixel_to_pan_tilt(0.0, math.radians(25.0), 10.0, 0.0)
    assert math.degrees(pan) == pytest.approx(-6.30, abs=0.005)
    assert math.degrees(tilt) == pytest.approx(24.87, abs=0.005)
    pan0, tilt0 = m.pixel_to_pan_tilt(0.0, 0.0, 10.0, 0.0)
    assert math.degrees(pan0) == pytest.approx(-math.degrees(math.atan(0.1)), abs=1e-9)
    assert tilt0 == pytest.approx(0.0, abs=1e-12)
    # Image y points down: a pixel above the centre is a higher tilt.
    assert m.pixel_to_pan_tilt(0.3, 0.2, 0.0, -5.0)[1] > 0.2


def test_pixel_and_bearing_are_inverse():
    m = PinholePixelModel(K)
    rng = np.random.default_rng(0)
    for _ in range(50):
        head = (rng.uniform(-3, 3), rng.uniform(-1.2, 1.2))
        x, y = rng.uniform(-150, 150), rng.uniform(-110, 110)
        pan, tilt = m.pixel_to_pan_tilt(*head, x, y)
        assert m.bearing_to_pixel(*head, pan_tilt_bearing(pan, tilt)) == pytest.approx((x, y), abs=1e-8)


def test_search_cells_cover_the_range():
    """Every direction in the search range lands inside the frame of some grid cell."""
    search = SearchConfig(tilt_min=math.radians(-80), tilt_max=math.radians(10))
    m = PinholePixelModel(CameraIntrinsics(440, 440, 160, 120, 320, 240))
    cells = search_cells(search, m.field_of_view())
    rng = np.random.default_rng(1)
    for _ in range(300):
        b = pan_tilt_bearing(rng.uniform(-math.pi, math.pi), rng.uniform(search.tilt_min, search.tilt_max))
        hits = [px for c in cells if (px := m.bearing_to_pixel(*c, b)) is not None
                and 0 <= px[0] < 320 and 0 <= px[1] < 240]
        assert hits, b
    ordered = nearest_first(cells, (0.5, -0.5))
    assert sorted(ordered) == sorted(cells) and ordered == nearest_first(cells, (0.5, -0.5))


def test_brightest_spot_is_sub_pixel():
    ys, xs = np.mgrid[0:60, 0:80]
    img = np.round(250 * np.exp(-((xs - 31.3) ** 2 + (ys - 22.7) ** 2) / (2 * 1.5**2))).astype(np.uint8)
    spot = brightest_spot()(img)
    assert spot is not None and spot.x == pytest.approx(31.3, abs=0.02) and spot.y == pytest.approx(22.7, abs=0.02)
    assert brightest_spot()(np.zeros((10, 10), np.uint8)) is None


@pytest.mark.parametrize("method, tol", [("pixel-offset", 5e-5), ("centre", 2.5e-3)])
def test_locator_finds_the_lit_led(method, tol):
    """Against the simulated head: the reading equals the scene's apparent bearing.

    pixel-offset is limited by the centroid of an 8-bit blob (~1e-5 rad); centre by the
    head's 1/14.4 degree step (half a step is 6e-4 rad, plus the centring tolerance).
    """
    from dataclasses import replace

    rig = load_rig(EXAMPLE)
    rig = replace(rig, search=replace(rig.search, method=method, centre_tolerance_px=1.0))
    sim = InProcessRig(rig)
    head = sim.open_head("cam0")
    locator = LedLocator(rig.search, PinholePixelModel(rig.cameras[0].intrinsics))
    checked = 0
    for j, node in enumerate(rig.node_ids[:8]):
        sim.scene.lit = {node}
        found = locator.locate(lambda op: op(head), (0.0, -0.5))
        visible = sim.scene.visible[0, j]  # LED lit directly: dead nodes only matter to set_led
        if not visible:
            assert found is None
            continue
        want = sim.scene.apparent[0, j]
        err = (math.remainder(found[0] - want[0], 2 * math.pi), found[1] - want[1])
        assert abs(err[0]) < tol / max(math.cos(want[1]), 0.05) and abs(err[1]) < tol
        checked += 1
    assert checked >= 5


def test_pinhole_model_agrees_with_the_camera_pipeline():
    """Two independent implementations of the same frames (this module and fgloc.camera.pixel_angles)."""
    from fgloc.camera.pixel_angles import pixel_to_pan_tilt

    k = CameraIntrinsics(fx=440.0, fy=430.0, cx=161.0, cy=118.0, width=320, height=240)
    m = PinholePixelModel(k)
    rng = np.random.default_rng(3)
    for _ in range(30):
        pan, tilt, x, y = rng.uniform(-3, 3), rng.uniform(-1.3, 1.3), rng.uniform(0, 320), rng.uniform(0, 240)
        want = pixel_to_pan_tilt(k, np.array([x, y]), pan, tilt)
        assert m.pixel_to_pan_tilt(pan, tilt, x, y) == pytest.approx((float(want[0]), float(want[1])), abs=1e-12)


def test_moves_are_clamped_to_the_search_range():
    search = SearchConfig(pan_min=math.radians(-170), pan_max=math.radians(170),
                          tilt_min=math.radians(-80), tilt_max=math.radians(20))
    loc = LedLocator(search, PinholePixelModel(CameraIntrinsics(440, 440, 160, 120, 320, 240)))
    assert loc.clamp(math.radians(175), 0.0) == pytest.approx((math.radians(170), 0.0))
    assert loc.clamp(math.radians(-176), -1.5) == pytest.approx((math.radians(-170), math.radians(-80)))
    assert loc.clamp(0.3, 0.1) == pytest.approx((0.3, 0.1))


class _CountingHead:
    """A head that records the operations it is asked for, then performs them."""

    def __init__(self, head):
        self.head, self.ops = head, []

    def move_to(self, pan, tilt):
        self.ops.append("move")
        self.head.move_to(pan, tilt)

    def grab_frame(self):
        self.ops.append("grab")
        return self.head.grab_frame()

    def position(self):
        self.ops.append("position")
        return self.head.position()

    def __getattr__(self, name):
        return getattr(self.head, name)


def _visible_node(sim):
    """A node cam0 sees."""
    return next(n for j, n in enumerate(sim.scene.node_ids) if sim.scene.visible[0, j])


def test_a_look_where_the_head_rests_only_grabs():
    """A search that starts where the head came to rest (its last reading) grabs at once: no
    move, no settle, the same reading. Forgetting the rest (another driver of the head) moves again."""
    rig = load_rig(EXAMPLE)
    sim = InProcessRig(rig)
    head = _CountingHead(sim.open_head("cam0"))
    locator = LedLocator(rig.search, PinholePixelModel(rig.cameras[0].intrinsics))
    near = _visible_node(sim)
    sim.scene.lit = {near}
    j = sim.scene.node_ids.index(near)
    first = locator.locate(lambda op: op(head), tuple(sim.scene.apparent[0, j]))
    assert first is not None and head.ops.count("move") >= 1 and locator.resting_at is not None
    head.ops.clear()
    again = locator.locate(lambda op: op(head), first)
    assert head.ops[0] == "grab" and "move" not in head.ops
    assert again == pytest.approx(first, abs=1e-9)
    assert locator.rests_at(*first)
    locator.resting_at = None
    head.ops.clear()
    assert locator.locate(lambda op: op(head), first) == pytest.approx(first, abs=1e-6)
    assert head.ops[0] == "move"


def test_the_rest_is_within_the_centring_tolerance():
    """``rests_at`` is true within ``centre_tolerance_px`` of the rest and false beyond it."""
    k = CameraIntrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    locator = LedLocator(SearchConfig(centre_tolerance_px=2.0), PinholePixelModel(k))
    assert not locator.rests_at(0.1, 0.0)  # unknown: never
    locator.resting_at = (0.1, 0.0)
    assert locator.rests_at(0.1 + 1.9 / 500.0, 0.0)
    assert not locator.rests_at(0.1 + 2.1 / 500.0, 0.0)
    assert locator.rests_at(0.1, 1.9 / 500.0) and not locator.rests_at(0.1, -2.1 / 500.0)
