"""The blink-code AM message, byte for byte (layout in drivers/tinyos/blink.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.drivers.tinyos.blink import (
    AM_BLINK_CODE,
    BlinkBroadcast,
    BlinkCommand,
    blink_broadcast,
    blink_command,
    blink_report,
    parse_blink_command,
    parse_blink_report,
    word_for_address,
)
from fgloc.drivers.tinyos.framing import Deframer, data_frame, parse_body
from fgloc.drivers.tinyos.messages import AmPacket


def _crc_xmodem(data: bytes) -> int:  # independent bitwise CRC-16/XMODEM
    crc = 0
    for byte in data:
        for i in range(7, -1, -1):
            bit = (byte >> i) & 1
            top = (crc >> 15) & 1
            crc = (crc << 1) & 0xFFFF
            if top ^ bit:
                crc ^= 0x1021
    return crc


def test_start_packet_bytes() -> None:
    cmd = BlinkCommand(start=True, length=16, code=0x0A5F, bit_period_s=0.03337, cycles=0)
    pkt = blink_command(5, cmd)
    expected = bytes.fromhex("00 0005 0000 0a 22 8b" "01 10 00000a5f 0d09 0000")
    assert pkt.pack() == expected
    body = bytes([0x44, 0x01]) + expected
    crc = _crc_xmodem(body)
    assert crc == 0x4A25
    assert data_frame(pkt, 1) == bytes([0x7E]) + body + bytes([crc & 0xFF, crc >> 8, 0x7E])


def test_round_trip_through_the_wire() -> None:
    cmd = BlinkCommand(start=True, length=20, code=0xABCDE, bit_period_s=0.0664, cycles=300)
    wire = data_frame(blink_command(0x0102, cmd), 7)
    bodies = Deframer().feed(wire)
    assert len(bodies) == 1
    pkt = parse_body(bodies[0]).packet
    assert pkt is not None
    assert pkt.am_type == AM_BLINK_CODE and pkt.dest == 0x0102
    got = parse_blink_command(pkt)
    assert got is not None and got.code == 0xABCDE and got.length == 20 and got.cycles == 300
    assert got.bit_period_s == pytest.approx(0.0664)


def test_stop_and_report() -> None:
    stop = blink_command(9, BlinkCommand(start=False))
    assert stop.payload == bytes(10)
    assert parse_blink_command(stop) == BlinkCommand(start=False)
    rep = blink_report(9, True, 16, 0x0A5F)
    assert rep.pack() == bytes.fromhex("00 ffff 0009 08 22 8c" "0009 01 10 00000a5f")
    assert parse_blink_report(rep) == (9, True, 16, 0x0A5F)


@pytest.mark.parametrize("payload", ["02" + "00" * 9, "01 04 00000001 0d09 0000", "01 10 00010000 0d09 0000",
                                     "01 10 00000a5f 0000 0000", "01 10"])
def test_malformed_payloads_rejected(payload: str) -> None:
    pkt = AmPacket(dest=1, src=0, am_type=AM_BLINK_CODE, payload=bytes.fromhex(payload))
    assert parse_blink_command(pkt) is None


def test_bad_commands_refused() -> None:
    with pytest.raises(ValueError):
        BlinkCommand(True, 16, 1 << 16, 0.033).payload()
    with pytest.raises(ValueError):
        BlinkCommand(True, 16, 5, 1.0).payload()


def test_broadcast_start_bytes() -> None:
    cmd = BlinkBroadcast(length=16, first=1, count=100, bit_period_s=0.01668, cycles=0)
    pkt = blink_broadcast(cmd)
    expected = bytes.fromhex("00 ffff 0000 0a 22 8b" "02 10 0001 0064 0684 0000")
    assert pkt.pack() == expected
    body = bytes([0x44, 0x02]) + expected
    crc = _crc_xmodem(body)
    assert data_frame(pkt, 2) == bytes([0x7E]) + body + bytes([crc & 0xFF, crc >> 8, 0x7E])
    assert crc == 0xDF96  # the worked example in docs/blink-codes.md
    got = parse_blink_command(parse_body(Deframer().feed(data_frame(pkt, 2))[0]).packet)  # type: ignore[arg-type]
    assert got == cmd


def test_broadcast_address_to_word() -> None:
    cmd = BlinkBroadcast(length=20, first=10, count=1000, bit_period_s=0.01668)
    book = code_book(1000)
    assert book.length == 20
    assert word_for_address(book, cmd, 10) == book.words[0]
    assert word_for_address(book, cmd, 1009) == book.words[999]
    assert word_for_address(book, cmd, 9) is None and word_for_address(book, cmd, 1010) is None
    assert word_for_address(code_book(100), cmd, 10) is None  # a 16-bit book: wrong length
    # the firmware's table is the largest book; any survey's book is its prefix
    assert code_book(1000).words == code_book(1112).words[:1000]
    assert code_book(37, length=20).words == book.words[:37]


def test_broadcast_only_valid_to_all_and_stop_broadcast() -> None:
    payload = BlinkBroadcast(16, 1, 100, 0.01668).payload()
    assert parse_blink_command(AmPacket(dest=5, src=0, am_type=AM_BLINK_CODE, payload=payload)) is None
    stop = blink_broadcast(BlinkCommand(start=False))
    assert stop.dest == 0xFFFF and parse_blink_command(stop) == BlinkCommand(start=False)
    with pytest.raises(ValueError):
        blink_broadcast(BlinkCommand(True, 16, 5, 0.033))
    for bad in ("02 04 0001 0064 0684 0000", "02 10 0001 0000 0684 0000", "02 10 ffff 0002 0684 0000",
                "02 10 0001 0064 0000 0000"):
        pkt = AmPacket(dest=0xFFFF, src=0, am_type=AM_BLINK_CODE, payload=bytes.fromhex(bad))
        assert parse_blink_command(pkt) is None


def test_pause_packet_bytes_and_round_trip() -> None:
    from fgloc.drivers.tinyos.blink import BlinkPause

    cmd = BlinkPause(first=1, nbytes=2, paused=frozenset({3, 10}))
    pkt = blink_broadcast(cmd)
    expected = bytes.fromhex("00 ffff 0000 06 22 8b" "04 02 0001 20 40")
    assert pkt.pack() == expected
    body = bytes([0x44, 0x03]) + expected
    crc = _crc_xmodem(body)
    assert data_frame(pkt, 3) == bytes([0x7E]) + body + bytes([crc & 0xFF, crc >> 8, 0x7E])
    assert crc == 0xB273  # the worked example in docs/blink-codes.md
    got = parse_blink_command(parse_body(Deframer().feed(data_frame(pkt, 3))[0]).packet)  # type: ignore[arg-type]
    assert got == cmd
    # every old payload still parses as before
    assert parse_blink_command(blink_broadcast(BlinkBroadcast(16, 1, 100, 0.01668))) == BlinkBroadcast(
        16, 1, 100, 0.01668)
    assert parse_blink_command(blink_broadcast(BlinkCommand(start=False))) == BlinkCommand(start=False)


def test_pause_malformed_and_unicast_refused() -> None:
    from fgloc.drivers.tinyos.blink import BlinkPause

    payload = BlinkPause(1, 1, frozenset({2})).payload()
    assert parse_blink_command(AmPacket(dest=5, src=0, am_type=AM_BLINK_CODE, payload=payload)) is None
    for bad in ("04 02 0001 20", "04 00 0001", "04 19 0001" + "00" * 25, "04 01 fffe 80"):
        pkt = AmPacket(dest=0xFFFF, src=0, am_type=AM_BLINK_CODE, payload=bytes.fromhex(bad))
        assert parse_blink_command(pkt) is None, bad
    with pytest.raises(ValueError):
        BlinkPause(1, 1, frozenset({9})).payload()  # outside the 8 addresses
    with pytest.raises(ValueError):
        BlinkPause(1, 25).payload()


def test_pause_packets_cover_a_range() -> None:
    from fgloc.drivers.tinyos.blink import BlinkPause, pause_packets

    rng = np.random.default_rng(4)
    paused = {int(a) for a in rng.choice(np.arange(10, 1010), 300, replace=False)}
    packets = pause_packets(paused, range(10, 1010))
    assert len(packets) == 6  # 192 addresses per packet
    got = set().union(*(BlinkPause.from_payload(p.payload()).paused for p in packets))
    assert got == paused
    covered = [a for p in packets for a in range(p.first, p.first + 8 * p.nbytes)]
    assert set(range(10, 1010)) <= set(covered)


def test_twin_pauses_and_resumes_the_led_field() -> None:
    from fgloc.camera.intrinsics import CameraIntrinsics
    from fgloc.camera.pixel_angles import pixel_to_pan_tilt
    from fgloc.core.geometry import pan_tilt_bearing
    from fgloc.core.model import CameraPose
    from fgloc.drivers.blink_frames import BlinkRenderConfig, motes_lit, render_view
    from fgloc.drivers.rendered_camera import LedScene, RenderedCamera
    from fgloc.drivers.tinyos.blink import BlinkPause
    from fgloc.drivers.twins.base_station import MoteFieldEmulator

    field = MoteFieldEmulator(nodes={1, 2, 3})
    assert len(field.handle(blink_broadcast(BlinkBroadcast(16, 1, 3, 0.03337)))) == 3
    assert field.handle(blink_broadcast(BlinkPause(1, 1, frozenset({2})))) == []  # no reports
    assert set(field.blink.lit()) == {1, 3} and 2 in field.blink.running
    intr = CameraIntrinsics.from_fov(320, 240, 50.0)
    uv = np.array([[80.0, 120.0], [160.0, 120.0], [240.0, 120.0]])
    p, t = pixel_to_pan_tilt(intr, uv, 0.0, 0.0)
    positions = {a: pan_tilt_bearing(p[a - 1], t[a - 1]) * 10.0 for a in (1, 2, 3)}
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    cfg = BlinkRenderConfig(drop_rate=0.0)

    def peak(lit: dict[int, tuple[int, int]], k: int) -> float:
        rng = np.random.default_rng(1)
        frames = render_view(cam, intr, 0.0, 0.0, motes_lit(lit, positions, 0.03337, rng), 40, rng, cfg)
        u, v = int(uv[k, 0]), int(uv[k, 1])
        return max(float(f[v - 2:v + 3, u - 2:u + 3].max()) for _, f in frames)

    dark = peak({}, 1)  # background only
    paused = field.blink.lit()
    assert peak(paused, 1) == pytest.approx(dark, abs=1e-9)  # the paused mote is dark in every frame
    assert peak(paused, 0) > dark + 100 and peak(paused, 2) > dark + 100
    field.handle(blink_broadcast(BlinkPause(1, 1)))  # resume: its bit 0
    assert set(field.blink.lit()) == {1, 2, 3}
    assert peak(field.blink.lit(), 1) > dark + 100
    field.handle(blink_broadcast(BlinkPause(1, 1, frozenset({1}))))
    field.handle(blink_command(1, BlinkCommand(True, 16, 0x0A5F, 0.03337)))  # a unicast start clears the pause
    assert 1 in field.blink.lit()
