"""VISCA codec against protocols.md worked examples, and the serial driver against the pty twin."""

from __future__ import annotations

import math

import pytest

from fgloc.drivers.ptz_units import CEILING, EVI_D30, EVI_D100, PanTiltUnits, PositionOutOfRangeError
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.visca_camera import ViscaCameraEmulator, ViscaSerialTwin
from fgloc.drivers.visca.codec import (
    ReplyKind,
    cmd_address_set,
    cmd_cancel,
    cmd_focus_auto,
    cmd_focus_manual,
    cmd_home,
    cmd_if_clear,
    cmd_if_clear_broadcast,
    cmd_pan_tilt_absolute,
    cmd_pan_tilt_position_inquiry,
    cmd_pan_tilt_stop,
    cmd_zoom_direct,
    cmd_zoom_position_inquiry,
    decode_nibbles,
    decode_pan_tilt,
    encode_nibbles,
    parse_reply,
)
from fgloc.drivers.visca.errors import (
    CommandBufferFull,
    CommandNotExecutable,
    ViscaDisconnected,
    ViscaProtocolError,
    ViscaSyntaxError,
    ViscaTimeout,
    error_for,
)
from fgloc.drivers.visca.head import HeadSettings, open_serial_head
from fgloc.drivers.visca.packets import PacketSplitter
from fgloc.drivers.visca.session import Timeouts

H = bytes.fromhex
FAST = Timeouts(ack=0.1, inquiry=0.1, completion_margin=0.3, retries=3)


# ---------------------------------------------------------------- codec: protocols.md 1.7 vectors


def test_encode_vectors() -> None:
    assert encode_nibbles(-1440) == H("0F 0A 06 00")
    assert encode_nibbles(360) == H("00 01 06 08")
    assert encode_nibbles(-1) == H("0F 0F 0F 0F")
    assert decode_nibbles(H("08 00 00 00")) == -32768


def test_absolute_move_packet() -> None:
    assert cmd_pan_tilt_absolute(1, -1000, 200, 0x18, 0x14) == H("81 01 06 02 18 14 0F 0C 01 08 00 00 0C 08 FF")


def test_position_reply_decodes_to_the_d100_limits() -> None:
    reply = parse_reply(H("90 50 0F 0A 06 00 00 01 06 08 FF"))
    assert reply.kind is ReplyKind.INQUIRY and reply.sender == 1
    assert decode_pan_tilt(reply.data) == (-1440, 360)


def test_zoom_direct_and_other_commands() -> None:
    assert cmd_zoom_direct(1, 0x4000) == H("81 01 04 47 04 00 00 00 FF")
    assert cmd_address_set() == H("88 30 01 FF")
    assert cmd_if_clear_broadcast() == H("88 01 00 01 FF")
    assert cmd_if_clear(1) == H("81 01 00 01 FF")
    assert cmd_pan_tilt_position_inquiry(1) == H("81 09 06 12 FF")
    assert cmd_zoom_position_inquiry(1) == H("81 09 04 47 FF")
    assert cmd_home(1) == H("81 01 06 04 FF")
    assert cmd_pan_tilt_stop(1) == H("81 01 06 01 18 14 03 03 FF")
    assert cmd_cancel(1, 2) == H("81 22 FF")
    assert cmd_focus_manual(1) == H("81 01 04 38 03 FF") and cmd_focus_auto(1) == H("81 01 04 38 02 FF")
    assert cmd_pan_tilt_absolute(2, 0, 0)[0] == 0x82


def test_error_replies_map_to_classes() -> None:
    r = parse_reply(H("90 60 02 FF"))
    assert r.kind is ReplyKind.ERROR and (r.socket, r.error_code) == (0, 2)
    assert isinstance(error_for(r.error_code, r.socket), ViscaSyntaxError)
    r = parse_reply(H("90 61 41 FF"))
    exc = error_for(r.error_code, r.socket, "move")
    assert isinstance(exc, CommandNotExecutable) and exc.socket == 1
    assert "not executable" in str(exc) and "socket 1" in str(exc)
    assert isinstance(error_for(0x03, 0), CommandBufferFull)
    assert "0x7A" in str(error_for(0x7A, 0))  # unknown code keeps its number


def test_parse_other_replies_and_reject_garbage() -> None:
    assert parse_reply(H("90 41 FF")).kind is ReplyKind.ACK
    assert parse_reply(H("A0 52 FF")) == parse_reply(H("A0 52 FF"))
    assert parse_reply(H("A0 52 FF")).sender == 2 and parse_reply(H("A0 52 FF")).socket == 2
    assert parse_reply(H("88 30 02 FF")).data == b"\x02"
    assert parse_reply(H("90 38 FF")).kind is ReplyKind.NETWORK_CHANGE
    for bad in ("90 41", "10 41 FF", "91 41 FF", "90 77 FF", "90 41 05 06 FF"):
        with pytest.raises(ViscaProtocolError):
            parse_reply(H(bad))
    with pytest.raises(ViscaProtocolError):
        decode_nibbles(H("0F 1A 06 00"))


@pytest.mark.parametrize("value", [-32768, -1440, -1000, -1, 0, 1, 200, 360, 1440, 32767])
def test_round_trip_signed(value: int) -> None:
    assert decode_nibbles(encode_nibbles(value)) == value


def test_round_trip_five_nibble_pan_and_overflow() -> None:
    assert decode_nibbles(encode_nibbles(-70000, 5)) == -70000
    with pytest.raises(ValueError):
        encode_nibbles(32768)
    with pytest.raises(ValueError):
        cmd_pan_tilt_absolute(1, 0, 0, 0x00, 0x14)  # idle-axis speed 0 is illegal (quirk 1)


def test_splitter_resyncs_on_garbage_and_overlong_packets() -> None:
    s = PacketSplitter()
    out = s.feed(H("00 12 90 41 FF 05") + H("90") + bytes([0x01] * 20) + H("90 51 FF"))
    assert out == [H("90 41 FF"), H("90 51 FF")]
    assert s.dropped_bytes >= 3 and s.dropped_packets == 1
    # a lost terminator does not swallow the next packet
    assert s.feed(H("90 50 0F 0A") + H("90 41 FF")) == [H("90 41 FF")]
    assert s.dropped_packets == 2


# ---------------------------------------------------------------- driver against the pty twin


def _head(twin: ViscaSerialTwin, **kw):
    return open_serial_head(twin.port, timeouts=kw.pop("timeouts", FAST), **kw)


def test_move_and_read_back_in_spec_convention() -> None:
    """Moving to spec (+30 deg, -10 deg) on a desk D100 puts -432/-144 counts on the wire."""
    with ViscaSerialTwin(time_scale=0.002) as twin, _head(twin) as head:
        head.move_to(math.radians(30.0), math.radians(-10.0))
        assert twin.emulator.log[-1] == cmd_pan_tilt_absolute(1, -432, -144, 0x18, 0x14)
        assert head.position_counts() == (-432, -144)
        pan, tilt = head.position()
        assert math.degrees(pan) == pytest.approx(30.0) and math.degrees(tilt) == pytest.approx(-10.0)
        head.set_zoom(0.5)
        assert head.zoom() == pytest.approx(0.5)
        head.home()
        assert head.position_counts() == (0, 0)
        head.stop()
        assert head.session.stats.retries == 0


def _replies_when_returned(twin: ViscaSerialTwin, call) -> list[bytes]:
    """Run ``call``; the replies the twin had sent from its start up to the moment it returned.

    The twin logs each reply just before writing it, so this list holds at least every reply
    the driver read; a reply still scheduled when the call returned is not in it."""
    start = len(twin.sent)
    call()
    return list(twin.sent[start:])


def _assert_returned_after_completion(replies: list[bytes]) -> None:
    """The move's ACK (z0 4y FF) and, after it, the Completion on the same socket (z0 5y FF) were sent."""
    acks = [r for r in replies if len(r) == 3 and r[1] & 0xF0 == 0x40]
    assert len(acks) == 1, replies
    socket = acks[0][1] & 0x0F
    completion = bytes([acks[0][0], 0x50 | socket, 0xFF])
    assert completion in replies, f"returned before the completion was sent: {[r.hex(' ') for r in replies]}"
    assert replies.index(acks[0]) < replies.index(completion)


def test_move_waits_for_completion_of_a_slow_move() -> None:
    """With real-time motion (20.8 deg at 300 deg/s: the Completion follows the ACK by ~0.07 s)
    move_to returns only after the twin sent the Completion, and the read-back is the target."""
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        replies = _replies_when_returned(twin, lambda: head.move_to_counts(300, 0))
        _assert_returned_after_completion(replies)
        assert head.position_counts() == (300, 0)


def test_ceiling_mount_and_d30_model() -> None:
    with ViscaSerialTwin(model=EVI_D30) as twin, _head(twin, units=PanTiltUnits(EVI_D30, CEILING)) as head:
        head.move_to(math.radians(50.0), math.radians(10.0))
        assert head.position_counts() == (440, -120)  # 8.8 and 12 counts/deg, ceiling signs
        with pytest.raises(PositionOutOfRangeError):
            head.move_to(math.radians(120.0), 0.0)


def test_dropped_replies_are_retried() -> None:
    """A dropped ACK, a dropped completion and a dropped inquiry reply all recover by resending."""
    faults = FaultConfig(script=["ok", "ok", "ok", "drop", "ok", "ok", "drop", "ok", "ok", "drop", "ok", "ok"])
    # replies: addr-set, IF_Clear, position, [move ACK dropped] -> resend: ACK, completion,
    # position [dropped] -> resend: position, move ACK, [completion dropped] -> resend ...
    with ViscaSerialTwin(faults=faults) as twin, _head(twin, settings=HeadSettings(confirm_reads=False)) as head:
        head.move_to_counts(100, 50)
        assert head.position_counts() == (100, 50)
        head.move_to_counts(-100, -50)
        assert head.position_counts() == (-100, -50)
        assert twin.faults.counts["drop"] == 3
        assert head.session.stats.retries >= 3


def test_garbled_bytes_are_survived_at_a_high_rate() -> None:
    """30 % of replies garbled (one random byte): every move still lands, every read-back is right."""
    faults = FaultConfig(garble_rate=0.3, seed=7)
    with ViscaSerialTwin(faults=faults) as twin, _head(twin, timeouts=Timeouts(0.05, 0.05, 0.1, retries=8)) as head:
        for k in range(15):
            target = (k * 97 - 700, k * 31 - 200)
            head.move_to_counts(*target)
            assert head.position_counts() == target
        assert twin.faults.counts["garble"] > 5


def test_error_reply_raises_the_mapped_exception() -> None:
    with ViscaSerialTwin(faults=FaultConfig(error_codes=(0x41,))) as twin, _head(twin) as head:
        twin.faults.force_error()
        with pytest.raises(CommandNotExecutable, match="pan-tilt position inquiry"):
            head.position_counts()
        head.position_counts()
        twin.faults.force_error()
        with pytest.raises(CommandNotExecutable, match="pan-tilt absolute move"):
            head.move_to_counts(10, 10)
        head.move_to_counts(10, 10)  # the next one goes through
    with ViscaSerialTwin(faults=FaultConfig(error_rate=1.0, error_codes=(0x03,))) as twin, _head(twin) as head:
        with pytest.raises(CommandBufferFull):  # buffer full is retried, then reported
            head.move_to_counts(10, 10)


def test_illegal_command_gets_syntax_error_from_the_twin() -> None:
    """The twin enforces the D100 tilt speed limit 0x14, like the camera (quirk 2)."""
    with ViscaSerialTwin() as twin, _head(twin) as head:
        with pytest.raises(ViscaSyntaxError):
            head.session.command(cmd_pan_tilt_absolute(1, 0, 0, 0x18, 0x18))


def test_slow_completion_within_budget_and_beyond() -> None:
    with ViscaSerialTwin(faults=FaultConfig(slow_seconds=0.15)) as twin, _head(twin) as head:
        head.position_counts()
        twin.faults.force("ok", "slow")  # the move's ACK, then its completion 0.15 s late
        replies = _replies_when_returned(twin, lambda: head.move_to_counts(5, 5))
        _assert_returned_after_completion(replies)  # waited for the late Completion, no resend
        assert head.session.stats.retries == 0
    with ViscaSerialTwin(faults=FaultConfig(slow_rate=1.0, slow_seconds=5.0)) as twin, \
            _head(twin, timeouts=Timeouts(0.1, 0.1, 0.1, retries=1)) as head:
        with pytest.raises(ViscaTimeout, match="no completion"):
            head.move_to_counts(5, 5)


def test_disconnect_raises_a_clear_error() -> None:
    with ViscaSerialTwin(faults=FaultConfig(disconnect_after=4)) as twin, _head(twin) as head:
        head.move_to_counts(1, 1)  # requests: address set, IF_Clear, position, move
        with pytest.raises(ViscaDisconnected, match="visca"):
            head.position_counts()


def test_disconnect_with_reconnect_recovers() -> None:
    with ViscaSerialTwin(faults=FaultConfig(disconnect_after=3, reconnect_after=0.1)) as twin:
        head = _head(twin)
        head.session.reconnects = 20
        head.move_to_counts(1, 1)
        assert head.position_counts() == (1, 1)
        assert head.session.stats.reconnects >= 1
        head.close()


def test_no_device_is_one_clear_error(tmp_path) -> None:
    with pytest.raises(ViscaDisconnected, match="cannot open serial port"):
        open_serial_head(str(tmp_path / "nothing"))


def test_no_answer_times_out() -> None:
    with ViscaSerialTwin(faults=FaultConfig(drop_rate=1.0)) as twin:
        with pytest.raises(ViscaTimeout, match="Address Set"):
            open_serial_head(twin.port, timeouts=Timeouts(0.05, 0.05, 0.1, retries=1))


def test_grab_frame_uses_the_twin_renderer() -> None:
    import numpy as np

    def render(pose):
        return np.full((4, 6), pose.pan_counts % 256, dtype=np.uint8)

    emulator = ViscaCameraEmulator(EVI_D100, renderer=render)
    with ViscaSerialTwin(emulator) as twin, _head(twin, frames=emulator.frame_source()) as head:
        head.move_to_counts(77, 0)
        assert head.grab_frame().shape == (4, 6) and head.grab_frame()[0, 0] == 77


def test_network_change_triggers_address_set_and_if_clear() -> None:
    """An unsolicited ``90 38 FF`` (protocols.md 1.10 item 6): the head re-initialises before its next command."""
    with ViscaSerialTwin() as twin, _head(twin) as head:
        head.move_to_counts(20, 20)
        n_before = len(twin.emulator.log)
        twin.inject_raw(bytes.fromhex("90 38 FF"))
        head.move_to_counts(30, 30)  # the change is seen while waiting for this move's replies
        assert head.position_counts() == (30, 30)
        after = twin.emulator.log[n_before:]
        assert cmd_address_set() in after and cmd_if_clear(1) in after
        assert head.session.stats.network_changes == 1


def test_line_noise_one_percent_of_bytes() -> None:
    """1 % of all reply bytes corrupted (the issue's acceptance level): 40 moves land exactly, reads agree."""
    with ViscaSerialTwin(faults=FaultConfig(byte_error_rate=0.01, drop_rate=0.05, seed=21)) as twin, \
            _head(twin, timeouts=Timeouts(0.05, 0.05, 0.1, retries=6)) as head:
        for k in range(40):
            target = ((k * 73) % 2800 - 1400, (k * 37) % 700 - 350)
            head.move_to_counts(*target)
            assert head.position_counts() == target
        assert twin.faults.counts["byte_error"] > 5 and twin.faults.counts["drop"] > 5


def test_heads_satisfy_the_rig_protocol() -> None:
    from fgloc.core.hardware import PanTiltHead
    from fgloc.drivers.sony_cgi import SonyCgiClient, SonyCgiHead

    with ViscaSerialTwin() as twin, _head(twin) as head:
        assert isinstance(head, PanTiltHead)
    assert isinstance(SonyCgiHead(SonyCgiClient("http://127.0.0.1:1")), PanTiltHead)


def test_every_d100_count_round_trips_through_the_wire_format() -> None:
    """Full pan and tilt ranges: command encoding -> emulator decoding -> inquiry reply -> driver decoding."""
    emulator = ViscaCameraEmulator(EVI_D100)
    for pan in range(EVI_D100.pan_min, EVI_D100.pan_max + 1):
        tilt = (pan * 7) % 721 - 360
        emulator.handle(cmd_pan_tilt_absolute(1, pan, tilt))
        (_, reply, _), = emulator.handle(cmd_pan_tilt_position_inquiry(1))
        assert decode_pan_tilt(parse_reply(reply).data) == (pan, tilt)
    # one past the limits is refused by the camera with a syntax error
    (_, reply, _), = emulator.handle(cmd_pan_tilt_absolute(1, EVI_D100.pan_max + 1, 0))
    assert parse_reply(reply).error_code == 0x02


def test_at_9600_baud_the_default_timeouts_hold() -> None:
    """With D100 wire time emulated (9600 bit/s, protocols.md 1.5), the default timeouts need no retries."""
    with ViscaSerialTwin(baudrate=9600) as twin, open_serial_head(twin.port) as head:
        for target in [(100, 10), (-1440, -360), (1440, 360)]:
            head.move_to_counts(*target)
            assert head.position_counts() == target
        head.set_autofocus(False)
        assert twin.emulator.autofocus is False
        assert head.session.stats.retries == 0 and head.session.stats.timeouts == 0
