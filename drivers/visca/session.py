"""A VISCA session: one command at a time on a link, replies matched by socket, with retries.

Waits for ACK-or-error, then for the Completion *on the ACKed socket* (stale packets
of other sockets are skipped); inquiries wait for ``y0 50 data FF``; timeouts are
retried (all commands used here are idempotent absolute commands, so a resend is
safe); every error reply raises a :class:`fgloc.drivers.visca.errors.ViscaErrorReply`
subclass. All times are seconds.

Which Completion is ours (socket and order, protocols.md 1.4-1.5): only one that arrives
*after* our ACK, on the ACKed socket. That is not enough when the camera still owes a
Completion on that socket: a command we gave up on (no Completion within its budget) or
cancelled (Sony: no Completion follows a cancel, but a firmware that sends it anyway must
not fool us). For such a socket the session opens a *stray window* (until the abandoned
command's deadline plus its budget, :attr:`ViscaSession.stray`); a Completion on it inside
the window is taken only if the command's ``confirm()`` check (the head is at the target)
holds, otherwise it is counted in ``stats.stray`` and the wait goes on.

A resend after an ACK timeout is the other source of strays: the first send may have reached the
camera (the host stalled, or only the ACK was late), which then runs the command twice and
answers twice. The ACK the driver reads may then be the first send's, and its Completion may come
early (the resend interrupted the move) or the resend's ACK and Completion may still be on the wire
after the command returned, where the next command would take them for its own and return before
the head moved: one reply behind for every later command. So after such a resend a Completion on
either socket counts only if ``confirm()`` holds, and once the command is done the wire is
drained by an inquiry, whose answer comes after every reply the camera sent before it: the
``confirm()`` read-back that accepted the Completion (what it met is dropped as stale), or a
power inquiry for a command without a check. A link whose replies
carry their request's tag (VISCA over IP: the sequence number) already drops every reply to an
earlier request, so over such a link no stray window is opened.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.visca.codec import ReplyKind, cmd_address_set, cmd_if_clear, cmd_power_inquiry, parse_reply
from fgloc.drivers.visca.errors import (
    CommandBufferFull,
    ViscaDisconnected,
    ViscaGarbledReply,
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

    # Optional class attribute ``tags_replies = True``: every reply carries its request's tag (the
    # VISCA-over-IP sequence number) and the link drops replies to earlier requests itself, so no
    # Completion can be a stray one and the session opens no stray windows.



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
    stray: int = 0  # Completions refused because they belong to an abandoned or cancelled command


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
        #: socket -> monotonic time until which a Completion there may be a stray one (see module doc)
        self.stray: dict[int, float] = {}
        self._held: list[Reply] = []  # replies met during a confirm() inquiry, re-read afterwards
        self._holding = False

    # -- public
    def command(self, packet: bytes, completion_timeout: float | None = None, name: str = "",
                confirm: Callable[[], bool] | None = None) -> None:
        """Send a command; wait for its ACK, then its Completion on the same socket.

        ``completion_timeout`` (s) defaults to the completion margin. A timeout at
        either stage resends the command (idempotent commands only). ``confirm()``
        (e.g. "the head reads back the target") decides whether a Completion that may be
        a stray one (see the module doc) is ours; without it such a Completion is taken.
        """
        name = name or packet.hex(" ")
        wait = completion_timeout if completion_timeout is not None else self.timeouts.completion_margin
        self._with_reconnect(lambda: self._command(packet, wait, name, confirm))

    def cancel(self, socket: int) -> bool:
        """Command cancel ``8x 2y FF``: True if the camera cancelled a command (``z0 6y 04 FF``),
        False if the socket was empty (``z0 6y 05 FF``). Either way the socket gets a stray window
        of ``completion_margin`` s: a Completion there is checked before it is believed."""
        from fgloc.drivers.visca.codec import cmd_cancel

        def attempt(n: int) -> bool:
            self._send(cmd_cancel(self.address, socket), n > 0)
            deadline = time.monotonic() + self.timeouts.ack
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    raise ViscaTimeout(f"no reply from camera {self.address} to cancel socket {socket}")
                if reply.kind is ReplyKind.ERROR and reply.socket == socket and reply.error_code in (0x04, 0x05):
                    if not getattr(self.link, "tags_replies", False):
                        until = time.monotonic() + self.timeouts.completion_margin
                        self.stray[socket] = max(self.stray.get(socket, 0.0), until)
                    return reply.error_code == 0x04
                if reply.kind is ReplyKind.ERROR and reply.socket in (0, socket):
                    raise error_for(reply.error_code, reply.socket, f"cancel socket {socket}")
                self.stats.stale += 1

        def run() -> bool:
            return RetryPolicy(self.timeouts.retries + 1, ViscaTimeout).call(attempt, self._count_retry)

        return self._with_reconnect(run)

    def inquiry(self, packet: bytes, expect_len: int, name: str = "", nibbles: bool = True) -> bytes:
        """Send an inquiry; return the data bytes of the ``y0 50 data FF`` reply (length checked;
        with ``nibbles`` every data byte must be ``0x0?``, as in position replies)."""
        name = name or packet.hex(" ")
        return self._with_reconnect(lambda: self._inquiry(packet, expect_len, name, nibbles))

    def if_clear(self) -> None:
        """IF_Clear to this camera: waits for ``z0 50 FF`` (no ACK)."""
        self._with_reconnect(lambda: self._if_clear())

    def address_set(self) -> int:
        """Broadcast Address Set; returns the number of cameras on the chain."""
        return self._with_reconnect(self._address_set)

    # -- internals
    def _with_reconnect(self, op: Callable[[], _T]) -> _T:
        """``op()``; after a disconnect wait ``reconnect_wait`` s, reopen the link, re-initialise, run it again."""

        def attempt(n: int) -> _T:
            if n:
                self.link.reopen()
                if self._on_reconnect is not None:
                    self._on_reconnect()
            return op()

        def before_retry(failures: int, error: BaseException) -> None:
            self.stats.reconnects += 1
            log.warning("VISCA link lost (%s); reconnecting (%d/%d)", error, failures, self.reconnects)

        with self._lock:
            policy = RetryPolicy(self.reconnects + 1, ViscaDisconnected, self.reconnect_wait)
            return policy.call(attempt, before_retry)

    def _count_retry(self, failures: int, error: BaseException) -> None:
        self.stats.retries += 1
        log.debug("camera %d: retrying after: %s", self.address, error)

    def _send(self, packet: bytes, retransmit: bool = False) -> None:
        self.stats.sent += 1
        self.link.send(packet, retransmit)

    def _next(self, deadline: float) -> Reply | None:
        """Next well-formed reply from our camera before ``deadline``; None on timeout."""
        if self._held and not self._holding:
            return self._held.pop(0)
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

    def _command(self, packet: bytes, completion_timeout: float, name: str,
                 confirm: Callable[[], bool] | None = None) -> None:
        """Send, wait for ACK (``ack`` s), then for the Completion on that socket; timeouts resend."""
        t = self.timeouts
        acked = True  # a resend after an ACKed attempt is a new message, not a retransmission
        echoed = False  # a send whose ACK we never read may still be run by the camera (module doc)

        def attempt(n: int) -> None:
            nonlocal acked, echoed
            retransmit = n > 0 and not acked
            echoed = echoed or (retransmit and not getattr(self.link, "tags_replies", False))
            self._send(packet, retransmit=retransmit)
            acked = False
            socket = self._await_ack(name)
            acked = True
            acked_at = time.monotonic()
            try:
                self._await_completion(socket, completion_timeout, name, confirm, echoed)
            except ViscaTimeout:  # the camera may still send this command's Completion later
                if not getattr(self.link, "tags_replies", False):
                    until = acked_at + 2 * completion_timeout
                    self.stray[socket] = max(self.stray.get(socket, 0.0), until)
                raise

        def retryable(error: BaseException) -> bool:  # buffer full answers in place of the ACK only
            return isinstance(error, ViscaTimeout) or (isinstance(error, CommandBufferFull) and not acked)

        def wait(failures: int, error: BaseException) -> float:
            return t.buffer_full_wait if isinstance(error, CommandBufferFull) else 0.0

        RetryPolicy(t.retries + 1, retryable, wait).call(attempt, self._count_retry)
        if echoed and confirm is None:  # with a confirm, its inquiry has drained the wire (_believe)
            self._drain(name)

    def _drain(self, name: str) -> None:
        """After a resend: a power inquiry, whose answer comes after every reply the camera sent
        before it, so the ACK and Completion of a send we never had an answer to are read here
        (counted stale) and not taken by the next command."""
        log.info("camera %d: %s was resent after a late ACK; draining the replies to the first send",
                 self.address, name)
        self._inquiry(cmd_power_inquiry(self.address), 1, "power inquiry (drain)", nibbles=False)

    def _await_ack(self, name: str) -> int:
        """The socket of the ACK; ViscaTimeout after ``timeouts.ack`` s, the error class for an error reply."""
        deadline = time.monotonic() + self.timeouts.ack
        while True:
            reply = self._next(deadline)
            if reply is None:
                self.stats.timeouts += 1
                raise ViscaTimeout(f"no ACK from camera {self.address} to {name}")
            if reply.kind is ReplyKind.ACK:
                return reply.socket
            if reply.kind is ReplyKind.ERROR:
                raise error_for(reply.error_code, reply.socket, name)
            self.stats.stale += 1

    def _await_completion(self, socket: int, timeout: float, name: str,
                          confirm: Callable[[], bool] | None = None, echoed: bool = False) -> None:
        """The Completion (or error) on ``socket`` within ``timeout`` s; other sockets' packets are stale,
        and a Completion in the socket's stray window counts only if ``confirm()`` holds. When
        ``echoed`` (the command was resent after a send we had no ACK to) the ACKed socket may be the
        first send's, so with a ``confirm`` a Completion on any socket counts if ``confirm()`` holds."""
        deadline = time.monotonic() + timeout
        while True:
            reply = self._next(deadline)
            if reply is None:
                self.stats.timeouts += 1
                raise ViscaTimeout(f"no completion from camera {self.address} for {name} within {timeout:.1f} s")
            ours = reply.socket == socket or (echoed and confirm is not None)
            if not ours or reply.kind not in (ReplyKind.COMPLETION, ReplyKind.ERROR):
                self.stats.stale += 1
                continue
            if reply.kind is ReplyKind.COMPLETION:
                if self._believe(reply.socket, confirm, name, echoed):
                    return
                continue
            if reply.socket != socket:  # an error of the first send's socket: the resend's answer may follow
                self.stats.stale += 1
                continue
            raise error_for(reply.error_code, reply.socket, name)

    def _believe(self, socket: int, confirm: Callable[[], bool] | None, name: str, echoed: bool = False) -> bool:
        """Is a Completion on ``socket`` ours? Yes outside a stray window; inside (or after a resend,
        ``echoed``) if ``confirm()`` holds."""
        until = self.stray.get(socket)
        if not echoed and (until is None or time.monotonic() >= until):
            self.stray.pop(socket, None)
            return True
        if confirm is None:
            return True
        self._holding = True  # replies met by confirm's inquiries are re-read afterwards, not dropped
        try:
            ok = confirm()
        finally:
            self._holding = False
        if ok:  # the command is done: what confirm's inquiry met came before its answer, and is stale
            self.stats.stale += len(self._held)
            self._held.clear()
        else:
            self.stats.stray += 1
            log.warning("camera %d: ignoring a Completion on socket %d that is not %s's (a stray one of an "
                        "abandoned, cancelled or resent command)", self.address, socket, name)
        return ok

    def _inquiry(self, packet: bytes, expect_len: int, name: str, nibbles: bool = True) -> bytes:
        """Send an inquiry, wait ``timeouts.inquiry`` s for its data; timeouts and garbled replies ask again
        (after a garbled reply as a new message: the camera got the inquiry, so over IP a resend under
        the same sequence number could only be refused as a repeat)."""
        answered = False

        def attempt(n: int) -> bytes:
            nonlocal answered
            self._send(packet, n > 0 and not answered)
            answered = False
            deadline = time.monotonic() + self.timeouts.inquiry
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    raise ViscaTimeout(f"no reply from camera {self.address} to {name}")
                if reply.kind is ReplyKind.INQUIRY:
                    answered = True
                    if len(reply.data) != expect_len:
                        self.stats.garbled += 1
                        raise ViscaGarbledReply(f"reply to {name} has {len(reply.data)} data bytes, "
                                                f"expected {expect_len}")
                    if nibbles and any(b & 0xF0 for b in reply.data):
                        self.stats.garbled += 1
                        raise ViscaGarbledReply(f"reply to {name} has corrupted nibbles")
                    return reply.data
                if reply.kind is ReplyKind.ERROR and reply.socket == 0:
                    raise error_for(reply.error_code, 0, name)
                if self._holding:
                    self._held.append(reply)
                else:
                    self.stats.stale += 1

        policy = RetryPolicy(self.timeouts.retries + 1, (ViscaTimeout, ViscaGarbledReply, CommandBufferFull))
        return policy.call(attempt, self._count_retry)

    def _if_clear(self) -> None:
        def attempt(n: int) -> None:
            self._send(cmd_if_clear(self.address), n > 0)
            deadline = time.monotonic() + self.timeouts.ack
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    raise ViscaTimeout(f"no reply from camera {self.address} to IF_Clear")
                if reply.kind is ReplyKind.COMPLETION and reply.socket == 0:
                    return
                if reply.kind is ReplyKind.ERROR:
                    raise error_for(reply.error_code, reply.socket, "IF_Clear")
                self.stats.stale += 1

        RetryPolicy(self.timeouts.retries + 1, ViscaTimeout).call(attempt, self._count_retry)

    def _address_set(self) -> int:
        def attempt(n: int) -> int:
            self._send(cmd_address_set())
            deadline = time.monotonic() + self.timeouts.ack
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    raise ViscaTimeout("no reply to Address Set (is the camera on and the cable a crossed VISCA "
                                       "cable?)")
                if reply.kind is ReplyKind.ADDRESS_SET:
                    return reply.data[0] - 1
                self.stats.stale += 1

        return RetryPolicy(self.timeouts.retries + 1, ViscaTimeout).call(attempt, self._count_retry)
