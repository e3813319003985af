"""Survey clock arithmetic against hand-computed cases."""

from __future__ import annotations

import math

import pytest

from fgloc.survey.clock import (
    EVI_D100,
    AxisModel,
    CameraTiming,
    FieldTime,
    Frames,
    PositionRead,
    Radio,
    RadioTiming,
    RigTiming,
    Settle,
    Slew,
    parallel,
    price,
)


def test_trapezoid_long_move_reaches_top_speed() -> None:
    ax = AxisModel(max_speed=2.0, accel=4.0)  # ramp 0.5 s covering 0.5 rad each way
    assert ax.move_time(3.0) == pytest.approx(3.0 / 2.0 + 2.0 / 4.0)  # 1.5 cruise-equivalent + 0.5


def test_triangle_short_move() -> None:
    ax = AxisModel(max_speed=2.0, accel=4.0)
    assert ax.move_time(0.25) == pytest.approx(2.0 * math.sqrt(0.25 / 4.0))  # 0.5 s
    assert ax.move_time(-0.25) == ax.move_time(0.25)
    assert ax.move_time(0.0) == 0.0
    # continuous at the switch-over distance v^2/a = 1 rad: both formulas give 1.0 s
    assert ax.move_time(1.0) == pytest.approx(1.0)


def test_d100_full_pan_sweep() -> None:
    # 200 deg at 300 deg/s with a 0.2 s ramp: 200/300 + 0.2 = 0.8667 s, plus 0.05 s command
    t = EVI_D100.slew_time(math.radians(200.0), 0.0)
    assert t == pytest.approx(200.0 / 300.0 + 0.2 + 0.05)
    # tilt is the slower axis: 50 deg at 125 deg/s: 0.4 + 0.2 = 0.6 s > pan 10 deg (triangle)
    assert EVI_D100.slew_time(math.radians(10.0), math.radians(50.0)) == pytest.approx(0.6 + 0.05)


def test_price_phases_and_parallel() -> None:
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=25.0, grab_latency_s=0.04),
                       radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
    ops = [Slew(math.radians(200.0), 0.0), Settle(), PositionRead(), Frames(10), Radio(unicast=2, broadcast=1)]
    ft = price(ops, timing)
    assert ft.phases["slew"] == pytest.approx(200.0 / 300.0 + 0.2 + 0.05)
    assert ft.phases["settle"] == pytest.approx(0.1)
    assert ft.phases["position"] == pytest.approx(0.04)
    assert ft.phases["frames"] == pytest.approx(0.02 + 10 * 0.04 + 0.04)  # half period + 10 + latency
    assert ft.phases["radio"] == pytest.approx(0.07)
    assert ft.total == pytest.approx(sum(ft.phases.values()))
    a, b = FieldTime({"slew": 1.0}), FieldTime({"frames": 2.5})
    assert parallel([a, b]) is b
    assert (a + b).total == pytest.approx(3.5)
    assert price([Frames(0)], timing).total == 0.0


def test_field_rate_and_coded_plan_by_hand() -> None:
    from fgloc.survey.field_plans import coded_survey_time
    from fgloc.survey.view_planner import RefinePass

    cam = CameraTiming(frame_rate_hz=25.0, grab_latency_s=0.04).at_field_rate()
    assert cam.frame_rate_hz == 50.0 and cam.grab_latency_s == 0.04
    assert cam.burst_time(10) == pytest.approx(0.01 + 0.2 + 0.04)
    timing = RigTiming(head=EVI_D100, camera=cam, radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
    d10 = math.radians(10.0)
    views = {"a": [(0.0, 0.0), (d10, 0.0)], "b": [(0.0, 0.0)]}
    refine = {"a": [RefinePass(0.25, [(d10, -d10)], 3), RefinePass(1.0, [(d10, -2 * d10)], 2)]}
    ct = coded_survey_time(views, 100, 10, timing, refine=refine, broadcast_start=True, start_broadcasts=3)
    burst = 0.25
    view0 = 0.1 + 0.04 + burst  # no move to the first view: settle, read, frames (slew = command only)
    move10_pan = EVI_D100.slew_time(d10, 0.0)
    move10_tilt = EVI_D100.slew_time(0.0, d10)
    wide = (0.05 + view0) + (move10_pan + view0)
    zoom = (0.25 + 0.75 + 1.0) * 2.0  # in to 0.25, on to 1.0, back out: 2 s for the full range
    fine = 2 * (move10_tilt + view0)
    assert ct.time.total == pytest.approx(wide + zoom + fine + 3 * 0.01 + 0.01)  # 3 start + 1 stop broadcasts
    assert ct.refinements == 2
    unicast = coded_survey_time(views, 100, 10, timing, broadcast_start=False)
    assert unicast.time.phases["radio"] == pytest.approx(100 * 0.03 + 0.01)


def test_continuous_frames_retries_extensions_and_resync_by_hand() -> None:
    from fgloc.survey.field_plans import coded_survey_time
    from fgloc.survey.view_planner import RefinePass

    cam = CameraTiming(frame_rate_hz=50.0, grab_latency_s=0.04)
    timing = RigTiming(head=EVI_D100, camera=cam, radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
    assert price([Frames(10, continuous=True)], timing).total == pytest.approx(0.2)  # no wait, no latency
    d10 = math.radians(10.0)
    views = {"a": [(0.0, 0.0), (d10, 0.0), (2 * d10, 0.0), (3 * d10, 0.0)]}
    refine = {"a": [RefinePass(0.5, [(3 * d10, -d10), (3 * d10, -2 * d10)], 4)]}
    ct = coded_survey_time(views, 100, 20, timing, retry_fraction=0.5, refine=refine, start_broadcasts=3,
                           extend_frames=10, retry_frames=8, refine_retry_fraction=0.5, zoom_out=False,
                           resync_s=4.0)
    burst = 0.01 + 30 * 0.02 + 0.04  # K + extension in one burst
    view = 0.1 + 0.04 + burst
    wide = (0.05 + view) + 3 * (EVI_D100.slew_time(d10, 0.0) + view) + 2 * 8 * 0.02  # 2 of 4 retried
    fine = 0.5 * 2.0 + 2 * (EVI_D100.slew_time(0.0, d10) + view) + 1 * 8 * 0.02  # zoom in, no zoom out
    lane = wide + fine
    resyncs = math.ceil(lane / 4.0) - 1
    assert ct.time.total == pytest.approx(lane + (3 + 1 + 3 * resyncs) * 0.01)
    # the phases add up to the total, refinement under 'centring'
    assert sum(ct.time.phases.values()) == pytest.approx(ct.time.total)
    assert ct.time.phases["centring"] == pytest.approx(fine)
    # the old defaults: burst retries of K frames for wide views only, and the zoom back out
    old = coded_survey_time(views, 100, 20, timing, retry_fraction=0.5, refine=refine, start_broadcasts=3)
    burst0 = 0.01 + 20 * 0.02 + 0.04
    view0 = 0.1 + 0.04 + burst0
    wide0 = (0.05 + view0) + 3 * (EVI_D100.slew_time(d10, 0.0) + view0) + 2 * burst0
    fine0 = 0.5 * 2.0 * 2 + 2 * (EVI_D100.slew_time(0.0, d10) + view0)
    assert old.time.total == pytest.approx(wide0 + fine0 + 4 * 0.01)


def test_radio_separation_plan_by_hand() -> None:
    from fgloc.survey.field_plans import coded_survey_time
    from fgloc.survey.view_planner import RadioRound, RefinePass

    cam = CameraTiming(frame_rate_hz=50.0, grab_latency_s=0.04)
    timing = RigTiming(head=EVI_D100, camera=cam, radio=RadioTiming(unicast_s=0.03, broadcast_s=0.01))
    d10 = math.radians(10.0)
    views = {"a": [(0.0, 0.0), (d10, 0.0)], "b": [(0.0, 0.0)]}
    # class 0: a re-records its first view, b nothing; class 1: a its second view, b its only view
    rounds = {"a": [RadioRound(0, [(0.0, 0.0)], (2,)), RadioRound(1, [(d10, 0.0)], (2,))],
              "b": [RadioRound(0, [], ()), RadioRound(1, [(0.0, 0.0)], (3,))]}
    refine = {"b": [RefinePass(0.5, [(0.0, -d10)], 1)]}  # a mote beside a lamp, zoomed in b
    ct = coded_survey_time(views, 100, 20, timing, refine=refine, start_broadcasts=3, retry_frames=8,
                           zoom_out=False, radio_rounds=rounds, pause_broadcasts=6, radio_retry_fraction=0.5)
    burst = 0.01 + 20 * 0.02 + 0.04
    view = 0.1 + 0.04 + burst  # settle, read, frames
    pan10 = EVI_D100.slew_time(d10, 0.0)
    wide = max((0.05 + view) + (pan10 + view), 0.05 + view)  # a is the slower lane
    # round 0: pause update (6 broadcasts), a slews back 10 deg and records; b idle
    round0 = 6 * 0.01 + (pan10 + view)
    # round 1: a slews 10 deg and records, b records without moving (command only); a's
    # retries: round(0.5 x 2) = 1 of its two views, placed on the running count (0 after
    # round 0, 1 after round 1); b: round(0.5 x 1) = 0 (round half to even)
    a1 = pan10 + view + 8 * 0.02
    b1 = 0.05 + view
    round1 = 6 * 0.01 + max(a1, b1)
    resume = 6 * 0.01  # one resume update before the zoom refinement
    fine = 0.5 * 2.0 + EVI_D100.slew_time(0.0, d10) + view  # b zooms in from its last round view
    radio = 3 * 0.01 + 0.01  # start (three broadcasts) and stop
    assert ct.time.total == pytest.approx(radio + wide + round0 + round1 + resume + fine)
    assert sum(ct.time.phases.values()) == pytest.approx(ct.time.total)
    assert ct.time.phases["separate"] == pytest.approx(round0 + round1 - 2 * 6 * 0.01)
    assert ct.time.phases["radio"] == pytest.approx(radio + 3 * 6 * 0.01)
    # no refinement after the rounds: no resume update
    bare = coded_survey_time(views, 100, 20, timing, start_broadcasts=3, retry_frames=8, radio_rounds=rounds,
                             pause_broadcasts=6, radio_retry_fraction=0.5)
    assert bare.time.total == pytest.approx(radio + wide + round0 + round1)
    # rounds without views change nothing: the plan without radio separation
    empty = {"a": [RadioRound(0, [], ())]}
    assert coded_survey_time(views, 100, 20, timing, radio_rounds=empty).time.total == pytest.approx(
        coded_survey_time(views, 100, 20, timing).time.total)


def test_a_slew_between_two_heads_takes_pan_the_short_way_round() -> None:
    from fgloc.survey.clock import Slew

    s = Slew.between((math.radians(170), 0.1), (math.radians(-170), -0.2))
    assert s.dpan == pytest.approx(math.radians(20)) and s.dtilt == pytest.approx(-0.3)
    assert Slew.between((0.3, 0.0), (-0.2, 0.4)) == Slew(-0.5, 0.4)


def test_a_zoom_during_a_move_costs_only_what_outlasts_the_move_on_a_head_that_can() -> None:
    """EVI-D100 (two VISCA sockets): a Slew with ``dzoom`` lasts max(axes, zoom) + one command
    round trip; the move is reported as 'slew', the zoom's excess as 'zoom'. A head without
    ``zoom_while_moving`` refuses such a Slew (its zoom must be priced as a Zoom)."""
    from dataclasses import replace

    from fgloc.survey.clock import SNC_RZ25N, Zoom, op_time

    timing = RigTiming()
    short, long_ = Slew(math.radians(10.0), 0.0, dzoom=0.78), Slew(math.radians(170.0), 0.0, dzoom=0.22)
    pan_short = 2.0 * math.sqrt(math.radians(10.0) / (math.radians(300.0) / 0.2))  # triangle: 0.163 s
    pan_long = math.radians(170.0) / math.radians(300.0) + 0.2  # trapezoid: 0.767 s
    # the zoom (1.56 s) outlasts the short move; the long move outlasts its zoom (0.44 s)
    assert op_time(short, timing) == pytest.approx(1.56 + 0.05)
    assert op_time(long_, timing) == pytest.approx(pan_long + 0.05)
    ft = price([short, long_], timing)
    assert ft.phases["slew"] == pytest.approx(pan_short + pan_long + 2 * 0.05)
    assert ft.phases["zoom"] == pytest.approx(1.56 - pan_short)
    # apart, the same moves cost the zoom travel in full
    apart = price([Zoom(0.78), Slew(short.dpan, 0.0), Zoom(0.22), Slew(long_.dpan, 0.0)], timing)
    assert apart.total - ft.total == pytest.approx(pan_short + 0.44)
    assert op_time(Slew(0.1, 0.0, dzoom=0.0), replace(timing, head=SNC_RZ25N)) > 0  # no zoom: any head
    with pytest.raises(ValueError, match="does not zoom while it moves"):
        price([short], replace(timing, head=SNC_RZ25N))


def test_a_clocked_head_moves_and_zooms_only_where_its_head_can_priced_as_one_move_inside_a_node() -> None:
    """``ClockedHeadProxy``: ``move_and_zoom`` exists only when the wrapped head has it (the coded
    survey detects the capability by it); outside a priced node it only tracks where the head is;
    inside, it records one Slew carrying the zoom travel, then the settle."""
    from fgloc.survey.coded_clock import ClockedHeadProxy, ClockSink

    class Plain:
        def __init__(self) -> None:
            self.at, self.zoom_now, self.calls = (0.0, 0.0), 0.0, []

        def move_to(self, pan: float, tilt: float) -> None:
            self.at = (pan, tilt)

        def zoom(self) -> float:
            return self.zoom_now

    class Zooming(Plain):
        def move_and_zoom(self, pan: float, tilt: float, zoom: float) -> None:
            self.calls.append((pan, tilt, zoom))
            self.at, self.zoom_now = (pan, tilt), zoom

    sink = ClockSink(["cam0"])
    assert not hasattr(ClockedHeadProxy(Plain(), "cam0", sink), "move_and_zoom")  # type: ignore[arg-type]
    head = Zooming()
    proxy = ClockedHeadProxy(head, "cam0", sink)  # type: ignore[arg-type]
    proxy.move_and_zoom(0.1, 0.0, 0.5)
    assert sink.take() == {"cam0": []} and head.calls == [(0.1, 0.0, 0.5)]
    sink.active = True
    proxy.move_and_zoom(0.3, -0.1, 0.25)
    assert sink.take()["cam0"] == [Slew.between((0.1, 0.0), (0.3, -0.1), 0.25 - 0.5), Settle()]
    assert head.at == (0.3, -0.1) and sink.where["cam0"] == (0.3, -0.1)
