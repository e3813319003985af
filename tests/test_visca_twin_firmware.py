"""The VISCA camera twin behaves like Sony firmware: cancel, Stop, power, drive, relative moves,
variable zoom and the version reply, byte for byte (protocols.md 1.3-1.6), on a controlled clock."""

from __future__ import annotations

import pytest

from fgloc.drivers.ptz_units import EVI_D100
from fgloc.drivers.twins.visca_emulator import ViscaCameraEmulator
from fgloc.drivers.visca.codec import (
    NO_MOVE,
    PAN_RIGHT,
    TILT_UP,
    cmd_cancel,
    cmd_if_clear,
    cmd_pan_tilt_absolute,
    cmd_pan_tilt_drive,
    cmd_pan_tilt_position_inquiry,
    cmd_pan_tilt_relative,
    cmd_pan_tilt_stop,
    cmd_power,
    cmd_power_inquiry,
    cmd_version_inquiry,
    cmd_zoom_direct,
    cmd_zoom_drive,
    cmd_zoom_position_inquiry,
    cmd_zoom_stop,
    decode_pan_tilt,
    decode_version,
    decode_zoom,
    parse_reply,
)

H = bytes.fromhex


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def camera(time_scale: float = 1.0) -> tuple[ViscaCameraEmulator, Clock]:
    clock = Clock()
    return ViscaCameraEmulator(EVI_D100, time_scale=time_scale, clock=clock), clock


def pos(cam: ViscaCameraEmulator) -> tuple[int, int]:
    (_, reply, _), = cam.handle(cmd_pan_tilt_position_inquiry(1))
    return decode_pan_tilt(parse_reply(reply).data)


def zoom(cam: ViscaCameraEmulator) -> int:
    (_, reply, _), = cam.handle(cmd_zoom_position_inquiry(1))
    return decode_zoom(parse_reply(reply).data)


def test_command_builders_match_sonys_command_list() -> None:
    """protocols.md 1.3 and 1.6 byte layouts."""
    assert cmd_power(1, True) == H("81 01 04 00 02 FF") and cmd_power(1, False) == H("81 01 04 00 03 FF")
    assert cmd_power_inquiry(1) == H("81 09 04 00 FF")
    assert cmd_pan_tilt_drive(1, NO_MOVE, TILT_UP, 0x0C, 0x0A) == H("81 01 06 01 0C 0A 03 01 FF")  # Up
    assert cmd_pan_tilt_drive(1, 1, 2) == H("81 01 06 01 18 14 01 02 FF")  # DownLeft
    assert cmd_pan_tilt_relative(1, -1000, 200, 0x18, 0x14) == H("81 01 06 03 18 14 0F 0C 01 08 00 00 0C 08 FF")
    assert cmd_zoom_drive(1, True) == H("81 01 04 07 02 FF") and cmd_zoom_drive(1, False) == H("81 01 04 07 03 FF")
    assert cmd_zoom_drive(1, True, 7) == H("81 01 04 07 27 FF") and cmd_zoom_drive(1, False, 0) == H("81 01 04 07 30 FF")
    with pytest.raises(ValueError):
        cmd_zoom_drive(1, True, 8)
    with pytest.raises(ValueError):
        cmd_pan_tilt_drive(1, 0, 3)


def test_version_reply_is_sonys_ten_byte_layout() -> None:
    cam, _ = camera()
    (_, reply, job), = cam.handle(cmd_version_inquiry(1))
    assert reply == H("90 50 00 01 04 0D 00 01 02 FF") and len(reply) == 10 and job is None
    assert decode_version(parse_reply(reply).data) == (0x0001, 0x040D, 0x0001, 2)


def test_cancel_stops_the_move_and_no_completion_follows() -> None:
    """Sony: ``z0 6y 04 FF`` answers a cancel, and no Completion follows the cancelled command."""
    cam, clock = camera()
    (_, ack, _), (delay, done, job) = cam.handle(cmd_pan_tilt_absolute(1, 1440, 0, 0x0C, 0x0C))
    assert ack == H("90 41 FF") and done == H("90 51 FF") and job is not None
    assert delay == pytest.approx(EVI_D100.move_seconds(1440, 0, 0x0C, 0x0C))  # 100 deg at 22 deg/s: 4.5 s
    clock.t += 1.0
    assert cam.handle(cmd_cancel(1, 1)) == [(0.0, H("90 61 04 FF"), None)]
    assert cam.completion_withdrawn(job)  # the twin drops the scheduled Completion
    here = pos(cam)
    assert here[0] == round(1440 * 1.0 / delay) and here[1] == 0  # stopped where it was after 1 s
    clock.t += 10.0
    assert pos(cam) == here
    assert cam.handle(cmd_cancel(1, 1)) == [(0.0, H("90 61 05 FF"), None)]  # nothing left in socket 1
    # the socket is free again: the next command gets socket 1 and its own Completion
    (_, ack2, _), (_, _, job2) = cam.handle(cmd_pan_tilt_absolute(1, 0, 0, 0x18, 0x14))
    assert ack2 == H("90 41 FF") and not cam.completion_withdrawn(job2)


def test_stop_ends_the_running_move_at_once_never_later() -> None:
    cam, clock = camera()
    (_, _, _), (_, _, job) = cam.handle(cmd_pan_tilt_absolute(1, -1440, 360, 0x08, 0x08))
    clock.t += 0.5
    replies = cam.handle(cmd_pan_tilt_stop(1))
    # the interrupted move's Completion now, then the Stop's own ACK and Completion (socket 1 is free again)
    assert [r for _, r, _ in replies] == [H("90 51 FF"), H("90 41 FF"), H("90 51 FF")]
    assert all(d == 0.0 for d, _, _ in replies)
    assert cam.completion_withdrawn(job)
    stopped = pos(cam)
    clock.t += 60.0
    assert pos(cam) == stopped and stopped != (-1440, 360)


def test_a_new_move_supersedes_the_running_one_and_if_clear_aborts() -> None:
    cam, clock = camera()
    _, (_, _, first) = cam.handle(cmd_pan_tilt_absolute(1, 1000, 0, 0x05, 0x05))
    clock.t += 0.2
    replies = cam.handle(cmd_pan_tilt_absolute(1, -100, 0, 0x18, 0x14))
    assert [r for _, r, _ in replies[:2]] == [H("90 51 FF"), H("90 41 FF")]
    assert cam.completion_withdrawn(first)
    _, _, second = replies[2]
    assert second is not None
    assert cam.handle(cmd_if_clear(1)) == [(0.0, H("90 50 FF"), None)]  # aborts: no Completion at all
    assert cam.completion_withdrawn(second)


def test_two_sockets_and_buffer_full() -> None:
    """A pan-tilt move and a zoom run together (sockets 1 and 2); a third command gets buffer full."""
    cam, _ = camera()
    assert cam.handle(cmd_pan_tilt_absolute(1, 1000, 0, 0x01, 0x01))[0][1] == H("90 41 FF")
    assert cam.handle(cmd_zoom_direct(1, 0x4000))[0][1] == H("90 42 FF")
    assert cam.handle(cmd_power(1, True)) == [(0.0, H("90 60 03 FF"), None)]
    assert set(cam.sockets) == {1, 2}


def test_power_off_on_and_the_power_inquiry() -> None:
    cam, _ = camera(0.0)
    assert [r for _, r, _ in cam.handle(cmd_power_inquiry(1))] == [H("90 50 02 FF")]
    assert [r for _, r, _ in cam.handle(cmd_power(1, False))] == [H("90 41 FF"), H("90 51 FF")]
    assert [r for _, r, _ in cam.handle(cmd_power_inquiry(1))] == [H("90 50 03 FF")]
    # standby: a move is not executable, inquiries are still answered
    assert [r for _, r, _ in cam.handle(cmd_pan_tilt_absolute(1, 100, 0))] == [H("90 61 41 FF")]
    assert pos(cam) == (0, 0)
    assert [r for _, r, _ in cam.handle(cmd_power(1, True))] == [H("90 41 FF"), H("90 51 FF")]
    assert [r for _, r, _ in cam.handle(cmd_power_inquiry(1))] == [H("90 50 02 FF")]
    cam.handle(cmd_pan_tilt_absolute(1, 100, 0))
    assert pos(cam) == (100, 0)


def test_power_on_takes_time_when_the_camera_was_off() -> None:
    clock = Clock()
    cam = ViscaCameraEmulator(EVI_D100, time_scale=1.0, power_on_seconds=3.0, clock=clock)
    cam.handle(cmd_power(1, False))
    _, (delay, done, _) = cam.handle(cmd_power(1, True))
    assert delay == 3.0 and done == H("90 51 FF")


def test_continuous_drive_moves_at_the_speed_table_until_stop_or_limit() -> None:
    """Right at speed 0x0C (22 deg/s on the D100): +22*14.4*0.5 = 158 counts after 0.5 s; Up at 0x0A
    (14 deg/s): +101 counts; the drive command completes at once and the head keeps moving."""
    cam, clock = camera()
    replies = cam.handle(cmd_pan_tilt_drive(1, PAN_RIGHT, TILT_UP, 0x0C, 0x0A))
    assert [(d, r) for d, r, _ in replies] == [(0.0, H("90 41 FF")), (0.0, H("90 51 FF"))]
    clock.t += 0.5
    assert pos(cam) == (round(22.0 * 14.4 * 0.5), round(14.0 * 14.4 * 0.5))
    cam.handle(cmd_pan_tilt_stop(1, 0x0C, 0x0A))
    here = pos(cam)
    clock.t += 5.0
    assert pos(cam) == here
    cam.handle(cmd_pan_tilt_drive(1, 1, 2, 0x18, 0x14))  # DownLeft at full speed runs into the limits
    clock.t += 30.0
    assert pos(cam) == (EVI_D100.pan_min, EVI_D100.tilt_min)
    # quirk 1: an idle axis still needs a legal speed; 00 is a syntax error, as on a BRC-300
    assert cam.handle(H("81 01 06 01 0C 00 02 03 FF")) == [(0.0, H("90 60 02 FF"), None)]
    assert cam.handle(H("81 01 06 01 0C 0A 04 03 FF")) == [(0.0, H("90 60 02 FF"), None)]


def test_relative_move_from_where_the_head_is_and_clamped_at_the_limits() -> None:
    cam, _ = camera(0.0)
    cam.handle(cmd_pan_tilt_absolute(1, 100, 50))
    replies = cam.handle(cmd_pan_tilt_relative(1, 200, -20))
    assert [r for _, r, _ in replies] == [H("90 41 FF"), H("90 51 FF")]
    assert pos(cam) == (300, 30)
    cam.handle(cmd_pan_tilt_relative(1, -4000, 4000))
    assert pos(cam) == (EVI_D100.pan_min, EVI_D100.tilt_max)


def test_variable_zoom_tele_wide_stop() -> None:
    """Twin timing: the optical range (0x4000) in zoom_seconds (2 s) at speed 7, 8/(p+1) times longer at p."""
    cam, clock = camera()
    replies = cam.handle(cmd_zoom_drive(1, True, 7))
    assert [(d, r) for d, r, _ in replies] == [(0.0, H("90 41 FF")), (0.0, H("90 51 FF"))]
    clock.t += 1.0
    assert zoom(cam) == 0x2000
    cam.handle(cmd_zoom_stop(1))
    clock.t += 1.0
    assert zoom(cam) == 0x2000
    cam.handle(cmd_zoom_drive(1, False, 1))  # wide at p = 1: 0x2000 counts in 2 * 0.5 * 4 = 4 s
    clock.t += 2.0
    assert zoom(cam) == 0x1000
    cam.handle(cmd_zoom_drive(1, True))  # standard tele = p 3: 0x4000 counts per 4 s
    clock.t += 1.0
    assert zoom(cam) == 0x1000 + 0x1000
    clock.t += 100.0
    assert zoom(cam) == EVI_D100.zoom_max  # Tele runs into the digital range (protocols.md 1.9)
    assert cam.handle(H("81 01 04 07 28 FF")) == [(0.0, H("90 60 02 FF"), None)]  # p = 8 does not exist
