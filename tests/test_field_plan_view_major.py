"""View-major radio rounds in the field plan: stations shared across classes, slots priced by hand."""

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
from fgloc.survey.clock import EVI_D100, CameraTiming, RadioTiming, RigTiming
from fgloc.survey.field_plans import (
    coded_survey_time,
    crowd_decoding,
    near_decoding,
    radio_round_time,
    view_major_round_time,
    view_major_slots,
)
from fgloc.survey.view_planner import RadioRound, coverage, plan_radio_rounds, plan_round_stations

ROOT = Path(__file__).resolve().parents[1]
TIMING = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=50.0, grab_latency_s=0.04),
                   radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
D10 = math.radians(10.0)
S0, S1 = (0.0, 0.0), (D10, 0.0)
#: camera a needs classes 0 and 1 at S0 and class 1 at S1; camera b class 1 at S0
ROUNDS = {"a": [RadioRound(0, [S0], (2,)), RadioRound(1, [S0, S1], (1, 2))],
          "b": [RadioRound(0, [], ()), RadioRound(1, [S0], (3,))]}


def test_view_major_slots_priced_by_hand() -> None:
    t, here, updates = view_major_round_time(ROUNDS, {"a": S0, "b": S0}, 20, TIMING, pause_broadcasts=6,
                                             retry_fraction=0.5, retry_frames=8, round_frames=7)
    update = 6 * 0.01
    short = 0.01 + 7 * 0.02 + 0.04  # a burst of K' = 7 samples: half a frame, 7 frames, grabber latency
    arrive = 0.05 + 0.1 + 0.04  # a (zero) slew's command, settle, position read
    pan10 = EVI_D100.slew_time(D10, 0.0)
    # slot 1: class 1 serves both cameras at S0 (both arrive); no retry yet (round(0.5) = 0)
    slot1 = update + arrive + short
    # slot 2: class 0, a stays on S0: one frame period before its burst, then its first retry (8 samples)
    slot2 = update + 0.02 + short + 8 * 0.02
    # slot 3: class 1 again, a moves to S1 (no guard: it settles), second retry (round(1.5) = 2)
    slot3 = update + pan10 + 0.1 + 0.04 + short + 8 * 0.02
    assert t.total == pytest.approx(slot1 + slot2 + slot3)
    assert updates == 3 and t.phases["radio"] == pytest.approx(3 * update)
    assert here == {"a": S1, "b": S0}
    # through the survey price: the order is a parameter, the class-major price differs
    views = {"a": [S0], "b": [S0]}
    by_view = coded_survey_time(views, 10, 20, TIMING, radio_rounds=ROUNDS, pause_broadcasts=6, retry_frames=8,
                                radio_retry_fraction=0.5, round_frames=7, round_order="view")
    by_class = coded_survey_time(views, 10, 20, TIMING, radio_rounds=ROUNDS, pause_broadcasts=6, retry_frames=8,
                                 radio_retry_fraction=0.5, round_frames=7)
    assert by_view.time.phases["separate"] == pytest.approx(t.total - 3 * update)
    assert by_class.time.total != pytest.approx(by_view.time.total)
    assert radio_round_time(ROUNDS, {"a": S0, "b": S0}, 20, TIMING, 6, 0.5, 8, 0, 7, order="view")[0] == t
    with pytest.raises(ValueError, match="round order"):
        radio_round_time(ROUNDS, {"a": S0, "b": S0}, 20, TIMING, order="diagonal")


def test_every_job_recorded_once_and_updates_only_on_a_class_change() -> None:
    rng = np.random.default_rng(3)
    views = [(float(p), 0.0) for p in np.radians([0.0, 20.0, 40.0, 60.0])]
    rounds: dict[str, list[RadioRound]] = {}
    for cam in ("a", "b", "c"):
        rounds[cam] = []
        for c in range(4):
            vs = [views[i] for i in sorted(rng.choice(4, int(rng.integers(0, 4)), replace=False))]
            rounds[cam].append(RadioRound(c, vs, (1,) * len(vs)))
    jobs = {(cam, v, rr.colour) for cam, rs in rounds.items() for rr in rs for v in rr.views}
    slots = view_major_slots(rounds, dict.fromkeys(rounds, views[0]))
    done = [(cam, v, s.colour) for s in slots for cam, v in s.records.items()]
    assert sorted(done) == sorted(jobs)  # every job exactly once
    where: dict[str, tuple[float, float]] = {}
    for s in slots:
        where |= s.moves
        assert s.records and all(where[cam] == v for cam, v in s.records.items())  # recorded where it stands
    for cam in rounds:  # a camera never comes back to a station it left
        visits = [s.moves[cam] for s in slots if cam in s.moves]
        assert len(visits) == len(set(visits)) == len({v for rr in rounds[cam] for v in rr.views})
    changes = sum(a.colour != b for a, b in zip(slots, [-1] + [s.colour for s in slots[:-1]]))
    _, _, updates = view_major_round_time(rounds, dict.fromkeys(rounds, views[0]), 20, TIMING, round_frames=7)
    assert updates == changes


def test_stations_are_shared_across_classes_and_cover_every_class() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    rng = np.random.default_rng(7)
    # a crowded far edge: 60 targets along a wide band of pan at one tilt, in 3 colour classes
    pt = np.column_stack([rng.uniform(-0.8, 0.8, 60), rng.uniform(-0.42, -0.38, 60)])
    colour = np.arange(60) % 3
    colour[::7] = -1  # some in no conflict
    wide = [(-0.5, -0.4), (0.0, -0.4), (0.5, -0.4)]
    targets = np.ones(60, bool)
    rounds = plan_round_stations(intr, pt, wide, colour, targets, start=(0.0, -1.2))
    assert [rr.colour for rr in rounds] == [0, 1, 2]
    stations = {v for rr in rounds for v in rr.views}
    for rr in rounds:
        mine = targets & (colour == rr.colour)
        assert coverage(intr, pt, np.array(rr.views), 12.0).any(axis=0)[mine].all()
        assert sum(rr.view_targets) == int(mine.sum())  # each target counted at one station
    assert len(stations) < sum(len(rr.views) for rr in rounds)  # a station serves several classes
    per_class = plan_radio_rounds(intr, pt, wide, colour, targets, start=(0.0, -1.2))
    assert len(stations) <= len({v for rr in per_class for v in rr.views})


def test_field_time_round_order_best_is_the_cheaper_and_view_major_pays_at_100x2(field_time: ModuleType) -> None:
    ft = field_time
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=30000.0 / 1001.0))
    base = ft.Variant(separate="radio", pair_rate=((6.0, 0.023), (8.0, 0.296), (12.0, 0.449), (math.inf, 0.473)),
                      round_frames=(1, 2), round_miss_rate=0.2552)
    by_class = ft.run(100, 2, timing, 0.1257, variant=base)
    by_view = ft.run(100, 2, timing, 0.1257, variant=replace(base, round_order="view"))
    best = ft.run(100, 2, timing, 0.1257, variant=replace(base, round_order="best"))
    assert by_view["coded"] < by_class["coded"]  # the camera stays on a view: fewer slews
    assert by_view["phases"]["radio"] > by_class["phases"]["radio"]  # ... for more pause updates
    assert best["coded"] == min(by_class["coded"], by_view["coded"])
    assert by_view["radio_cams"].endswith("(view-major)") and "view" not in by_class["radio_cams"]
    for ph in ("slew", "settle", "position", "frames"):  # the wide pass is untouched
        assert by_view["phases"][ph] == pytest.approx(by_class["phases"][ph])


def test_bad_round_order_is_one_line_exit_2() -> None:
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "field_time.py"), "--sizes", "100x2",
                          "--round-order", "diagonal"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "--round-order" in res.stderr.strip().splitlines()[-1] and "Traceback" not in res.stderr


def test_near_decoding_draws_only_the_band_at_its_rate() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    px = 1.0 / intr.fx  # one pixel of pan at tilt 0
    # motes on a line at tilt 0: gaps (px) 3 | 20 | 5 | 20 | 7 | 20 | 5, 6 (a crowd of three) | 20
    pans = np.cumsum([0.0, 3.0, 20.0, 5.0, 20.0, 7.0, 20.0, 5.0, 6.0, 20.0]) * px
    pt = np.column_stack([pans, np.zeros_like(pans)])
    rng = np.random.default_rng(0)
    all_band = near_decoding(intr, pt, 4.0, 8.0, 1.0, rng)
    # the pairs 5 and 7 px apart, alone within 8 px: drawn; the 3 px pair (a crowd) and the three not
    assert np.flatnonzero(all_band).tolist() == [2, 3, 4, 5]
    assert not near_decoding(intr, pt, 4.0, 8.0, 0.0, rng).any()
    by_table = near_decoding(intr, pt, 4.0, 8.0, ((6.0, 1.0), (math.inf, 0.0)), rng)
    assert np.flatnonzero(by_table).tolist() == [2, 3]  # 5 px at rate 1, 7 px at rate 0


def test_crowd_decoding_draws_crowds_alone_by_each_motes_nearest_neighbour() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    px = 1.0 / intr.fx
    # gaps (px): a pair 5 | 20 | a crowd of three 3, 6 | 20 | a crowd of four 5, 5, 7 | 20 | a lone mote
    pans = np.cumsum([0.0, 5.0, 20.0, 3.0, 6.0, 20.0, 5.0, 5.0, 7.0, 20.0]) * px
    pt = np.column_stack([pans, np.zeros_like(pans)])
    read, member = crowd_decoding(intr, pt, 8.0, {3: 1.0, 4: 1.0}, np.random.default_rng(0))
    assert np.flatnonzero(member).tolist() == [2, 3, 4, 5, 6, 7, 8]  # not the pair, not the lone mote
    assert (read == member).all()
    read3, member3 = crowd_decoding(intr, pt, 8.0, {3: 1.0}, np.random.default_rng(0))
    assert np.flatnonzero(member3).tolist() == [2, 3, 4] and (read3 == member3).all()
    # by each mote's nearest neighbour: 3 px for motes 2 and 3, 6 px for mote 4
    table = ((4.0, 0.0), (math.inf, 1.0))
    by_table, _ = crowd_decoding(intr, pt, 8.0, {3: table}, np.random.default_rng(0))
    assert np.flatnonzero(by_table).tolist() == [4]
    # a rate is a rate: over many crowds about that share of the motes is read
    row = np.cumsum(np.tile([20.0, 5.0, 5.0], 40)) * px  # 40 crowds of three per row, 10 rows 20 px apart
    many = np.column_stack([np.tile(row, 10), np.repeat(np.arange(10) * 20.0 * px, 120)])
    half, m = crowd_decoding(intr, many, 8.0, {3: 0.3}, np.random.default_rng(1))
    assert m.all() and abs(half.mean() - 0.3) < 0.04


def test_field_time_crowd_rates_read_crowds_and_replace_their_pair_draws(field_time: ModuleType) -> None:
    ft = field_time
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=30000.0 / 1001.0))
    base = ft.Variant(separate="zoom", separation_px=8.0, near_rate=0.7, pair_rate=1.0)
    none = ft.run(100, 2, timing, 0.1257, variant=base)
    every = ft.run(100, 2, timing, 0.1257, variant=replace(base, crowd_rates=((3, 1.0), (4, 1.0))))
    zero = ft.run(100, 2, timing, 0.1257, variant=replace(base, crowd_rates=((3, 0.0),)))
    assert every["crowd_motes"] > 0 and every["crowd_read"] == every["crowd_motes"] and zero["crowd_read"] == 0
    assert every["coded"] < none["coded"]
    # a 4 px pair inside a crowd of three is the crowd's draw now, not the pair decoder's
    assert zero["pairs_resolved"] <= none["pairs_resolved"] and zero["coded"] >= none["coded"]


def test_field_time_decoder_separation_prices_more_crowds(field_time: ModuleType) -> None:
    ft = field_time
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=30000.0 / 1001.0))
    # zoom refinement: a near mote the blind decoder reads needs no tile
    base = ft.Variant(separate="zoom")
    plan4 = ft.run(100, 2, timing, 0.1257, variant=base)
    none_read = ft.run(100, 2, timing, 0.1257, variant=replace(base, separation_px=8.0))
    some_read = ft.run(100, 2, timing, 0.1257, variant=replace(base, separation_px=8.0, near_rate=0.7))
    assert none_read["crowded"] > plan4["crowded"] and some_read["crowded"] == none_read["crowded"]
    assert none_read["coded"] > some_read["coded"] > plan4["coded"]
    # radio rounds: a read near mote still blinks beside its unread neighbour, so the conflict stays
    radio = ft.Variant(separate="radio", round_frames=(1, 2), round_miss_rate=0.2552, round_order="best")
    r4 = ft.run(100, 2, timing, 0.1257, variant=radio)
    r8 = ft.run(100, 2, timing, 0.1257, variant=replace(radio, separation_px=8.0, near_rate=0.7))
    assert r8["classes"] >= r4["classes"] and r8["round_views"] > r4["round_views"] and r8["coded"] > r4["coded"]


@pytest.mark.parametrize("args", [["--separation", "3"], ["--near-decode", "0.5"],
                                  ["--separation", "8", "--near-decode", "x"], ["--crowd-decode", "3=0.5"],
                                  ["--separation", "8", "--crowd-decode", "2=0.5"],
                                  ["--separation", "8", "--crowd-decode", "3=1.5"]])
def test_bad_separation_flags_are_one_line_exit_2(args: list[str]) -> None:
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "field_time.py"), "--sizes", "100x2", *args],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    last = res.stderr.strip().splitlines()[-1]
    assert ("--separation" in last or "--near-decode" in last or "--crowd-decode" in last)
    assert args[-1] in last and "Traceback" not in res.stderr
