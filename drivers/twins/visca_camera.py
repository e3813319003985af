"""A simulated VISCA PTZ camera: the device state machine and its pseudo-terminal twin.

:class:`ViscaCameraEmulator` is the camera: it takes one request packet
(``8x ... FF`` or a broadcast) and returns the reply packets with their delays,
keeping a head state (pan/tilt counts, zoom counts) that moves at the speed the
command asked for (speed table of the :class:`~fgloc.drivers.ptz_units.CameraModel`,
scaled by ``time_scale``; 0 = instantaneous). It enforces what a real D100 does:
two sockets (a third concurrent command gets "buffer full"), legal speed bytes and
position limits (else "syntax error"), ACK then Completion on the same socket,
inquiries answered without a socket, cancel.

:class:`ViscaSerialTwin` serves it on a pty (pyserial opens :attr:`port`) from a
background thread with fault injection; :mod:`fgloc.drivers.twins.visca_ip_camera` and
:mod:`fgloc.drivers.twins.sony_cgi_camera` serve the same emulator over UDP and HTTP.

Scene hook: ``renderer(pose) -> ndarray`` renders what the camera sees for a
:class:`HeadPose`; :meth:`ViscaCameraEmulator.frame_source` wraps it as a
``FrameSource`` for :class:`fgloc.drivers.visca.head.ViscaHead`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.drivers.frames import CallableFrameSource
from fgloc.drivers.ptz_units import EVI_D100, CameraModel
from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.pty_port import PtyPort
from fgloc.drivers.twins.pty_twin import PtyTwin, ScheduledReplies
from fgloc.drivers.visca.codec import decode_nibbles, encode_nibbles
from fgloc.drivers.visca.errors import ViscaProtocolError
from fgloc.drivers.visca.packets import PacketSplitter


@dataclass(frozen=True)
class HeadPose:
    """The emulated head's state in device counts (see fgloc.drivers.ptz_units for conversion)."""

    pan_counts: int
    tilt_counts: int
    zoom_counts: int
    model: CameraModel


Renderer = Callable[[HeadPose], np.ndarray]


@dataclass
class _Axis:
    """Linear motion of one quantity from ``start`` to ``target`` over [t0, t1]."""

    start: float
    target: float
    t0: float = 0.0
    t1: float = 0.0

    def at(self, now: float) -> int:
        if now >= self.t1 or self.t1 <= self.t0:
            return int(round(self.target))
        f = (now - self.t0) / (self.t1 - self.t0)
        return int(round(self.start + f * (self.target - self.start)))

    def go(self, target: float, now: float, seconds: float) -> None:
        self.start = self.at(now)
        self.target = target
        self.t0, self.t1 = now, now + seconds

    def freeze(self, now: float) -> None:
        here = self.at(now)
        self.start = self.target = here
        self.t0 = self.t1 = now


class ViscaCameraEmulator:
    """The camera's brain: request packet -> [(delay_s, reply packet, is_completion)]."""

    def __init__(self, model: CameraModel = EVI_D100, address: int = 1, time_scale: float = 0.0,
                 renderer: Renderer | None = None, zoom_seconds: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.model = model
        self.address = address
        self.time_scale = time_scale
        self.renderer = renderer
        self.zoom_seconds = zoom_seconds
        self.clock = clock
        self.pan = _Axis(0, 0)
        self.tilt = _Axis(0, 0)
        self.zoom = _Axis(0, 0)
        self.sockets: dict[int, float] = {}  # socket -> completion time
        self.autofocus = True
        self._lock = threading.RLock()
        self.log: list[bytes] = []  # every request packet received, in order

    # -- state
    def pose(self) -> HeadPose:
        now = self.clock()
        with self._lock:
            return HeadPose(self.pan.at(now), self.tilt.at(now), self.zoom.at(now), self.model)

    def set_pose(self, pan_counts: int, tilt_counts: int, zoom_counts: int = 0) -> None:
        """Teleport the head (test setup)."""
        with self._lock:
            self.pan = _Axis(pan_counts, pan_counts)
            self.tilt = _Axis(tilt_counts, tilt_counts)
            self.zoom = _Axis(zoom_counts, zoom_counts)

    def frame(self) -> np.ndarray:
        """What the camera sees now (needs a renderer)."""
        if self.renderer is None:
            raise RuntimeError("this simulated camera has no renderer")
        return self.renderer(self.pose())

    def frame_source(self) -> CallableFrameSource:
        """A FrameSource (``read() -> ndarray``) rendering the current pose."""
        return CallableFrameSource(self.frame)

    # -- replies
    def _hdr(self) -> int:
        return (self.address + 8) << 4

    def _ack(self, s: int) -> bytes:
        return bytes([self._hdr(), 0x40 | s, 0xFF])

    def _done(self, s: int) -> bytes:
        return bytes([self._hdr(), 0x50 | s, 0xFF])

    def error(self, socket: int, code: int) -> bytes:
        return bytes([self._hdr(), 0x60 | socket, code, 0xFF])

    def _inq(self, data: bytes) -> bytes:
        return bytes([self._hdr(), 0x50]) + data + b"\xff"

    def _free_socket(self, now: float) -> int | None:
        for s in list(self.sockets):
            if self.sockets[s] <= now:
                del self.sockets[s]
        for s in (1, 2):
            if s not in self.sockets:
                return s
        return None

    def _run(self, now: float, seconds: float) -> list[tuple[float, bytes, bool]]:
        s = self._free_socket(now)
        if s is None:
            return [(0.0, self.error(0, 0x03), False)]
        self.sockets[s] = now + seconds
        return [(0.0, self._ack(s), False), (seconds, self._done(s), True)]

    def handle(self, packet: bytes) -> list[tuple[float, bytes, bool]]:
        """Execute one request; returns (delay s, reply bytes, is_completion) in send order."""
        with self._lock:
            self.log.append(packet)
            return self._handle(packet, self.clock())

    def _handle(self, p: bytes, now: float) -> list[tuple[float, bytes, bool]]:
        syntax = [(0.0, self.error(0, 0x02), False)]
        if len(p) < 3 or p[-1] != 0xFF:
            return syntax
        if p[0] == 0x88:
            if p[1:] == b"\x30\x01\xff":
                self.address = 1
                return [(0.0, bytes([0x88, 0x30, 0x02, 0xFF]), False)]
            if p[1:] == b"\x01\x00\x01\xff":
                self._clear(now)
                return [(0.0, p, False)]
            return []
        if p[0] != 0x80 | self.address:
            return []  # not for us (a daisy chain would pass it on)
        body = p[1:-1]
        m = self.model
        if body == b"\x01\x00\x01":  # IF_Clear
            self._clear(now)
            return [(0.0, self._done(0), False)]
        if len(body) == 1 and body[0] & 0xF0 == 0x20:  # cancel
            s = body[0] & 0x0F
            if s in self.sockets and self.sockets[s] > now:
                del self.sockets[s]
                self.pan.freeze(now)
                self.tilt.freeze(now)
                return [(0.0, self.error(s, 0x04), False)]
            return [(0.0, self.error(s, 0x05), False)]
        if body[:3] == b"\x01\x06\x02" and len(body) == 5 + m.pan_nibbles + 4:
            vv, ww = body[3], body[4]
            try:
                pan = decode_nibbles(body[5:5 + m.pan_nibbles])
                tilt = decode_nibbles(body[5 + m.pan_nibbles:])
            except ViscaProtocolError:
                return syntax
            if not (1 <= vv <= m.max_pan_speed and 1 <= ww <= m.max_tilt_speed):
                return syntax
            if not (m.pan_min <= pan <= m.pan_max and m.tilt_min <= tilt <= m.tilt_max):
                return syntax
            return self._move(now, pan, tilt, vv, ww)
        if body[:3] == b"\x01\x06\x01" and len(body) == 7:  # pan-tilt drive (only Stop is emulated)
            vv, ww, dp, dt = body[3:7]
            if not (1 <= vv <= m.max_pan_speed and 1 <= ww <= m.max_tilt_speed) or (dp, dt) != (3, 3):
                return syntax
            self.pan.freeze(now)
            self.tilt.freeze(now)
            self.sockets.clear()
            return self._run(now, 0.0)
        if body in (b"\x01\x06\x04", b"\x01\x06\x05"):  # home, reset
            return self._move(now, 0, 0, m.max_pan_speed, m.max_tilt_speed)
        if body[:3] == b"\x01\x04\x47" and len(body) == 7:
            try:
                z = decode_nibbles(body[3:], signed=False)
            except ViscaProtocolError:
                return syntax
            if not 0 <= z <= m.zoom_max:
                return syntax
            seconds = self.time_scale * self.zoom_seconds * abs(z - self.zoom.at(now)) / max(m.zoom_max, 1)
            self.zoom.go(z, now, seconds)
            return self._run(now, seconds)
        if body in (b"\x01\x04\x38\x02", b"\x01\x04\x38\x03"):  # focus auto / manual
            self.autofocus = body[3] == 0x02
            return self._run(now, 0.0)
        if body == b"\x01\x04\x07\x00":
            self.zoom.freeze(now)
            return self._run(now, 0.0)
        if body == b"\x09\x06\x12":
            return [(0.0, self._inq(encode_nibbles(self.pan.at(now), m.pan_nibbles)
                                    + encode_nibbles(self.tilt.at(now), 4)), False)]
        if body == b"\x09\x04\x47":
            return [(0.0, self._inq(encode_nibbles(self.zoom.at(now), 4, signed=False)), False)]
        if body == b"\x09\x00\x02":
            return [(0.0, self._inq(bytes([0, 0, 0, 1, 0, 4, 0, 0x0D, 0, 0, 0, 1, 2])), False)]
        return syntax

    def _move(self, now: float, pan: int, tilt: int, vv: int, ww: int) -> list[tuple[float, bytes, bool]]:
        m = self.model
        dp = pan - self.pan.at(now)
        dt = tilt - self.tilt.at(now)
        seconds = self.time_scale * m.move_seconds(dp, dt, vv, ww)
        self.pan.go(pan, now, seconds)
        self.tilt.go(tilt, now, seconds)
        return self._run(now, seconds)

    def _clear(self, now: float) -> None:
        self.sockets.clear()
        self.pan.freeze(now)
        self.tilt.freeze(now)
        self.zoom.freeze(now)


def is_socket_request(packet: bytes) -> bool:
    """A command or inquiry addressed to one camera (the requests error injection applies to)."""
    return (len(packet) >= 4 and packet[0] & 0xF8 == 0x80 and packet[0] != 0x88
            and packet[1] in (0x01, 0x09) and packet[1:4] != b"\x01\x00\x01")


def apply_reply_faults(faults: FaultInjector, emulator: ViscaCameraEmulator, request: bytes,
                       now: float) -> list[tuple[float, bytes]]:
    """Run ``request`` through error injection, the emulator and per-reply faults -> [(due, bytes)]."""
    if is_socket_request(request):
        code = faults.request_error()
        if code is not None:
            socket = 0 if code in (0x02, 0x03) or request[1] == 0x09 else 1
            return [(now, emulator.error(socket, code))]
    out = []
    for delay, reply, is_completion in emulator.handle(request):
        sent = faults.faulted_reply(reply, can_be_slow=is_completion)
        if sent is not None:
            out.append((now + (delay + sent[0]), sent[1]))
    return out


class WireTime:
    """Serial wire time at ``baudrate`` (10 bit times per byte, 8N1); None = instantaneous pty."""

    def __init__(self, baudrate: int | None) -> None:
        self.byte_seconds = 0.0 if not baudrate else 10.0 / baudrate
        self._tx_free = 0.0

    def rx(self, packet: bytes) -> float:
        """Seconds until the last byte of ``packet`` (sent by the driver just now) has arrived."""
        return len(packet) * self.byte_seconds

    def can_send(self, now: float) -> bool:
        return now >= self._tx_free

    def sent(self, data: bytes, now: float) -> None:
        self._tx_free = max(now, self._tx_free) + len(data) * self.byte_seconds

    def wait(self, now: float, default: float) -> float:
        return max(0.0, min(default, self._tx_free - now)) if now < self._tx_free else default


def write_paced(port: PtyPort, out: ScheduledReplies, wire: WireTime,
                sent: list[bytes] | None = None) -> None:
    """Write every due reply, one at a time, respecting the line's transmit time.

    Each reply is appended to ``sent`` (when given) *before* it is written, so any reply
    the driver has read is already in ``sent``: an ordering witness that needs no clock."""
    while True:
        now = time.monotonic()
        if not wire.can_send(now):
            return
        data = out.pop_one(now)
        if data is None:
            return
        if sent is not None:
            sent.append(data)
        port.write(data)
        wire.sent(data, now)


class ViscaSerialTwin(PtyTwin):
    """The emulator on a pseudo-terminal; open :attr:`port` with pyserial. Use as a context manager.

    ``baudrate`` (e.g. 9600 for a D100) adds the wire time of both directions
    (a request is handled once its last byte would have arrived; replies leave
    one after another at line speed); None keeps the pty instantaneous.
    """

    def __init__(self, emulator: ViscaCameraEmulator | None = None, faults: FaultConfig | None = None,
                 model: CameraModel = EVI_D100, time_scale: float = 0.0, renderer: Renderer | None = None,
                 baudrate: int | None = None) -> None:
        self.emulator = emulator or ViscaCameraEmulator(model, time_scale=time_scale, renderer=renderer)
        self.wire = WireTime(baudrate)
        self._splitter = PacketSplitter()
        #: every reply written to the driver, in order (faults applied), appended just before the
        #: write: whatever the driver has received is in here (tests check event order with it)
        self.sent: list[bytes] = []
        super().__init__("visca", "visca-serial-twin", faults)

    def _reset_link(self) -> None:
        self._splitter.reset()

    def _read_timeout(self, now: float, wait: float) -> float:
        return self.wire.wait(now, wait)

    def _on_bytes(self, data: bytes) -> None:
        for packet in self._splitter.feed(data):
            if self.faults.count_request():
                self.disconnect(self.faults.config.reconnect_after)
                break
            arrived = time.monotonic() + self.wire.rx(packet)
            for due_at, reply in apply_reply_faults(self.faults, self.emulator, packet, arrived):
                self._out.put(due_at, reply)

    def _write_due(self) -> None:
        write_paced(self._pty, self._out, self.wire, self.sent)
