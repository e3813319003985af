"""A simulated VISCA-over-IP camera on a UDP socket bound to 127.0.0.1.

Serves :class:`fgloc.drivers.twins.visca_emulator.ViscaCameraEmulator` with the real
datagrams: RESET handling, sequence-number checking (a repeat of the last
executed number gets ``0F 01`` and is not executed again, like a Sony SRG), replies
echoing the request's sequence number, and the shared fault injection. A disconnect
closes the socket (the driver sees ICMP "connection refused") and rebinds the same
port later.

Payload types, as forgiving as SRG firmware: an inquiry is answered whether it comes
as ``01 10`` (Sony's document) or as ``01 00`` (what SRG firmware also accepts and
clients rely on); ``inquiry_types`` narrows that to model a stricter camera. A
command sent as ``01 10`` and any other type get ``0F 02`` (message-type abnormality).

``reply_port``: several cameras of the family send every reply to that fixed UDP
port on the controller (52381) instead of the sender's port; set it to model them.
"""

from __future__ import annotations

import socket
import threading
import time

from fgloc.drivers.ptz_units import VISCA_IP_GENERIC, CameraModel
from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.pty_twin import ScheduledReplies
from fgloc.drivers.twins.visca_camera import Renderer, ViscaCameraEmulator, apply_reply_faults
from fgloc.drivers.visca.codec import is_inquiry
from fgloc.drivers.visca.errors import ViscaProtocolError
from fgloc.drivers.visca.ip import (
    CONTROL_ACK,
    CONTROL_RESET,
    ERROR_MESSAGE_TYPE,
    ERROR_SEQUENCE,
    TYPE_COMMAND,
    TYPE_CONTROL,
    TYPE_CONTROL_REPLY,
    TYPE_INQUIRY,
    TYPE_REPLY,
    decode_message,
    encode_message,
)


class ViscaIpTwin:
    """UDP VISCA camera on ``127.0.0.1:port`` (ephemeral by default). Context manager."""

    def __init__(self, emulator: ViscaCameraEmulator | None = None, faults: FaultConfig | None = None,
                 model: CameraModel = VISCA_IP_GENERIC, time_scale: float = 0.0,
                 renderer: Renderer | None = None, port: int = 0, reply_port: int | None = None,
                 inquiry_types: tuple[int, ...] = (TYPE_INQUIRY, TYPE_COMMAND)) -> None:
        self.reply_port = reply_port
        self.inquiry_types = inquiry_types
        self.emulator = emulator or ViscaCameraEmulator(model, time_scale=time_scale, renderer=renderer)
        self.faults = FaultInjector(faults)
        self._sock = self._bind(port)
        self.port = self._sock.getsockname()[1]
        self._out: ScheduledReplies[tuple[bytes, tuple[str, int], int | None]] = ScheduledReplies()
        self._last_sequence: int | None = None
        self._stop = threading.Event()
        self._reconnect_at: float | None = None
        self._down = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._serve, name="visca-ip-twin", daemon=True)
        self._thread.start()

    @staticmethod
    def _bind(port: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.02)
        return sock

    @property
    def url(self) -> str:
        return f"udp://127.0.0.1:{self.port}"

    def disconnect(self, reconnect_after: float | None = None) -> None:
        """Camera off the network: close the socket; rebind after ``reconnect_after`` s (never if None)."""
        with self._lock:
            self._down = True
            self._sock.close()
            self._out.clear()
            self._reconnect_at = None if reconnect_after is None else time.monotonic() + reconnect_after

    def _serve(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            if self._down:
                if self._reconnect_at is not None and now >= self._reconnect_at:
                    with self._lock:
                        self._sock = self._bind(self.port)
                        self._down = False
                        self._reconnect_at = None
                        self._last_sequence = None
                else:
                    self._stop.wait(0.01)
                continue
            due = self._out.next_due()
            sock = self._sock
            sock.settimeout(0.02 if due is None else min(0.02, max(1e-3, due - now)))
            try:
                data, peer = sock.recvfrom(2048)
            except (TimeoutError, BlockingIOError):
                data, peer = None, None
            except OSError:
                if self._stop.is_set() or self._down:
                    continue
                data, peer = None, None
            if data is not None:
                self._handle(data, peer)
            for payload, addr, job in self._out.pop_due(time.monotonic()):
                if job is not None and self.emulator.completion_withdrawn(job):
                    continue  # the command was cancelled or interrupted: no Completion
                try:
                    self._sock.sendto(payload, addr)
                except OSError:
                    pass

    def _reply(self, due: float, payload_type: int, sequence: int, payload: bytes, peer: tuple[str, int],
               job: int | None = None) -> None:
        to = peer if self.reply_port is None else (peer[0], self.reply_port)
        self._out.put(due, (encode_message(payload_type, sequence, payload), to, job))

    def _handle(self, data: bytes, peer: tuple[str, int]) -> None:
        try:
            msg = decode_message(data)
        except ViscaProtocolError:
            return
        now = time.monotonic()
        if msg.payload_type == TYPE_CONTROL:
            if msg.payload == CONTROL_RESET:
                self._last_sequence = None
                self._reply(now, TYPE_CONTROL_REPLY, msg.sequence, CONTROL_ACK, peer)
            return
        allowed = self.inquiry_types if is_inquiry(msg.payload) else (TYPE_COMMAND,)
        if msg.payload_type not in allowed:
            self._reply(now, TYPE_CONTROL_REPLY, msg.sequence, ERROR_MESSAGE_TYPE, peer)
            return
        if msg.sequence == self._last_sequence:
            self._reply(now, TYPE_CONTROL_REPLY, msg.sequence, ERROR_SEQUENCE, peer)
            return
        if self.faults.count_request():
            self.disconnect(self.faults.config.reconnect_after)
            return
        self._last_sequence = msg.sequence
        for due, reply, job in apply_reply_faults(self.faults, self.emulator, msg.payload, now):
            self._reply(due, TYPE_REPLY, msg.sequence, reply, peer, job)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            self._sock.close()
        except OSError:
            pass

    def __enter__(self) -> ViscaIpTwin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
