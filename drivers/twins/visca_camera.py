"""A simulated VISCA PTZ camera on a pseudo-terminal, and the reply plumbing every VISCA twin shares.

The camera itself (state machine, sockets, cancel, interruption, power, drive, zoom) is
:class:`fgloc.drivers.twins.visca_emulator.ViscaCameraEmulator`, re-exported here.
:class:`ViscaSerialTwin` serves it on a pty (pyserial opens :attr:`port`) from a
background thread with fault injection; :mod:`fgloc.drivers.twins.visca_ip_camera` and
:mod:`fgloc.drivers.twins.sony_cgi_camera` serve the same emulator over UDP and HTTP.
A scheduled Completion is written only if the emulator has not withdrawn it meanwhile
(cancel, interruption, IF_Clear, power off): no late Completion of a stopped command.
"""

from __future__ import annotations

import time

from fgloc.drivers.ptz_units import EVI_D100, CameraModel
from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.pty_port import PtyPort
from fgloc.drivers.twins.pty_twin import PtyTwin, ScheduledReplies
from fgloc.drivers.twins.visca_emulator import HeadPose, Renderer, ViscaCameraEmulator
from fgloc.drivers.visca.packets import PacketSplitter

__all__ = ["HeadPose", "Renderer", "ViscaCameraEmulator", "ViscaSerialTwin", "apply_reply_faults",
           "is_socket_request", "write_paced", "WireTime"]


def is_socket_request(packet: bytes) -> bool:
    """A command or inquiry addressed to one camera (the requests error injection applies to)."""
    return (len(packet) >= 4 and packet[0] & 0xF8 == 0x80 and packet[0] != 0x88
            and packet[1] in (0x01, 0x09) and packet[1:4] != b"\x01\x00\x01")


def apply_reply_faults(faults: FaultInjector, emulator: ViscaCameraEmulator, request: bytes,
                       now: float) -> list[tuple[float, bytes, int | None]]:
    """Run ``request`` through error injection, the emulator and per-reply faults -> [(due, bytes, job)].

    ``job`` is the emulator's id of a Completion (ask :meth:`ViscaCameraEmulator.completion_withdrawn`
    before writing it), None for any other reply."""
    if is_socket_request(request):
        code = faults.request_error()
        if code is not None:
            socket = 0 if code in (0x02, 0x03) or request[1] == 0x09 else 1
            return [(now, emulator.error(socket, code), None)]
    out: list[tuple[float, bytes, int | None]] = []
    for delay, reply, job in emulator.handle(request):
        sent = faults.faulted_reply(reply, can_be_slow=job is not None)
        if sent is not None:
            out.append((now + (delay + sent[0]), sent[1], job))
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


def write_paced(port: PtyPort, out: ScheduledReplies[tuple[bytes, int | None]], wire: WireTime,
                sent: list[bytes] | None = None, emulator: ViscaCameraEmulator | None = None) -> None:
    """Write every due reply, one at a time, respecting the line's transmit time.

    A Completion the ``emulator`` has withdrawn (cancelled or interrupted command) is skipped.
    Each reply is appended to ``sent`` (when given) *before* it is written, so any reply
    the driver has read is already in ``sent``: an ordering witness that needs no clock."""
    while True:
        now = time.monotonic()
        if not wire.can_send(now):
            return
        item = out.pop_one(now)
        if item is None:
            return
        data, job = item
        if job is not None and emulator is not None and emulator.completion_withdrawn(job):
            continue
        if sent is not None:
            sent.append(data)
        port.write(data)
        wire.sent(data, now)


class ViscaSerialTwin(PtyTwin[tuple[bytes, "int | None"]]):
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
            for due_at, reply, job in apply_reply_faults(self.faults, self.emulator, packet, arrived):
                self._out.put(due_at, (reply, job))

    def _write_due(self) -> None:
        write_paced(self._pty, self._out, self.wire, self.sent, self.emulator)
