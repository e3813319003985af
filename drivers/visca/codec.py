"""VISCA message codec (pure functions): nibble encoding, command builders, reply parsing.

All byte facts from ``shared/reference/protocols.md`` section 1. Positions are signed
16-bit two's-complement device counts sent one nibble per byte; zoom is unsigned
counts. Every ``cmd_*`` returns a whole packet ``8x ... FF`` (``x`` the camera
address 1..7). Shared with VISCA-over-IP (:mod:`fgloc.drivers.visca.ip`), the Sony CGI
VISCA tunnel (:mod:`fgloc.drivers.sony_cgi`) and the twins.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from fgloc.drivers.visca.errors import ViscaProtocolError

TERMINATOR = 0xFF
BROADCAST = 0x88
MAX_PACKET = 16


def encode_nibbles(value: int, n: int = 4, signed: bool = True) -> bytes:
    """``value`` as ``n`` bytes ``0v`` (high nibble first), two's complement over 4n bits."""
    bits = 4 * n
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if not lo <= value <= hi:
        raise ValueError(f"{value} does not fit in {n} nibbles ({'signed' if signed else 'unsigned'})")
    v = value & ((1 << bits) - 1)
    return bytes((v >> (4 * (n - 1 - i))) & 0x0F for i in range(n))


def decode_nibbles(data: bytes, signed: bool = True) -> int:
    """Inverse of :func:`encode_nibbles`; raises ViscaProtocolError if a high nibble is set."""
    v = 0
    for b in data:
        if b & 0xF0:
            raise ViscaProtocolError(f"nibble byte 0x{b:02X} has its high nibble set")
        v = (v << 4) | b
    bits = 4 * len(data)
    if signed and v >= 1 << (bits - 1):
        v -= 1 << bits
    return v


def _packet(address: int, *body: int | bytes) -> bytes:
    if not 1 <= address <= 7:
        raise ValueError(f"VISCA camera address must be 1..7, got {address}")
    out = bytearray([0x80 | address])
    for part in body:
        out.extend(part if isinstance(part, (bytes, bytearray)) else bytes([part]))
    out.append(TERMINATOR)
    return bytes(out)


def cmd_address_set() -> bytes:
    """Broadcast Address Set ``88 30 01 FF``: first camera becomes 1."""
    return bytes([BROADCAST, 0x30, 0x01, TERMINATOR])


def cmd_if_clear_broadcast() -> bytes:
    """Broadcast IF_Clear ``88 01 00 01 FF`` (echoed back unchanged)."""
    return bytes([BROADCAST, 0x01, 0x00, 0x01, TERMINATOR])


def cmd_if_clear(address: int = 1) -> bytes:
    """IF_Clear to one camera ``8x 01 00 01 FF`` (reply ``z0 50 FF``, no ACK)."""
    return _packet(address, 0x01, 0x00, 0x01)


def _check_speed(speed: int, limit: int, axis: str) -> None:
    if not 1 <= speed <= limit:
        raise ValueError(f"{axis} speed byte must be 0x01..0x{limit:02X}, got 0x{speed:02X}")


def cmd_pan_tilt_absolute(address: int, pan: int, tilt: int, pan_speed: int = 0x18, tilt_speed: int = 0x14,
                          pan_nibbles: int = 4) -> bytes:
    """AbsolutePosition ``8x 01 06 02 VV WW 0Y.. 0Z.. FF`` (pan/tilt in signed device counts)."""
    _check_speed(pan_speed, 0x18, "pan")
    _check_speed(tilt_speed, 0x18, "tilt")
    speeds = (pan_speed, tilt_speed) if pan_nibbles == 4 else (pan_speed, 0x00)
    return _packet(address, 0x01, 0x06, 0x02, *speeds, encode_nibbles(pan, pan_nibbles),
                   encode_nibbles(tilt, 4))


def cmd_pan_tilt_stop(address: int, pan_speed: int = 0x18, tilt_speed: int = 0x14) -> bytes:
    """Pan-tiltDrive Stop ``8x 01 06 01 VV WW 03 03 FF`` (legal speeds even when stopping)."""
    _check_speed(pan_speed, 0x18, "pan")
    _check_speed(tilt_speed, 0x18, "tilt")
    return _packet(address, 0x01, 0x06, 0x01, pan_speed, tilt_speed, 0x03, 0x03)


def cmd_home(address: int = 1) -> bytes:
    """Pan-tilt Home ``8x 01 06 04 FF``."""
    return _packet(address, 0x01, 0x06, 0x04)


def cmd_pan_tilt_reset(address: int = 1) -> bytes:
    """Pan-tilt Reset ``8x 01 06 05 FF`` (re-initialisation run)."""
    return _packet(address, 0x01, 0x06, 0x05)


def cmd_pan_tilt_position_inquiry(address: int = 1) -> bytes:
    """Pan-tiltPosInq ``8x 09 06 12 FF``."""
    return _packet(address, 0x09, 0x06, 0x12)


def cmd_zoom_direct(address: int, zoom: int) -> bytes:
    """CAM_Zoom Direct ``8x 01 04 47 0p 0q 0r 0s FF`` (unsigned zoom counts)."""
    return _packet(address, 0x01, 0x04, 0x47, encode_nibbles(zoom, 4, signed=False))


def cmd_zoom_stop(address: int = 1) -> bytes:
    """CAM_Zoom Stop ``8x 01 04 07 00 FF``."""
    return _packet(address, 0x01, 0x04, 0x07, 0x00)


def cmd_zoom_position_inquiry(address: int = 1) -> bytes:
    """CAM_ZoomPosInq ``8x 09 04 47 FF``."""
    return _packet(address, 0x09, 0x04, 0x47)


def cmd_focus_auto(address: int = 1) -> bytes:
    """CAM_Focus Auto ``8x 01 04 38 02 FF``."""
    return _packet(address, 0x01, 0x04, 0x38, 0x02)


def cmd_focus_manual(address: int = 1) -> bytes:
    """CAM_Focus Manual ``8x 01 04 38 03 FF`` (lock focus while measuring, protocols.md 1.6)."""
    return _packet(address, 0x01, 0x04, 0x38, 0x03)


def cmd_cancel(address: int, socket: int) -> bytes:
    """Command cancel ``8x 2y FF``."""
    return _packet(address, 0x20 | (socket & 0x0F))


def cmd_version_inquiry(address: int = 1) -> bytes:
    """CAM_VersionInq ``8x 09 00 02 FF``."""
    return _packet(address, 0x09, 0x00, 0x02)


def cmd_power(address: int, on: bool) -> bytes:
    """CAM_Power On ``8x 01 04 00 02 FF`` / Off ``8x 01 04 00 03 FF``."""
    return _packet(address, 0x01, 0x04, 0x00, 0x02 if on else 0x03)


def cmd_power_inquiry(address: int = 1) -> bytes:
    """CAM_PowerInq ``8x 09 04 00 FF`` (reply ``y0 50 02 FF`` on, ``03`` off)."""
    return _packet(address, 0x09, 0x04, 0x00)


PAN_LEFT, PAN_RIGHT, TILT_UP, TILT_DOWN, NO_MOVE = 0x01, 0x02, 0x01, 0x02, 0x03


def cmd_pan_tilt_drive(address: int, pan_dir: int, tilt_dir: int, pan_speed: int = 0x18,
                       tilt_speed: int = 0x14) -> bytes:
    """Pan-tiltDrive ``8x 01 06 01 VV WW pp tt FF``: pan 01 left / 02 right / 03 none, tilt 01 up /
    02 down / 03 none (03 03 = Stop); legal speeds always (protocols.md 1.10 item 1)."""
    _check_speed(pan_speed, 0x18, "pan")
    _check_speed(tilt_speed, 0x18, "tilt")
    if pan_dir not in (1, 2, 3) or tilt_dir not in (1, 2, 3):
        raise ValueError(f"pan-tilt drive directions must be 1..3, got {pan_dir}, {tilt_dir}")
    return _packet(address, 0x01, 0x06, 0x01, pan_speed, tilt_speed, pan_dir, tilt_dir)


def cmd_pan_tilt_relative(address: int, dpan: int, dtilt: int, pan_speed: int = 0x18,
                          tilt_speed: int = 0x14) -> bytes:
    """RelativePosition ``8x 01 06 03 VV WW 0Y.. 0Z.. FF`` (signed count offsets)."""
    _check_speed(pan_speed, 0x18, "pan")
    _check_speed(tilt_speed, 0x18, "tilt")
    return _packet(address, 0x01, 0x06, 0x03, pan_speed, tilt_speed, encode_nibbles(dpan, 4),
                   encode_nibbles(dtilt, 4))


def cmd_zoom_drive(address: int, tele: bool, speed: int | None = None) -> bytes:
    """CAM_Zoom Tele/Wide: standard ``8x 01 04 07 02/03 FF``, variable ``2p``/``3p`` (p = 0..7)."""
    if speed is None:
        return _packet(address, 0x01, 0x04, 0x07, 0x02 if tele else 0x03)
    if not 0 <= speed <= 7:
        raise ValueError(f"variable zoom speed must be 0..7, got {speed}")
    return _packet(address, 0x01, 0x04, 0x07, (0x20 if tele else 0x30) | speed)


def decode_version(data: bytes) -> tuple[int, int, int, int]:
    """Version inquiry data ``gg gg hh hh jj jj kk`` -> (vendor, model, ROM version, sockets)."""
    if len(data) != 7:
        raise ViscaProtocolError(f"version inquiry data has {len(data)} bytes, expected 7")
    return (int.from_bytes(data[0:2], "big"), int.from_bytes(data[2:4], "big"), int.from_bytes(data[4:6], "big"),
            data[6])


def is_inquiry(packet: bytes) -> bool:
    """True for an inquiry packet ``8x 09 ...``."""
    return len(packet) >= 3 and packet[1] == 0x09


class ReplyKind(Enum):
    ACK = "ack"
    COMPLETION = "completion"  # z0 5y FF with y != 0, or z0 50 FF (IF_Clear)
    INQUIRY = "inquiry"  # z0 50 data FF
    ERROR = "error"
    NETWORK_CHANGE = "network_change"
    ADDRESS_SET = "address_set"
    IF_CLEAR_ECHO = "if_clear_echo"


@dataclass(frozen=True)
class Reply:
    """One decoded reply packet. ``sender`` is the camera address (1..7), 0 for broadcast."""

    kind: ReplyKind
    sender: int
    socket: int = 0
    data: bytes = b""
    error_code: int = 0


def parse_reply(packet: bytes) -> Reply:
    """Decode one complete reply packet (header .. FF); ViscaProtocolError when malformed."""
    if len(packet) < 3 or packet[-1] != TERMINATOR or not packet[0] & 0x80:
        raise ViscaProtocolError(f"malformed VISCA packet {packet.hex(' ')}")
    if TERMINATOR in packet[:-1]:
        raise ViscaProtocolError(f"terminator inside VISCA packet {packet.hex(' ')}")
    header, kind_byte, rest = packet[0], packet[1], packet[2:-1]
    if header == BROADCAST:
        if kind_byte == 0x30 and len(rest) == 1:
            return Reply(ReplyKind.ADDRESS_SET, 0, data=bytes(rest))
        if kind_byte == 0x01 and rest == b"\x00\x01":
            return Reply(ReplyKind.IF_CLEAR_ECHO, 0)
        raise ViscaProtocolError(f"unexpected broadcast packet {packet.hex(' ')}")
    if header & 0x0F != 0:
        raise ViscaProtocolError(f"reply header 0x{header:02X} is not addressed to the controller")
    sender = ((header >> 4) & 0x0F) - 8
    if not 1 <= sender <= 7:
        raise ViscaProtocolError(f"reply header 0x{header:02X} names no camera")
    hi, socket = kind_byte >> 4, kind_byte & 0x0F
    if hi == 0x4 and not rest:
        return Reply(ReplyKind.ACK, sender, socket)
    if hi == 0x5:
        if socket == 0 and rest:
            return Reply(ReplyKind.INQUIRY, sender, 0, bytes(rest))
        if not rest:
            return Reply(ReplyKind.COMPLETION, sender, socket)
    if hi == 0x6 and len(rest) == 1:
        return Reply(ReplyKind.ERROR, sender, socket, error_code=rest[0])
    if kind_byte == 0x38 and not rest:
        return Reply(ReplyKind.NETWORK_CHANGE, sender)
    raise ViscaProtocolError(f"unrecognised VISCA reply {packet.hex(' ')}")


def decode_pan_tilt(data: bytes, pan_nibbles: int = 4) -> tuple[int, int]:
    """Inquiry data ``0w.. 0z..`` -> signed (pan, tilt) counts."""
    if len(data) != pan_nibbles + 4:
        raise ViscaProtocolError(f"pan-tilt inquiry data has {len(data)} bytes, expected {pan_nibbles + 4}")
    return decode_nibbles(data[:pan_nibbles]), decode_nibbles(data[pan_nibbles:])


def decode_zoom(data: bytes) -> int:
    """Zoom inquiry data ``0p 0q 0r 0s`` -> unsigned zoom counts."""
    if len(data) != 4:
        raise ViscaProtocolError(f"zoom inquiry data has {len(data)} bytes, expected 4")
    return decode_nibbles(data, signed=False)
