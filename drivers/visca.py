"""Sony VISCA: message codec, RS-232 link on pyserial, a socket-matching session, and a PanTiltHead.

Layers (bottom up), all byte facts from ``shared/reference/protocols.md`` section 1:

* codec: :func:`encode_nibbles` / :func:`decode_nibbles` (signed 16-bit two's
  complement, one nibble per byte), command builders (``cmd_*``) returning whole
  packets ``8x ... FF``, and :func:`parse_reply` turning one reply packet into a
  :class:`Reply`. Pure functions; shared with VISCA-over-IP (``visca_ip.py``) and the
  Sony CGI VISCA tunnel (``sony_cgi.py``) and the twins.
* :class:`PacketSplitter`: byte stream -> packets (resyncs on a header byte, drops
  and counts garbage).
* :class:`ViscaLink` protocol and :class:`SerialLink` (pyserial, 9600 8N1).
* :class:`ViscaSession`: one command at a time; waits for ACK-or-error, then for the
  Completion *on the ACKed socket* (stale packets of other sockets are skipped);
  inquiries wait for ``y0 50 data FF``; timeouts are retried (all commands used here
  are idempotent absolute commands, so a resend is safe); every error reply raises a
  :class:`ViscaErrorReply` subclass.
* :class:`ViscaHead`: ``fgloc.core.hardware.PanTiltHead`` in spec radians via
  :class:`fgloc.drivers.ptz_units.PanTiltUnits`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Protocol, TypeVar

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.drivers.ptz_units import EVI_D100, CameraModel, PanTiltUnits, PositionOutOfRangeError

if TYPE_CHECKING:
    import serial

log = logging.getLogger(__name__)
_T = TypeVar("_T")

TERMINATOR = 0xFF
BROADCAST = 0x88
MAX_PACKET = 16

# ---------------------------------------------------------------------------------------------
# errors


class ViscaError(FglocError):
    """Base of every VISCA failure (one-line message, safe to show a user)."""


class ViscaTimeout(ViscaError):
    """No (valid) reply within the timeout after all retries."""


class ViscaDisconnected(ViscaError):
    """The port or connection went away (device unplugged, pty closed, socket error)."""


class ViscaProtocolError(ViscaError):
    """A reply that cannot be what we asked for (wrong length, bad nibbles)."""


class ViscaErrorReply(ViscaError):
    """The camera answered with an error packet ``z0 6y ee FF``."""

    code: int = -1
    meaning: str = "unknown error"

    def __init__(self, socket: int, code: int | None = None, command: str = "") -> None:
        self.socket = socket
        if code is not None:
            self.code = code
        what = f" to {command}" if command else ""
        super().__init__(f"camera replied '{self.meaning}' (error 0x{self.code:02X}, socket {socket}){what}")


class MessageLengthError(ViscaErrorReply):
    code, meaning = 0x01, "message length error"


class ViscaSyntaxError(ViscaErrorReply):
    code, meaning = 0x02, "syntax error"


class CommandBufferFull(ViscaErrorReply):
    code, meaning = 0x03, "command buffer full"


class CommandCanceled(ViscaErrorReply):
    code, meaning = 0x04, "command canceled"


class NoSocket(ViscaErrorReply):
    code, meaning = 0x05, "no socket"


class CommandNotExecutable(ViscaErrorReply):
    code, meaning = 0x41, "command not executable"


ERROR_CLASSES: dict[int, type[ViscaErrorReply]] = {
    cls.code: cls
    for cls in (MessageLengthError, ViscaSyntaxError, CommandBufferFull, CommandCanceled, NoSocket,
                CommandNotExecutable)
}


def error_for(code: int, socket: int, command: str = "") -> ViscaErrorReply:
    """The exception instance for an error code (unknown codes keep their number)."""
    cls = ERROR_CLASSES.get(code)
    if cls is None:
        exc = ViscaErrorReply(socket, code, command)
        return exc
    return cls(socket, None, command)


# ---------------------------------------------------------------------------------------------
# codec (pure)


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


# ---------------------------------------------------------------------------------------------
# byte stream -> packets


class PacketSplitter:
    """Split a VISCA byte stream into packets ``(hdr) ... FF``.

    Bytes before a header (bit 7 set) are discarded; packets longer than 16 bytes
    are discarded. No byte inside a reply has bit 7 set (data are nibbles, kinds
    are 0x3y-0x6y), so a header byte in the middle of a packet means its
    terminator was lost: the partial packet is dropped and a new one starts there.
    Drops are counted in ``dropped_bytes`` / ``dropped_packets``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped_bytes = 0
        self.dropped_packets = 0

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        for b in data:
            if not self._buf:
                if b & 0x80 and b != TERMINATOR:
                    self._buf.append(b)
                else:
                    self.dropped_bytes += 1
                continue
            if b & 0x80 and b != TERMINATOR:  # a new header: the previous packet lost its FF
                self.dropped_packets += 1
                self.dropped_bytes += len(self._buf)
                self._buf.clear()
            self._buf.append(b)
            if b == TERMINATOR:
                out.append(bytes(self._buf))
                self._buf.clear()
            elif len(self._buf) >= MAX_PACKET:
                self.dropped_packets += 1
                self.dropped_bytes += len(self._buf)
                self._buf.clear()
        return out

    def reset(self) -> None:
        self._buf.clear()


# ---------------------------------------------------------------------------------------------
# links


class ViscaLink(Protocol):
    """Carries whole VISCA packets; implementations: serial, VISCA-over-IP, HTTP tunnel."""

    def send(self, packet: bytes, retransmit: bool = False) -> None:
        """Send one packet (``8x ... FF``); ``retransmit`` marks a resend after a timeout."""

    def receive(self, timeout: float) -> bytes | None:
        """Next reply packet, or None after ``timeout`` seconds without one."""

    def flush_input(self) -> None:
        """Discard anything received but not yet read."""

    def reopen(self) -> None:
        """Re-establish the connection after a disconnect."""

    def close(self) -> None:
        """Release the port/socket."""


class SerialLink:
    """VISCA over RS-232 via pyserial (9600 bit/s 8N1, no flow control; DTR left asserted)."""

    def __init__(self, port: str, baudrate: int = 9600) -> None:
        self.port = port
        self.baudrate = baudrate
        self._splitter = PacketSplitter()
        self._pending: list[bytes] = []
        self._serial = self._open()

    def _open(self) -> serial.Serial:
        import serial

        try:
            return serial.Serial(self.port, self.baudrate, bytesize=8, parity="N", stopbits=1,
                                 timeout=0.05, write_timeout=1.0, xonxoff=False, rtscts=False)
        except (serial.SerialException, OSError) as exc:
            raise ViscaDisconnected(f"{self.port}: cannot open serial port ({_short(exc)})") from None

    @property
    def garbage_bytes(self) -> int:
        return self._splitter.dropped_bytes

    def send(self, packet: bytes, retransmit: bool = False) -> None:
        try:
            self._serial.write(packet)
            self._serial.flush()
        except _serial_errors() as exc:
            raise ViscaDisconnected(f"{self.port}: write failed ({_short(exc)})") from None

    def receive(self, timeout: float) -> bytes | None:
        errors = _serial_errors()
        deadline = time.monotonic() + timeout
        while not self._pending:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            try:
                self._serial.timeout = min(remaining, 0.05)
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except errors as exc:
                raise ViscaDisconnected(f"{self.port}: device disconnected ({_short(exc)})") from None
            if chunk:
                self._pending.extend(self._splitter.feed(chunk))
        return self._pending.pop(0)

    def flush_input(self) -> None:
        self._pending.clear()
        self._splitter.reset()
        try:
            self._serial.reset_input_buffer()
        except Exception:  # noqa: BLE001 - a dead port is reported by the next read
            pass

    def reopen(self) -> None:
        self.close()
        self._splitter.reset()
        self._pending.clear()
        self._serial = self._open()

    def close(self) -> None:
        try:
            self._serial.close()
        except Exception:  # noqa: BLE001
            pass


def _serial_errors() -> tuple[type[BaseException], ...]:
    """Exceptions pyserial lets through when a device vanishes (termios.error on a closed pty)."""
    import termios

    import serial

    return (serial.SerialException, OSError, TypeError, termios.error)


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


# ---------------------------------------------------------------------------------------------
# session: ACK / completion / inquiry matching with retries


@dataclass
class SessionStats:
    """Counters for what went wrong on the wire (for logs and tests)."""

    sent: int = 0
    retries: int = 0
    timeouts: int = 0
    garbled: int = 0
    stale: int = 0
    network_changes: int = 0
    reconnects: int = 0


@dataclass
class Timeouts:
    """Seconds to wait: ACK-or-error, inquiry reply, completion margin added to the move time."""

    ack: float = 0.2
    inquiry: float = 0.3
    completion_margin: float = 1.0
    retries: int = 3
    buffer_full_wait: float = 0.1


class ViscaSession:
    """One VISCA camera behind a link: sends commands one at a time and matches replies by socket."""

    def __init__(self, link: ViscaLink, address: int = 1, timeouts: Timeouts | None = None,
                 reconnects: int = 3, on_reconnect: Callable[[], None] | None = None,
                 reconnect_wait: float = 0.2) -> None:
        self.link = link
        self.address = address
        self.timeouts = timeouts or Timeouts()
        self.reconnects = reconnects
        self.reconnect_wait = reconnect_wait
        self.network_changed = False  # set on an unsolicited Network Change; the head re-initialises
        self.stats = SessionStats()
        self._lock = threading.RLock()
        self._on_reconnect = on_reconnect

    # -- public
    def command(self, packet: bytes, completion_timeout: float | None = None, name: str = "") -> None:
        """Send a command; wait for its ACK, then its Completion on the same socket.

        ``completion_timeout`` (s) defaults to the completion margin. A timeout at
        either stage resends the command (idempotent commands only).
        """
        name = name or packet.hex(" ")
        wait = completion_timeout if completion_timeout is not None else self.timeouts.completion_margin
        self._with_reconnect(lambda: self._command(packet, wait, name))

    def inquiry(self, packet: bytes, expect_len: int, name: str = "") -> bytes:
        """Send an inquiry; return the data bytes of the ``y0 50 data FF`` reply (length checked)."""
        name = name or packet.hex(" ")
        return self._with_reconnect(lambda: self._inquiry(packet, expect_len, name))

    def if_clear(self) -> None:
        """IF_Clear to this camera: waits for ``z0 50 FF`` (no ACK)."""
        self._with_reconnect(lambda: self._if_clear())

    def address_set(self) -> int:
        """Broadcast Address Set; returns the number of cameras on the chain."""
        return self._with_reconnect(self._address_set)

    # -- internals
    def _with_reconnect(self, op: Callable[[], _T]) -> _T:
        with self._lock:
            attempts = 0
            while True:
                try:
                    return op()
                except ViscaDisconnected:
                    if attempts >= self.reconnects:
                        raise
                    attempts += 1
                    self.stats.reconnects += 1
                    log.warning("VISCA link lost; reconnecting (%d/%d)", attempts, self.reconnects)
                    time.sleep(self.reconnect_wait)
                    try:
                        self.link.reopen()
                    except ViscaDisconnected:
                        if attempts >= self.reconnects:
                            raise
                        continue
                    if self._on_reconnect is not None:
                        self._on_reconnect()

    def _send(self, packet: bytes, retransmit: bool = False) -> None:
        self.stats.sent += 1
        self.link.send(packet, retransmit)

    def _next(self, deadline: float) -> Reply | None:
        """Next well-formed reply from our camera before ``deadline``; None on timeout."""
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            raw = self.link.receive(remaining)
            if raw is None:
                return None
            try:
                reply = parse_reply(raw)
            except ViscaProtocolError as exc:
                self.stats.garbled += 1
                log.debug("dropping %s", exc)
                continue
            if reply.kind is ReplyKind.NETWORK_CHANGE:
                self.stats.network_changes += 1
                self.network_changed = True
                log.warning("camera %d reported a network change", reply.sender)
                continue
            if reply.sender not in (0, self.address):
                self.stats.stale += 1
                continue
            return reply

    def _command(self, packet: bytes, completion_timeout: float, name: str) -> None:
        t = self.timeouts
        last: ViscaError | None = None
        acked = True  # a resend after an ACKed attempt is a new message, not a retransmission
        for attempt in range(t.retries + 1):
            if attempt:
                self.stats.retries += 1
            self._send(packet, retransmit=attempt > 0 and not acked)
            acked = False
            # stage 1: ACK or error
            deadline = time.monotonic() + t.ack
            socket = None
            busy = False
            while socket is None:
                reply = self._next(deadline)
                if reply is None:
                    break
                if reply.kind is ReplyKind.ACK:
                    socket = reply.socket
                elif reply.kind is ReplyKind.ERROR:
                    exc = error_for(reply.error_code, reply.socket, name)
                    if not isinstance(exc, CommandBufferFull):
                        raise exc
                    last, busy = exc, True
                    time.sleep(t.buffer_full_wait)
                    break
                else:
                    self.stats.stale += 1
            if socket is None:
                if not busy:
                    self.stats.timeouts += 1
                    last = ViscaTimeout(f"no ACK from camera {self.address} to {name}")
                continue
            # stage 2: completion on that socket
            acked = True
            deadline = time.monotonic() + completion_timeout
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    last = ViscaTimeout(f"no completion from camera {self.address} for {name} "
                                        f"within {completion_timeout:.1f} s")
                    break
                if reply.socket != socket or reply.kind not in (ReplyKind.COMPLETION, ReplyKind.ERROR):
                    self.stats.stale += 1
                    continue
                if reply.kind is ReplyKind.COMPLETION:
                    return
                raise error_for(reply.error_code, reply.socket, name)
        assert last is not None
        raise last

    def _inquiry(self, packet: bytes, expect_len: int, name: str) -> bytes:
        t = self.timeouts
        last: ViscaError = ViscaTimeout(f"no reply from camera {self.address} to {name}")
        for attempt in range(t.retries + 1):
            if attempt:
                self.stats.retries += 1
            self._send(packet, attempt > 0)
            deadline = time.monotonic() + t.inquiry
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    last = ViscaTimeout(f"no reply from camera {self.address} to {name}")
                    break
                if reply.kind is ReplyKind.INQUIRY:
                    if len(reply.data) != expect_len:
                        self.stats.garbled += 1
                        last = ViscaProtocolError(f"reply to {name} has {len(reply.data)} data bytes, "
                                                  f"expected {expect_len}")
                        break
                    if any(b & 0xF0 for b in reply.data):
                        self.stats.garbled += 1
                        last = ViscaProtocolError(f"reply to {name} has corrupted nibbles")
                        break
                    return reply.data
                if reply.kind is ReplyKind.ERROR and reply.socket == 0:
                    exc = error_for(reply.error_code, 0, name)
                    if isinstance(exc, CommandBufferFull):
                        last = exc
                        break
                    raise exc
                self.stats.stale += 1
        raise last

    def _if_clear(self) -> None:
        t = self.timeouts
        for attempt in range(t.retries + 1):
            if attempt:
                self.stats.retries += 1
            self._send(cmd_if_clear(self.address), attempt > 0)
            deadline = time.monotonic() + t.ack
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    break
                if reply.kind is ReplyKind.COMPLETION and reply.socket == 0:
                    return
                if reply.kind is ReplyKind.ERROR:
                    raise error_for(reply.error_code, reply.socket, "IF_Clear")
                self.stats.stale += 1
        raise ViscaTimeout(f"no reply from camera {self.address} to IF_Clear")

    def _address_set(self) -> int:
        t = self.timeouts
        for attempt in range(t.retries + 1):
            if attempt:
                self.stats.retries += 1
            self._send(cmd_address_set())
            deadline = time.monotonic() + t.ack
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    break
                if reply.kind is ReplyKind.ADDRESS_SET:
                    return reply.data[0] - 1
                self.stats.stale += 1
        raise ViscaTimeout("no reply to Address Set (is the camera on and the cable a crossed VISCA cable?)")


# ---------------------------------------------------------------------------------------------
# the PanTiltHead


class FrameSourceLike(Protocol):
    def read(self) -> np.ndarray: ...


@dataclass
class HeadSettings:
    """Per-head knobs: speeds (VISCA bytes), read-back confirmation, settle time (s)."""

    pan_speed: int | None = None  # None: the model's maximum
    tilt_speed: int | None = None
    confirm_reads: bool = True  # read position until two successive inquiries agree
    max_reads: int = 5
    settle_seconds: float = 0.0


class ViscaHead:
    """``fgloc.core.hardware.PanTiltHead`` over VISCA (any link): angles in spec radians.

    The read-back position is what ``position()`` returns (never the commanded one);
    with ``confirm_reads`` it is read until two successive inquiries agree, which
    also rejects a reply whose nibbles were corrupted in transit (VISCA has no
    checksum) and a head still settling (protocols.md 1.10 item 9).
    """

    def __init__(self, session: ViscaSession, units: PanTiltUnits | None = None,
                 frames: FrameSourceLike | Callable[[], np.ndarray] | None = None,
                 settings: HeadSettings | None = None) -> None:
        self.session = session
        self.units = units or PanTiltUnits(EVI_D100)
        self.frames = frames
        self.settings = settings or HeadSettings()
        session._on_reconnect = self._reinit
        self._last_counts: tuple[int, int] | None = None

    @property
    def model(self) -> CameraModel:
        return self.units.model

    @property
    def address(self) -> int:
        return self.session.address

    # -- setup
    def initialize(self, address_set: bool = True) -> None:
        """Address Set (serial only) then IF_Clear, as every known driver does at start-up."""
        self._uses_address_set = address_set
        if address_set:
            self.session.address_set()
        self.session.if_clear()
        self.session.network_changed = False

    _uses_address_set = False

    def _reinit(self) -> None:
        """After a reconnect or a Network Change: Address Set (serial) + IF_Clear (protocols.md 1.10 item 6)."""
        self.session.network_changed = False
        self._last_counts = None
        try:
            if self._uses_address_set:
                self.session._address_set()
            self.session._if_clear()
        except ViscaError as exc:
            log.warning("re-initialising the camera failed: %s", exc)

    def _ready(self) -> None:
        if self.session.network_changed:
            log.warning("camera reported a network change; re-running Address Set and IF_Clear")
            self._reinit()

    # -- counts level
    def _speeds(self) -> tuple[int, int]:
        m = self.model
        ps = self.settings.pan_speed or m.max_pan_speed
        ts = self.settings.tilt_speed or m.max_tilt_speed
        return min(ps, m.max_pan_speed), min(ts, m.max_tilt_speed)

    def move_to_counts(self, pan: int, tilt: int) -> None:
        """Absolute move in device counts; blocks until the camera reports completion."""
        self._ready()
        m = self.model
        if not (m.pan_min <= pan <= m.pan_max and m.tilt_min <= tilt <= m.tilt_max):
            raise PositionOutOfRangeError(
                f"({pan}, {tilt}) counts outside {m.name} range pan {m.pan_min}..{m.pan_max}, "
                f"tilt {m.tilt_min}..{m.tilt_max}")
        ps, ts = self._speeds()
        start = self._last_counts
        if start is None:  # size the completion timeout from the real distance (protocols.md 1.5)
            try:
                start = self.read_counts_once()
            except (ViscaTimeout, ViscaProtocolError):
                start = None
        if start is None:
            dp, dt = m.pan_max - m.pan_min, m.tilt_max - m.tilt_min
        else:
            dp, dt = pan - start[0], tilt - start[1]
        wait = m.move_seconds(dp, dt, ps, ts) * 1.2 + self.session.timeouts.completion_margin
        packet = cmd_pan_tilt_absolute(self.address, pan, tilt, ps, ts, m.pan_nibbles)
        self.session.command(packet, completion_timeout=wait, name="pan-tilt absolute move")
        self._last_counts = (pan, tilt)
        if self.settings.settle_seconds > 0:
            time.sleep(self.settings.settle_seconds)

    def read_counts_once(self) -> tuple[int, int]:
        data = self.session.inquiry(cmd_pan_tilt_position_inquiry(self.address), self.model.pan_nibbles + 4,
                                    name="pan-tilt position inquiry")
        return decode_pan_tilt(data, self.model.pan_nibbles)

    def position_counts(self) -> tuple[int, int]:
        """Read-back (pan, tilt) in device counts (confirmed by two equal reads when enabled)."""
        self._ready()
        prev = self.read_counts_once()
        if not self.settings.confirm_reads:
            self._last_counts = prev
            return prev
        for _ in range(self.settings.max_reads - 1):
            cur = self.read_counts_once()
            if cur == prev:
                self._last_counts = cur
                return cur
            prev = cur
        raise ViscaProtocolError(f"pan-tilt position did not read the same twice in {self.settings.max_reads} reads "
                                 "(head still moving or line noise)")

    # -- PanTiltHead
    def move_to(self, pan: float, tilt: float) -> None:
        """Move to spec (pan, tilt) radians; blocks until completion."""
        self.move_to_counts(*self.units.to_counts(pan, tilt))

    def position(self) -> tuple[float, float]:
        """Read-back spec (pan, tilt) radians."""
        return self.units.to_spec(*self.position_counts())

    def set_zoom(self, zoom: float) -> None:
        counts = self.units.zoom_to_counts(zoom)
        wait = 3.0 + self.session.timeouts.completion_margin
        self.session.command(cmd_zoom_direct(self.address, counts), completion_timeout=wait, name="zoom direct")

    def zoom_counts(self) -> int:
        data = self.session.inquiry(cmd_zoom_position_inquiry(self.address), 4, name="zoom position inquiry")
        return decode_zoom(data)

    def zoom(self) -> float:
        return self.units.zoom_from_counts(self.zoom_counts())

    def set_autofocus(self, on: bool) -> None:
        """Auto focus on, or manual (focus held where it is) while measuring."""
        packet = cmd_focus_auto(self.address) if on else cmd_focus_manual(self.address)
        self.session.command(packet, name="focus auto" if on else "focus manual")

    def stop(self) -> None:
        ps, ts = self._speeds()
        self.session.command(cmd_pan_tilt_stop(self.address, ps, ts), name="pan-tilt stop")
        self._last_counts = None

    def home(self) -> None:
        m = self.model
        ps, ts = self._speeds()
        wait = m.move_seconds(m.pan_max - m.pan_min, m.tilt_max - m.tilt_min, ps, ts) * 1.2 \
            + self.session.timeouts.completion_margin
        self.session.command(cmd_home(self.address), completion_timeout=wait, name="home")
        self._last_counts = (0, 0)

    def grab_frame(self) -> np.ndarray:
        if self.frames is None:
            raise ViscaError("this head has no frame source (give --video or a FrameSource)")
        if callable(self.frames) and not hasattr(self.frames, "read"):
            return self.frames()
        return self.frames.read()

    def close(self) -> None:
        self.session.link.close()

    def __enter__(self) -> ViscaHead:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_serial_head(port: str, units: PanTiltUnits | None = None, address: int = 1,
                     timeouts: Timeouts | None = None, frames=None, settings: HeadSettings | None = None,
                     initialize: bool = True, baudrate: int = 9600) -> ViscaHead:
    """Open a VISCA head on a serial port (Address Set + IF_Clear unless ``initialize=False``)."""
    link = SerialLink(port, baudrate)
    head = ViscaHead(ViscaSession(link, address, timeouts), units, frames, settings)
    if initialize:
        try:
            head.initialize(address_set=True)
        except ViscaError:
            link.close()
            raise
    return head
