"""TinyOS 2.x serial protocol against protocols.md 3.4/3.7/3.9, and MoteNetwork against the twins."""

from __future__ import annotations

import random
import time

import pytest

from fgloc.core.hardware import LedController
from fgloc.drivers.tinyos.errors import MoteDisconnected, MoteError, MoteProtocolError, MoteTimeout
from fgloc.drivers.tinyos.forwarder import SerialForwarderLink
from fgloc.drivers.tinyos.framing import (
    PROTO_ACK,
    PROTO_PACKET_ACK,
    Deframer,
    ack_frame,
    crc16,
    data_frame,
    frame,
    parse_body,
)
from fgloc.drivers.tinyos.messages import (
    AM_LED_COMMAND,
    AmPacket,
    led_command,
    led_report,
    node_address,
    parse_led_report,
)
from fgloc.drivers.tinyos.network import MoteNetwork, open_mote_network
from fgloc.drivers.tinyos.serial_link import SerialMoteLink
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, MoteFieldEmulator, SerialForwarderTwin
from fgloc.drivers.twins.faults import FaultConfig

H = bytes.fromhex
EX1 = AmPacket(dest=0x0005, src=0x0000, am_type=0x89, payload=H("01 07"), group=0x22)


# ------------------------------------------------------------------ codec vectors (protocols.md 3.3-3.7)


def test_crc_check_value_and_example_crcs() -> None:
    assert crc16(b"123456789") == 0x31C3
    assert crc16(H("44 01 00 00 05 00 00 02 22 89 01 07")) == 0x38DB
    assert crc16(H("43 01")) == 0x48BE
    assert crc16(H("45 00 FF FF 00 05 03 22 8A 00 05 01")) == 0x93EF


def test_example_1_acked_packet() -> None:
    assert data_frame(EX1, seq=1) == H("7E 44 01 00 00 05 00 00 02 22 89 01 07 DB 38 7E")
    assert led_command(5, True) == EX1  # the LED-on command is exactly worked example 1's packet


def test_example_2_ack() -> None:
    assert ack_frame(1) == H("7E 43 01 BE 48 7E")


def test_example_3_mote_report() -> None:
    report = led_report(5, True)
    assert data_frame(report, None) == H("7E 45 00 FF FF 00 05 03 22 8A 00 05 01 EF 93 7E")
    assert parse_led_report(report) == (5, True)


def test_example_4_escaping() -> None:
    p = AmPacket(dest=0xBEEF, src=0, am_type=6, payload=H("01 02 03 04 05"), group=0x7D)
    wire = H("7E 45 00 BE EF 00 00 05 7D 5D 06 01 02 03 04 05 B6 8B 7E")
    assert data_frame(p, None) == wire
    bodies = Deframer().feed(wire)
    assert len(bodies) == 1 and parse_body(bodies[0]).packet == p


def test_serialforwarder_packet_bytes() -> None:
    """protocols.md 3.7: example 1 travels over SF as 0A 00 00 05 00 00 02 22 89 01 07."""
    data = EX1.pack()
    assert bytes([len(data)]) + data == H("0A 00 00 05 00 00 02 22 89 01 07")


def test_round_trip_all_frames_through_the_deframer() -> None:
    frames = [data_frame(EX1, 1), ack_frame(1), data_frame(led_report(5, True), None),
              data_frame(AmPacket(0xBEEF, 0, 6, H("01 02 03 04 05"), 0x7D), None)]
    d = Deframer()
    bodies = d.feed(b"".join(frames))
    parsed = [parse_body(b) for b in bodies]
    assert [f.protocol for f in parsed] == [PROTO_PACKET_ACK, PROTO_ACK, 0x45, 0x45]
    assert parsed[0].seq == 1 and parsed[0].packet == EX1 and parsed[1].seq == 1
    assert d.stats.dropped == 0


def test_crc_bytes_that_need_escaping() -> None:
    """Search a payload whose CRC low or high byte is 7E/7D: escaping must cover the CRC too."""
    for k in range(5000):
        p = AmPacket(1, 0, 0x89, k.to_bytes(2, "big"))
        body = bytes([0x45]) + p.pack()
        c = crc16(body)
        if (c & 0xFF) in (0x7E, 0x7D) or (c >> 8) in (0x7E, 0x7D):
            wire = data_frame(p, None)
            assert wire.count(0x7E) == 2  # only the flags
            assert parse_body(Deframer().feed(wire)[0]).packet == p
            return
    pytest.fail("no CRC needing an escape found")


# ------------------------------------------------------------------ parser cases (protocols.md 3.9)


def test_leading_garbage_and_double_flags_resync() -> None:
    d = Deframer()
    bodies = d.feed(H("12 34 56 7E 7E") + data_frame(EX1, 1))
    assert len(bodies) == 1 and parse_body(bodies[0]).packet == EX1


def test_bad_crc_dropped_next_frame_accepted() -> None:
    bad = bytearray(data_frame(EX1, 1))
    bad[5] ^= 0x01
    d = Deframer()
    bodies = d.feed(bytes(bad) + data_frame(EX1, 2))
    assert len(bodies) == 1 and parse_body(bodies[0]).seq == 2
    assert d.stats.bad_crc == 1


def test_flag_after_escape_is_loss_of_sync() -> None:
    d = Deframer()
    bodies = d.feed(H("7E 45 00 7D 7E") + data_frame(EX1, 3)[1:])
    assert d.stats.escape_errors == 1
    assert len(bodies) == 1 and parse_body(bodies[0]).seq == 3


def test_truncated_overlong_and_malformed_frames_are_counted() -> None:
    d = Deframer()
    assert d.feed(H("7E 45 00 7E")) == []  # too short
    assert d.stats.truncated == 1
    d.feed(bytes([0x7E]) + bytes([0x01] * 300) + bytes([0x7E]))
    assert d.stats.too_long == 1
    short_len = frame(H("45 00 00 05 00 00 09 22 89 01"))  # length field 9 but 1 payload byte
    body = d.feed(short_len)[0]
    with pytest.raises(MoteProtocolError):
        parse_body(body)


def test_reader_survives_random_noise() -> None:
    """10 000 random bytes interleaved with good frames: every good frame still comes out, no exception."""
    rng = random.Random(1)
    d = Deframer()
    good = 0
    for i in range(200):
        d.feed(bytes(rng.randrange(256) for _ in range(50)))
        d.feed(b"\x7e")  # noise can leave us mid-frame; a real link idles with flags too
        got = [parse_body(b) for b in d.feed(data_frame(led_report(i, True), None))]
        good += sum(1 for f in got if f.packet == led_report(i, True))
    assert good == 200
    assert d.stats.dropped > 0


def test_node_addresses() -> None:
    assert node_address("n005") == 5 and node_address(7) == 7 and node_address("mote-12") == 12
    assert node_address("kitchen", {"kitchen": 40}) == 40
    with pytest.raises(MoteError):
        node_address("kitchen")
    with pytest.raises(MoteError):
        node_address(70000)


# ------------------------------------------------------------------ driver against the twins


def _serial_net(twin, **kw) -> MoteNetwork:
    link = SerialMoteLink(twin.port, ack_timeout=kw.pop("ack_timeout", 0.05), retries=kw.pop("retries", 5))
    return MoteNetwork(link, report_timeout=kw.pop("report_timeout", 0.1), **kw)


def test_led_on_off_over_serial() -> None:
    lit = []
    field = MoteFieldEmulator(on_led=lambda n, on: lit.append((n, on)))
    with BaseStationSerialTwin(field) as twin, _serial_net(twin) as net:
        assert isinstance(net, LedController)
        assert net.set_led("n005", True) is True
        assert net.set_led("n005", False) is True
        assert lit == [(5, True), (5, False)]
        assert field.received[0] == EX1


def test_silent_node_returns_false() -> None:
    with BaseStationSerialTwin(MoteFieldEmulator(silent=[9])) as twin, _serial_net(twin, attempts=2) as net:
        assert net.set_led("n009", True) is False
        assert net.set_led("n008", True) is True


def test_dropped_and_garbled_replies_recover_over_serial() -> None:
    """20 % of ACKs/reports dropped and 10 % garbled: every LED command still confirmed; garbage counted."""
    faults = FaultConfig(drop_rate=0.2, garble_rate=0.1, seed=11)
    with BaseStationSerialTwin(faults=faults) as twin, _serial_net(twin, attempts=6, retries=8) as net:
        for node in range(20):
            assert net.set_led(f"n{node:03d}", node % 2 == 0)
        assert twin.faults.counts["drop"] > 3 and twin.faults.counts["garble"] > 2
        assert net.link.stats.dropped > 0 and net.link.stats.retries > 0


def test_truncated_frames_from_the_line_are_counted_not_fatal() -> None:
    with BaseStationSerialTwin() as twin, _serial_net(twin) as net:
        twin.inject_raw(H("7E 45 00 FF 7E") + H("7E 45 00 FF FF 00 05 03 22 8A 00 05 01 00 00 7E") + H("99 7D 7E"))
        time.sleep(0.1)
        assert net.set_led("n001", True)
        assert net.link.stats.truncated >= 1 and net.link.stats.bad_crc >= 1


def test_no_ack_is_a_timeout_and_error_reply_is_a_protocol_error() -> None:
    with BaseStationSerialTwin(faults=FaultConfig(drop_rate=1.0)) as twin, _serial_net(twin, retries=2) as net:
        with pytest.raises(MoteTimeout, match="did not acknowledge after 3 tries"):
            net.set_led("n001", True)
    with BaseStationSerialTwin() as twin, _serial_net(twin) as net:
        twin.faults.force_error()
        with pytest.raises(MoteProtocolError, match="unknown protocol"):
            net.set_led("n001", True)


def test_slow_ack_within_and_beyond_the_timeout() -> None:
    with BaseStationSerialTwin(faults=FaultConfig(slow_seconds=0.03)) as twin, _serial_net(twin, ack_timeout=0.2) as net:
        twin.faults.force("slow", "slow")
        assert net.set_led("n002", True)
        assert net.link.stats.retries == 0
    with BaseStationSerialTwin(faults=FaultConfig(slow_rate=1.0, slow_seconds=1.0)) as twin, \
            _serial_net(twin, ack_timeout=0.05, retries=1) as net:
        with pytest.raises(MoteTimeout):
            net.set_led("n002", True)


def test_serial_disconnect_is_clear_and_reconnect_recovers() -> None:
    with BaseStationSerialTwin(faults=FaultConfig(disconnect_after=1)) as twin, _serial_net(twin) as net:
        assert net.set_led("n001", True)
        with pytest.raises(MoteDisconnected, match="basestation"):
            net.set_led("n002", True)
    with BaseStationSerialTwin(faults=FaultConfig(disconnect_after=1, reconnect_after=0.1)) as twin, \
            _serial_net(twin, reconnects=20) as net:
        assert net.set_led("n001", True)
        assert net.set_led("n002", True)


def test_serialforwarder_led_and_faults() -> None:
    with SerialForwarderTwin(faults=FaultConfig(drop_rate=0.3, garble_rate=0.1, seed=2)) as twin, \
            open_mote_network(twin.url, report_timeout=0.1, attempts=8) as net:
        for node in range(10):
            assert net.set_led(f"n{node}", True)
        assert twin.field.led_on == {n: True for n in range(10)}


def test_serialforwarder_handshake_and_disconnect() -> None:
    with SerialForwarderTwin(hello=b"T!") as twin:  # a TinyOS 1.x SerialForwarder
        with pytest.raises(MoteProtocolError, match="not a TinyOS 2"):
            SerialForwarderLink("127.0.0.1", twin.port)
    with SerialForwarderTwin(faults=FaultConfig(disconnect_after=1)) as twin, \
            open_mote_network(twin.url, report_timeout=0.1) as net:
        net.reconnects = 0
        assert net.set_led("n1", True)
        with pytest.raises(MoteDisconnected, match="tcp://127.0.0.1"):
            net.set_led("n2", True)
    with SerialForwarderTwin(faults=FaultConfig(disconnect_after=1, reconnect_after=0.1)) as twin, \
            open_mote_network(twin.url, report_timeout=0.1) as net:
        net.reconnects = 30
        assert net.set_led("n1", True) and net.set_led("n2", True)


def test_nothing_listening() -> None:
    with pytest.raises(MoteDisconnected, match="cannot connect"):
        open_mote_network("tcp://127.0.0.1:1")
    with pytest.raises(MoteDisconnected, match="cannot open serial port"):
        open_mote_network("/nonexistent/tty")
    assert AM_LED_COMMAND == 0x89


def test_driver_acks_a_packet_with_ack_from_the_mote_side() -> None:
    """protocols.md 3.9: a 0x44 from the mote side (legal, unusual) is answered with 0x43 seq and delivered."""
    with BaseStationSerialTwin() as twin, _serial_net(twin) as net:
        twin.inject_raw(data_frame(led_report(4, True), seq=7))
        packet = net.link.receive(1.0)
        assert packet == led_report(4, True)
        deadline = time.monotonic() + 1.0
        while not twin.acks_received and time.monotonic() < deadline:
            time.sleep(0.01)
        assert twin.acks_received == [7] and net.link.stats.acks_sent == 1


def test_serialforwarder_forwards_every_packet_to_every_client() -> None:
    """Like TinyOS's SerialForwarder: a node's report reaches every connected client, not only the
    client whose command caused it; a command from one client goes to the motes only."""
    with SerialForwarderTwin() as twin, open_mote_network(twin.url, report_timeout=0.5) as a, \
            open_mote_network(twin.url, report_timeout=0.5) as b:
        deadline = time.monotonic() + 5.0  # the forwarder serves a client once it has read its handshake
        while twin.clients_ready < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert twin.clients_ready == 2
        assert a.set_led("n1", True)
        seen_by_b = b.link.receive(1.0)
        assert seen_by_b is not None and parse_led_report(seen_by_b) == (1, True)
        assert b.set_led("n2", False)
        seen_by_a = a.link.receive(1.0)
        assert seen_by_a is not None and parse_led_report(seen_by_a) == (2, False)
        assert a.link.receive(0.1) is None and b.link.receive(0.1) is None  # one copy each, no echo of commands
        assert [p.dest for p in twin.field.received] == [1, 2]
