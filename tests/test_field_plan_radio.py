"""Short rounds in the field plan: a round view priced at K' samples; off, every figure unchanged."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey import field_plan_radio, field_plans
from fgloc.survey.clock import EVI_D100, CameraTiming, RadioTiming, RigTiming
from fgloc.survey.field_plans import coded_survey_time, radio_round_time, radio_separation
from fgloc.survey.view_planner import RadioRound

ROOT = Path(__file__).resolve().parents[1]
TIMING = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=50.0, grab_latency_s=0.04),
                   radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
D10 = math.radians(10.0)
VIEWS = {"a": [(0.0, 0.0), (D10, 0.0)], "b": [(0.0, 0.0)]}
ROUNDS = {"a": [RadioRound(0, [(0.0, 0.0)], (2,)), RadioRound(1, [(D10, 0.0)], (2,))],
          "b": [RadioRound(0, [], ()), RadioRound(1, [(0.0, 0.0)], (3,))]}


def test_names_are_re_exported() -> None:
    for name in ("RadioSeparation", "radio_separation", "radio_round_time", "coded_view_ops"):
        assert getattr(field_plans, name) is getattr(field_plan_radio, name)


def test_short_round_view_priced_at_k_prime_by_hand() -> None:
    ct = coded_survey_time(VIEWS, 100, 20, TIMING, start_broadcasts=3, retry_frames=8, radio_rounds=ROUNDS,
                           pause_broadcasts=6, radio_retry_fraction=0.5, round_frames=7)
    burst = 0.01 + 20 * 0.02 + 0.04  # half a frame, 20 frames, grabber latency
    view = 0.1 + 0.04 + burst
    short = 0.1 + 0.04 + 0.01 + 7 * 0.02 + 0.04  # a round view: K' = 7 samples
    pan10 = EVI_D100.slew_time(D10, 0.0)
    wide = max((0.05 + view) + (pan10 + view), 0.05 + view)
    round0 = 6 * 0.01 + (pan10 + short)
    round1 = 6 * 0.01 + max(pan10 + short + 8 * 0.02, 0.05 + short)  # a's retry continues for 8 samples
    radio = 3 * 0.01 + 0.01
    assert ct.time.total == pytest.approx(radio + wide + round0 + round1)
    assert ct.time.phases["separate"] == pytest.approx(round0 + round1 - 2 * 6 * 0.01)
    # a round view at K' = K is priced as before; retries as new bursts are bursts of K'
    same = coded_survey_time(VIEWS, 100, 20, TIMING, retry_frames=8, radio_rounds=ROUNDS, radio_retry_fraction=0.5,
                             round_frames=20)
    off = coded_survey_time(VIEWS, 100, 20, TIMING, retry_frames=8, radio_rounds=ROUNDS, radio_retry_fraction=0.5)
    assert same.time.total == off.time.total
    t_burst, _, _ = radio_round_time(ROUNDS, {"a": (D10, 0.0), "b": (0.0, 0.0)}, 20, TIMING, 6, 0.5, None, 0, 7)
    b_round1 = 6 * 0.01 + max(pan10 + short + (0.01 + 7 * 0.02 + 0.04), 0.05 + short)
    assert t_burst.total == pytest.approx(6 * 0.01 + pan10 + short + b_round1)


def test_a_read_mote_is_paused_through_the_rounds_and_conflicts_with_nobody() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    px = 1.0 / intr.fx
    # one camera: a chain 0 - 1 - 2, 5 px apart (0 and 2 are 10 px apart), and a lone mote 3
    pt = np.column_stack([np.array([0.0, 5.0, 10.0, 60.0]) * px, np.zeros(4)])
    views = {"a": [(0.0, 0.0)]}
    every = radio_separation(intr, {"a": pt}, views, 8.0, ("a",))
    assert every.classes == 2 and every.colour[0] == every.colour[2] != every.colour[1] and every.colour[3] < 0
    # mote 1 read in the wide view: paused in every round, so 0 and 2 (crowded in the wide view,
    # conflicting with nobody now) share the first class and one round view
    read1 = radio_separation(intr, {"a": pt}, views, 8.0, ("a",), needed={"a": np.array([True, False, True, True])})
    assert read1.classes == 1 and read1.colour[1] < 0 and read1.colour[0] == read1.colour[2] == 0
    assert len(read1.rounds["a"]) == 1 and read1.rounds["a"][0].view_targets == (2,)
    # none of the crowd read: every round as before; all of it read: no round at all
    none_read = radio_separation(intr, {"a": pt}, views, 8.0, ("a",), needed={"a": np.ones(4, bool)})
    assert none_read.colour.tolist() == every.colour.tolist()
    all_read = radio_separation(intr, {"a": pt}, views, 8.0, ("a",), needed={"a": np.array([False] * 3 + [True])})
    assert all_read.classes == 0 and not any(rr.views for rr in all_read.rounds["a"])
    # but a mote another radio camera still needs from a crowd is lit in its class: the conflict stays
    pt_b = np.column_stack([np.array([0.0, 5.0, 30.0, 60.0]) * px, np.zeros(4)])  # 1 crowds 0 in camera b
    both = radio_separation(intr, {"a": pt, "b": pt_b}, {"a": views["a"], "b": views["a"]}, 8.0, ("a", "b"),
                            needed={"a": np.array([True, False, True, True]), "b": np.ones(4, bool)})
    assert both.colour[1] >= 0 and both.colour[0] != both.colour[1] and both.colour[2] != both.colour[1]
    # the bitmap covers the paused crowded mote's address as well as the classes'
    far = radio_separation(intr, {"a": pt}, views, 8.0, ("a",), needed={"a": np.array([True, True, False, True])},
                           addresses=[1, 2, 5000, 6000])
    assert far.colour[2] < 0 and far.pause_broadcasts == 3 * math.ceil(5000 / (8 * 24))


def test_field_time_without_the_lever_is_unchanged_and_the_lever_shortens_rounds(field_time: ModuleType) -> None:
    ft = field_time
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=30000.0 / 1001.0))
    base = ft.Variant(separate="radio")
    off = ft.run(100, 2, timing, 0.1257, variant=base)
    k = off["K"]
    assert k == 3 * off["L"] + 2
    # the lever at K' = K with the wide miss rate is the plan without it, to the last bit
    same = ft.run(100, 2, timing, 0.1257, variant=replace(base, round_frames=(3, 2), round_miss_rate=0.1257))
    assert same["coded"] == off["coded"] and same["phases"] == off["phases"]
    short = ft.run(100, 2, timing, 0.1257, variant=replace(base, round_frames=(1, 2), round_miss_rate=0.1257))
    assert short["round_K"] == off["L"] + 2 and off["round_K"] == 0
    assert short["phases"]["separate"] < off["phases"]["separate"]
    for ph in ("slew", "settle", "position"):  # the wide pass is untouched
        assert short["phases"][ph] == pytest.approx(off["phases"][ph])
    assert ft.round_frames_of("2L+2") == (2, 2) and ft.round_frames_of("L") == (1, 0) and ft.round_frames_of("18") == (0, 18)


@pytest.mark.parametrize("args", [["--round-frames", "5"], ["--round-frames", "xL"], ["--round-miss-rate", "0.1"],
                                  ["--round-frames", "L+2", "--round-miss-rate", "1.5"]])
def test_bad_round_flags_are_one_line_exit_2(args: list[str]) -> None:
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "field_time.py"), "--sizes", "100x2", *args],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "--round-" in res.stderr.strip().splitlines()[-1] and "Traceback" not in res.stderr
