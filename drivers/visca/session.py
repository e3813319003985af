"""A VISCA session: one command at a time on a link, replies matched by socket, with retries.

Waits for ACK-or-error, then for the Completion *on the ACKed socket* (stale packets
of other sockets are skipped); inquiries wait for ``y0 50 data FF``; timeouts are
retried (all commands used here are idempotent absolute commands, so a resend is
safe); every error reply raises a :class:`fgloc.drivers.visca.errors.ViscaErrorReply`
subclass. All times are seconds.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar

from fgloc.drivers.visca.codec import ReplyKind, cmd_address_set, cmd_if_clear, parse_reply
from fgloc.drivers.visca.errors import (
    CommandBufferFull,
    ViscaDisconnected,
    ViscaError,
    ViscaProtocolError,
    ViscaTimeout,
    error_for,
)

if TYPE_CHECKING:
    from fgloc.drivers.visca.codec import Reply

log = logging.getLogger(__name__)
_T = TypeVar("_T")


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
