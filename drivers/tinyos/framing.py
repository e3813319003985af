"""TinyOS 2.x serial framing (pure): HDLC flags and escaping, CRC-16, frame bodies, the Deframer.

Wire format (protocols.md section 3)::

    7E | P | [S] | D | dest(2) src(2) len group type | payload | crc_lo crc_hi | 7E

* ``P``: 0x43 ACK (+ the acknowledged seq), 0x44 packet-with-ack (+ seq byte S),
  0x45 packet-no-ack, 0xFF unknown-protocol reply;
* CRC-16/XMODEM (poly 0x1021, init 0, MSB-first) over P .. last payload byte,
  un-escaped, sent low byte first;
* every 0x7E/0x7D between the flags is sent as 0x7D, byte ^ 0x20.

Malformed input never raises in the :class:`Deframer`: bad CRC, truncated frames,
escape errors and over-long frames are dropped and counted in :class:`LinkStats`.
"""

from __future__ import annotations

from dataclasses import dataclass

from fgloc.drivers.tinyos.errors import MoteProtocolError
from fgloc.drivers.tinyos.messages import AmPacket

FLAG = 0x7E
ESCAPE = 0x7D
XOR = 0x20

PROTO_ACK = 0x43
PROTO_PACKET_ACK = 0x44
PROTO_PACKET_NOACK = 0x45
PROTO_UNKNOWN = 0xFF
MAX_FRAME = 256


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/XMODEM (poly 0x1021, init 0, no reflection, no final XOR); check("123456789") = 0x31C3."""
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def escape(data: bytes) -> bytes:
    """HDLC byte stuffing of everything between the flags."""
    out = bytearray()
    for b in data:
        if b in (FLAG, ESCAPE):
            out += bytes([ESCAPE, b ^ XOR])
        else:
            out.append(b)
    return bytes(out)


def frame(body: bytes) -> bytes:
    """``7E escape(body + crc_lo crc_hi) 7E`` for a body starting with the protocol byte."""
    crc = crc16(body)
    return bytes([FLAG]) + escape(body + bytes([crc & 0xFF, crc >> 8])) + bytes([FLAG])



def data_frame(packet: AmPacket, seq: int | None) -> bytes:
    """A wire frame: 0x44 + seq when ``seq`` is given (ACK requested), else 0x45."""
    if seq is None:
        return frame(bytes([PROTO_PACKET_NOACK]) + packet.pack())
    return frame(bytes([PROTO_PACKET_ACK, seq & 0xFF]) + packet.pack())


def ack_frame(seq: int) -> bytes:
    """The ACK ``7E 43 seq crc crc 7E``."""
    return frame(bytes([PROTO_ACK, seq & 0xFF]))


@dataclass(frozen=True)
class Frame:
    """A decoded frame body (CRC checked and removed)."""

    protocol: int
    seq: int | None
    packet: AmPacket | None
    data: bytes  # bytes after P (and S)


def parse_body(body: bytes) -> Frame:
    """Protocol byte .. payload (CRC removed) -> Frame; MoteProtocolError when malformed."""
    p = body[0]
    if p == PROTO_ACK:
        if len(body) != 2:
            raise MoteProtocolError(f"ACK frame of {len(body)} bytes")
        return Frame(p, body[1], None, body[1:])
    if p == PROTO_PACKET_ACK:
        if len(body) < 2:
            raise MoteProtocolError("packet-with-ack frame without sequence byte")
        return Frame(p, body[1], AmPacket.unpack(body[2:]), body[2:])
    if p == PROTO_PACKET_NOACK:
        return Frame(p, None, AmPacket.unpack(body[1:]), body[1:])
    return Frame(p, None, None, body[1:])


@dataclass
class LinkStats:
    """What the reader dropped or did; never reset implicitly."""

    frames: int = 0
    bad_crc: int = 0
    truncated: int = 0
    too_long: int = 0
    escape_errors: int = 0
    malformed: int = 0
    acks_sent: int = 0
    retries: int = 0
    sent: int = 0

    @property
    def dropped(self) -> int:
        return self.bad_crc + self.truncated + self.too_long + self.escape_errors + self.malformed


class Deframer:
    """HDLC receive state machine: bytes -> CRC-checked frame bodies. Never raises.

    Resyncs on every flag; ``7D 7E`` (flag right after an escape) drops the frame
    being built and starts a new one (the Java Packetizer's loss-of-sync rule).
    Flag pairs with fewer than 4 bytes between them are idle/truncated frames.
    """

    def __init__(self, stats: LinkStats | None = None) -> None:
        self.stats = stats or LinkStats()
        self._buf = bytearray()
        self._in_frame = False
        self._escaped = False

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        for b in data:
            if b == FLAG:
                if self._escaped:
                    self.stats.escape_errors += 1
                    self._buf.clear()
                    self._escaped = False
                    self._in_frame = True
                    continue
                if self._in_frame and self._buf:
                    body = self._finish()
                    if body is not None:
                        out.append(body)
                self._buf.clear()
                self._in_frame = True
                continue
            if not self._in_frame:
                continue  # garbage before the first flag
            if self._escaped:
                self._buf.append(b ^ XOR)
                self._escaped = False
            elif b == ESCAPE:
                self._escaped = True
            else:
                self._buf.append(b)
            if len(self._buf) > MAX_FRAME + 2:
                self.stats.too_long += 1
                self._buf.clear()
                self._in_frame = False  # wait for the next flag
        return out

    def _finish(self) -> bytes | None:
        raw = bytes(self._buf)
        if len(raw) < 4:
            self.stats.truncated += 1
            return None
        body, crc = raw[:-2], raw[-2] | (raw[-1] << 8)
        if crc16(body) != crc:
            self.stats.bad_crc += 1
            return None
        self.stats.frames += 1
        return body
