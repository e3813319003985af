"""Short rounds in the field plan: a round view priced at K' samples; off, every figure unchanged."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import pytest

from fgloc.survey import field_plan_radio, field_plans
from fgloc.survey.clock import EVI_D100, CameraTiming, RadioTiming, RigTiming
from fgloc.survey.field_plans import coded_survey_time, radio_round_time
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
