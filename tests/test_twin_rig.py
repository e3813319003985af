"""The byte-level simulated rig: scene hooks see spec angles, LEDs reach the scene, faults recover."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.rig import TwinCamera, TwinRig


def _scene_recorder():
    seen: list[tuple[str, float, float, float]] = []

    def render(camera_id: str, pan: float, tilt: float, zoom: float) -> np.ndarray:
        seen.append((camera_id, pan, tilt, zoom))
        return np.zeros((4, 4), np.uint8)

    return seen, render


@pytest.mark.parametrize("transport,mount", [("serial", "desk"), ("serial", "ceiling"), ("udp", "upright"),
                                             ("http", "desk")])
def test_renderer_gets_the_spec_pose_the_driver_reports(transport, mount) -> None:
    """Whatever the transport and mounting, the scene sees exactly the read-back spec angles."""
    seen, render = _scene_recorder()
    model = "SNC-RZ25N" if transport == "http" else "EVI-D100"
    with TwinRig([TwinCamera("cam0", transport, model, mount)], render=render) as rig:
        head = rig.open_head("cam0")
        assert isinstance(head, PanTiltHead)
        head.move_to(math.radians(-40.0), math.radians(12.0))
        head.grab_frame()
        cam, pan, tilt, _ = seen[-1]
        assert cam == "cam0" and (pan, tilt) == pytest.approx(head.position(), abs=1e-12)
        assert math.degrees(pan) == pytest.approx(-40.0, abs=0.05) and math.degrees(tilt) == pytest.approx(12.0, abs=0.05)


def test_leds_reach_the_scene_and_silent_nodes_fail() -> None:
    lit: dict[int, bool] = {}
    with TwinRig([TwinCamera("cam0")], on_led=lambda n, on: lit.__setitem__(n, on), silent_nodes=[3]) as rig:
        leds = rig.open_leds()
        assert isinstance(leds, LedController)
        assert leds.set_led("n001", True) and lit == {1: True}
        assert leds.set_led("n003", True) is False


def test_two_cameras_with_faults_and_a_disconnect() -> None:
    """5 % drops, 1 % byte noise on every twin, cam1 unplugged once for 0.2 s: all moves and LEDs succeed."""
    faults = FaultConfig(drop_rate=0.05, byte_error_rate=0.01, seed=3)
    cam1 = FaultConfig(drop_rate=0.05, byte_error_rate=0.01, seed=4, disconnect_after=20, reconnect_after=0.2)
    with TwinRig([TwinCamera("cam0"), TwinCamera("cam1", "udp")], faults=faults,
                 camera_faults={"cam1": cam1}) as rig:
        heads = {c: rig.open_head(c) for c in ("cam0", "cam1")}
        heads["cam1"].session.reconnects = 20
        leds = rig.open_leds()
        for k in range(15):
            assert leds.set_led(f"n{k}", True)
            for head in heads.values():
                target = (math.radians(3.0 * k - 20), math.radians(k - 7.0))
                head.move_to(*target)
                assert head.position() == pytest.approx(target, abs=math.radians(0.5 / 14.4))
            assert leds.set_led(f"n{k}", False)
        assert rig.twins["cam1"].faults.counts["disconnect"] == 1


def test_node_ids_map_to_addresses_and_back() -> None:
    lit: set[str] = set()
    with TwinRig([TwinCamera("cam0")], node_ids=["n001", "n002", "n017"], silent_nodes=["n002"],
                 on_led=lambda n, on: (lit.add if on else lit.discard)(n)) as rig:
        leds = rig.open_leds()
        assert leds.set_led("n017", True) and lit == {"n017"}
        assert leds.set_led("n002", True) is False  # silent
        assert leds.set_led("n099", True) is False  # no such mote
        assert leds.set_led("n017", False) and lit == set()
