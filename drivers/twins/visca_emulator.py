"""The simulated VISCA camera's brain: request packet in, reply packets (with their delays) out.

:class:`ViscaCameraEmulator` keeps a head state (pan/tilt counts, zoom counts, power,
focus mode) that moves at the speed the command asked for (speed table of the
:class:`~fgloc.drivers.ptz_units.CameraModel`, scaled by ``time_scale``; 0 = instantaneous).
What it enforces, as a Sony head does (protocols.md 1.4-1.6, 1.10):

* two command sockets: every accepted command gets ``z0 4y FF`` then ``z0 5y FF`` on the same
  socket; a third concurrent command gets "buffer full" ``z0 60 03 FF``;
* legal speed bytes (01..max, even for Stop) and positions inside the model's range, else
  "syntax error" ``z0 60 02 FF``; inquiries are answered ``z0 50 data FF`` without a socket;
* **cancel** ``8x 2y FF``: the command in socket *y* stops where it is, the reply is
  ``z0 6y 04 FF`` and *no Completion follows* (Sony); an empty socket gets ``z0 6y 05 FF``;
* **interruption** (twin's choice, UNVERIFIED on hardware): a new pan-tilt command (Stop,
  drive, absolute, relative, home, reset) ends a running pan-tilt move where the head is,
  and a new zoom command ends a running zoom; the interrupted command's Completion is sent
  at once, before the new command's ACK, never later;
* IF_Clear and Power Off abort running commands without a Completion;
* while the power is off, commands other than power and IF_Clear get "not executable"
  ``z0 6y 41 FF`` (inquiries are still answered).

Each reply is ``(delay_s, packet, job)``: ``job`` is an id for a Completion (None otherwise).
A twin holding a scheduled Completion asks :meth:`ViscaCameraEmulator.completion_withdrawn`
just before writing it, so a Completion of a cancelled or interrupted command is never sent.

Scene hook: ``renderer(pose) -> ndarray`` renders what the camera sees for a
:class:`HeadPose`; :meth:`ViscaCameraEmulator.frame_source` wraps it as a ``FrameSource``.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.drivers.frames import CallableFrameSource
from fgloc.drivers.ptz_units import EVI_D100, CameraModel
from fgloc.drivers.visca.codec import decode_nibbles, encode_nibbles
from fgloc.drivers.visca.errors import ViscaProtocolError

#: Version inquiry answer fields (``y0 50 gg gg hh hh jj jj kk FF``): vendor 0001 = Sony (D100
#: manual); the model and ROM codes are the twin's own placeholders, not a real unit's.
VENDOR_SONY = 0x0001
TWIN_MODEL_CODE = 0x040D
TWIN_ROM_VERSION = 0x0001
SOCKETS = 2

PANTILT = "pan-tilt"
ZOOM = "zoom"

Reply = tuple[float, bytes, "int | None"]  # (delay s, packet, completion job id)


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


@dataclass
class _Job:
    """A command holding a socket until ``end`` (monotonic s); ``actuator`` None = instant."""

    socket: int
    end: float
    actuator: str | None


class ViscaCameraEmulator:
    """The camera's brain: request packet -> [(delay_s, reply packet, completion job id or None)]."""

    def __init__(self, model: CameraModel = EVI_D100, address: int = 1, time_scale: float = 0.0,
                 renderer: Renderer | None = None, zoom_seconds: float = 2.0, power_on_seconds: float = 0.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.model = model
        self.address = address
        self.time_scale = time_scale
        self.renderer = renderer
        self.zoom_seconds = zoom_seconds  # full optical range at the fastest zoom speed, real seconds
        self.power_on_seconds = power_on_seconds
        self.clock = clock
        self.pan = _Axis(0, 0)
        self.tilt = _Axis(0, 0)
        self.zoom = _Axis(0, 0)
        self.autofocus = True
        self.power = True
        self._jobs: dict[int, _Job] = {}  # running commands by job id
        self._withdrawn: set[int] = set()  # scheduled Completions that must not be sent
        self._ids = itertools.count(1)
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

    @property
    def sockets(self) -> dict[int, float]:
        """Busy sockets now: socket -> end time (monotonic s) of the command holding it."""
        now = self.clock()
        with self._lock:
            return {j.socket: j.end for j in self._jobs.values() if j.end > now}

    def frame(self) -> np.ndarray:
        """What the camera sees now (needs a renderer)."""
        if self.renderer is None:
            raise RuntimeError("this simulated camera has no renderer")
        return self.renderer(self.pose())

    def frame_source(self) -> CallableFrameSource:
        """A FrameSource (``read() -> ndarray``) rendering the current pose."""
        return CallableFrameSource(self.frame)

    def completion_withdrawn(self, job: int) -> bool:
        """True if the scheduled Completion of ``job`` must not be sent (its command was cancelled,
        interrupted or cleared before it finished). Asked by a twin just before the write."""
        with self._lock:
            if job in self._withdrawn:
                self._withdrawn.discard(job)
                return True
            return False

    # -- reply packets
    def _hdr(self) -> int:
        return (self.address + 8) << 4

    def _ack(self, s: int) -> bytes:
        return bytes([self._hdr(), 0x40 | s, 0xFF])

    def _done(self, s: int) -> bytes:
        return bytes([self._hdr(), 0x50 | s, 0xFF])

    def error(self, socket: int, code: int) -> bytes:
        return bytes([self._hdr(), 0x60 | socket, code, 0xFF])

    def _inq(self, data: bytes) -> Reply:
        return 0.0, bytes([self._hdr(), 0x50]) + data + b"\xff", None

    # -- sockets and jobs
    def _reap(self, now: float) -> None:
        for jid in [j for j, job in self._jobs.items() if job.end <= now]:
            del self._jobs[jid]

    def _end(self, now: float, actuator: str | None = None, complete: bool = False) -> list[Reply]:
        """End the running commands on ``actuator`` (all when None) now: their scheduled Completion is
        withdrawn; with ``complete`` each gets its Completion at once instead."""
        self._reap(now)
        out: list[Reply] = []
        for jid, job in list(self._jobs.items()):
            if actuator is None or job.actuator == actuator:
                del self._jobs[jid]
                self._withdrawn.add(jid)
                if complete:
                    out.append((0.0, self._done(job.socket), None))
        return out

    def _run(self, now: float, seconds: float, actuator: str | None, before: list[Reply] | None = None) -> list[Reply]:
        """Take a free socket for a command lasting ``seconds``: ACK now, Completion after ``seconds``."""
        self._reap(now)
        busy = {j.socket for j in self._jobs.values()}
        free = [s for s in range(1, SOCKETS + 1) if s not in busy]
        if not free:
            return [*(before or []), (0.0, self.error(0, 0x03), None)]
        jid = next(self._ids)
        self._jobs[jid] = _Job(free[0], now + seconds, actuator)
        return [*(before or []), (0.0, self._ack(free[0]), None), (seconds, self._done(free[0]), jid)]

    def _not_executable(self, now: float) -> list[Reply]:
        self._reap(now)
        busy = {j.socket for j in self._jobs.values()}
        socket = next((s for s in range(1, SOCKETS + 1) if s not in busy), 0)
        return [(0.0, self.error(socket, 0x41), None)]

    # -- requests
    def handle(self, packet: bytes) -> list[Reply]:
        """Execute one request; returns (delay s, reply bytes, completion job id or None) in send order."""
        with self._lock:
            self.log.append(packet)
            return self._handle(packet, self.clock())

    def _handle(self, p: bytes, now: float) -> list[Reply]:
        syntax: list[Reply] = [(0.0, self.error(0, 0x02), None)]
        if len(p) < 3 or p[-1] != 0xFF:
            return syntax
        if p[0] == 0x88:
            if p[1:] == b"\x30\x01\xff":
                self.address = 1
                return [(0.0, bytes([0x88, 0x30, 0x02, 0xFF]), None)]
            if p[1:] == b"\x01\x00\x01\xff":
                self._clear(now)
                return [(0.0, p, None)]
            return []
        if p[0] != 0x80 | self.address:
            return []  # not for us (a daisy chain would pass it on)
        body = p[1:-1]
        if body == b"\x01\x00\x01":  # IF_Clear: aborts everything, no Completion for aborted commands
            self._clear(now)
            return [(0.0, self._done(0), None)]
        if len(body) == 1 and body[0] & 0xF0 == 0x20:
            return self._cancel(now, body[0] & 0x0F)
        if body[:1] == b"\x09":
            return self._inquiry(now, body) or syntax
        if body[:1] != b"\x01":
            return syntax
        if body[:3] == b"\x01\x04\x00" and len(body) == 4 and body[3] in (0x02, 0x03):
            return self._power(now, body[3] == 0x02)
        if not self.power:
            return self._not_executable(now) if self._known_command(body) else syntax
        return self._command(now, body) or syntax

    def _known_command(self, body: bytes) -> bool:
        return body[:3] in (b"\x01\x06\x01", b"\x01\x06\x02", b"\x01\x06\x03", b"\x01\x06\x04", b"\x01\x06\x05",
                            b"\x01\x04\x07", b"\x01\x04\x47", b"\x01\x04\x38")

    def _cancel(self, now: float, socket: int) -> list[Reply]:
        self._reap(now)
        for jid, job in list(self._jobs.items()):
            if job.socket == socket:
                del self._jobs[jid]
                self._withdrawn.add(jid)
                self._freeze(now, job.actuator)
                return [(0.0, self.error(socket, 0x04), None)]
        return [(0.0, self.error(socket, 0x05), None)]

    def _power(self, now: float, on: bool) -> list[Reply]:
        if not on:
            self._clear(now)
            self.power = False
            return self._run(now, 0.0, None)
        seconds = 0.0 if self.power else self.time_scale * self.power_on_seconds
        self.power = True
        return self._run(now, seconds, None)

    def _inquiry(self, now: float, body: bytes) -> list[Reply]:
        m = self.model
        if body == b"\x09\x06\x12":  # Pan-tiltPosInq
            return [self._inq(encode_nibbles(self.pan.at(now), m.pan_nibbles) + encode_nibbles(self.tilt.at(now), 4))]
        if body == b"\x09\x04\x47":  # CAM_ZoomPosInq
            return [self._inq(encode_nibbles(self.zoom.at(now), 4, signed=False))]
        if body == b"\x09\x04\x00":  # CAM_PowerInq: 02 on, 03 off
            return [self._inq(bytes([0x02 if self.power else 0x03]))]
        if body == b"\x09\x04\x38":  # CAM_FocusModeInq: 02 auto, 03 manual
            return [self._inq(bytes([0x02 if self.autofocus else 0x03]))]
        if body == b"\x09\x06\x11":  # Pan-tiltMaxSpeedInq
            return [self._inq(bytes([m.max_pan_speed, m.max_tilt_speed]))]
        if body == b"\x09\x00\x02":  # CAM_VersionInq: y0 50 gg gg hh hh jj jj kk FF
            data = b"".join(v.to_bytes(2, "big") for v in (VENDOR_SONY, TWIN_MODEL_CODE, TWIN_ROM_VERSION))
            return [self._inq(data + bytes([SOCKETS]))]
        return []

    def _command(self, now: float, body: bytes) -> list[Reply]:
        m = self.model
        if body[:3] in (b"\x01\x06\x02", b"\x01\x06\x03") and len(body) == 5 + m.pan_nibbles + 4:
            vv, ww = body[3], body[4]
            try:
                pan = decode_nibbles(body[5:5 + m.pan_nibbles])
                tilt = decode_nibbles(body[5 + m.pan_nibbles:])
            except ViscaProtocolError:
                return []
            if not self._speeds_ok(vv, ww):
                return []
            if body[2] == 0x03:  # relative: from where the head is now, stopping at the limits
                pan = min(max(self.pan.at(now) + pan, m.pan_min), m.pan_max)
                tilt = min(max(self.tilt.at(now) + tilt, m.tilt_min), m.tilt_max)
            elif not (m.pan_min <= pan <= m.pan_max and m.tilt_min <= tilt <= m.tilt_max):
                return []
            return self._move(now, pan, tilt, vv, ww)
        if body[:3] == b"\x01\x06\x01" and len(body) == 7:
            return self._drive(now, *body[3:7])
        if body in (b"\x01\x06\x04", b"\x01\x06\x05"):  # home, reset
            return self._move(now, 0, 0, m.max_pan_speed, m.max_tilt_speed)
        if body[:3] == b"\x01\x04\x47" and len(body) == 7:  # zoom direct
            try:
                z = decode_nibbles(body[3:], signed=False)
            except ViscaProtocolError:
                return []
            if not 0 <= z <= m.zoom_max:
                return []
            return self._zoom_to(now, z, 7, lasting=True)
        if body[:3] == b"\x01\x04\x07" and len(body) == 4:
            return self._zoom_drive(now, body[3])
        if body in (b"\x01\x04\x38\x02", b"\x01\x04\x38\x03"):  # focus auto / manual
            self.autofocus = body[3] == 0x02
            return self._run(now, 0.0, None)
        return []

    def _speeds_ok(self, vv: int, ww: int) -> bool:
        return 1 <= vv <= self.model.max_pan_speed and 1 <= ww <= self.model.max_tilt_speed

    def _move(self, now: float, pan: int, tilt: int, vv: int, ww: int) -> list[Reply]:
        m = self.model
        before = self._end(now, PANTILT, complete=True)
        dp = pan - self.pan.at(now)
        dt = tilt - self.tilt.at(now)
        seconds = self.time_scale * m.move_seconds(dp, dt, vv, ww)
        self.pan.go(pan, now, seconds)
        self.tilt.go(tilt, now, seconds)
        return self._run(now, seconds, PANTILT, before)

    def _drive(self, now: float, vv: int, ww: int, dp: int, dt: int) -> list[Reply]:
        """Pan-tiltDrive: pan 01 left / 02 right / 03 none, tilt 01 up / 02 down / 03 none; 03 03 = Stop.

        Runs until Stop or the range limit; the command itself completes at once."""
        m = self.model
        if not self._speeds_ok(vv, ww) or dp not in (1, 2, 3) or dt not in (1, 2, 3):
            return []
        before = self._end(now, PANTILT, complete=True)
        for axis, direction, lo, hi, speed, per_deg in (
                (self.pan, dp, m.pan_min, m.pan_max, m.pan_speed(vv), m.pan_counts_per_deg),
                (self.tilt, dt, m.tilt_min, m.tilt_max, m.tilt_speed(ww), m.tilt_counts_per_deg)):
            if direction == 3:
                axis.freeze(now)
                continue
            # + pan = right, + tilt = up (protocols.md 1.8): pan 01 (left) and tilt 02 (down) go to the minimum
            target = lo if (axis is self.pan) == (direction == 1) else hi
            axis.go(target, now, self.time_scale * abs(target - axis.at(now)) / per_deg / speed)
        return self._run(now, 0.0, None, before)

    def _zoom_seconds(self, dz: float, speed: int) -> float:
        """Twin's zoom timing: the optical range in ``zoom_seconds`` at speed 7, 8/(p+1) times longer at p."""
        full = max(self.model.zoom_optical_tele, 1)
        return self.time_scale * self.zoom_seconds * abs(dz) / full * 8.0 / (speed + 1)

    def _zoom_to(self, now: float, z: int, speed: int, lasting: bool) -> list[Reply]:
        before = self._end(now, ZOOM, complete=True)
        seconds = self._zoom_seconds(z - self.zoom.at(now), speed)
        self.zoom.go(z, now, seconds)
        return self._run(now, seconds if lasting else 0.0, ZOOM if lasting else None, before)

    def _zoom_drive(self, now: float, code: int) -> list[Reply]:
        """CAM_Zoom 00 stop, 02/03 tele/wide at the standard speed (p = 3), 2p/3p variable (p 0..7)."""
        if code == 0x00:
            before = self._end(now, ZOOM, complete=True)
            self.zoom.freeze(now)
            return self._run(now, 0.0, None, before)
        if code in (0x02, 0x03):
            code = (0x20 if code == 0x02 else 0x30) | 3
        if code & 0xF0 not in (0x20, 0x30) or code & 0x0F > 7:
            return []
        target = self.model.zoom_max if code & 0xF0 == 0x20 else 0
        return self._zoom_to(now, target, code & 0x0F, lasting=False)

    def _freeze(self, now: float, actuator: str | None) -> None:
        if actuator in (PANTILT, None):
            self.pan.freeze(now)
            self.tilt.freeze(now)
        if actuator in (ZOOM, None):
            self.zoom.freeze(now)

    def _clear(self, now: float) -> None:
        self._end(now)
        self._freeze(now, None)
