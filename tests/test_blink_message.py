"""The blink-code AM message, byte for byte (layout in drivers/tinyos/blink.py)."""

from __future__ import annotations

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
