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

Two commands at once (:meth:`ViscaSession.commands_at_once`, protocols.md 1.4-1.5 and pitfall 4):
the camera has two command sockets, so a pan-tilt move and a zoom can run together. Each is sent
only after the previous one's ACK (pitfall 3), then the Completions are matched by socket in
whatever order they come; every rule above (stray windows, ``confirm()``, error classes) holds
per socket. Whatever cannot run that way falls back to the one-at-a-time path (see the method).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.visca.codec import ReplyKind, cmd_address_set, cmd_if_clear, cmd_power_inquiry, parse_reply
from fgloc.drivers.visca.errors import (
    CommandBufferFull,
    ViscaDisconnected,
    ViscaErrorReply,
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


#: command sockets of a Sony VISCA camera: at most this many commands run at once (protocols.md 1.4)
SOCKETS = 2


@dataclass(frozen=True)
class TogetherCommand:
    """One command of :meth:`ViscaSession.commands_at_once`, with the arguments of
    :meth:`ViscaSession.command`: ``completion_timeout`` (s, None = the completion margin) counts
    from its ACK; ``confirm()`` decides whether a Completion that may be a stray one is its own."""

    packet: bytes
    completion_timeout: float | None = None
    name: str = ""
    confirm: Callable[[], bool] | None = None

    @property
    def label(self) -> str:
        return self.name or self.packet.hex(" ")


@dataclass
class _Running:
    """A command of :meth:`ViscaSession.commands_at_once` ACKed and waiting for its Completion."""

    command: TogetherCommand
    wait: float  # completion budget, s
    acked_at: float  # monotonic s

    @property
    def deadline(self) -> float:
        return self.acked_at + self.wait


class ViscaSession:
    """One VISCA camera behind a link: sends commands one at a time (or two at once, one per
    command socket) and matches replies by socket."""

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
        wait = self._budget(completion_timeout)
        self._with_reconnect(lambda: self._command(packet, wait, name, confirm))

    def commands_at_once(self, commands: Sequence[TogetherCommand]) -> None:
        """Run up to two commands at once, one in each command socket (e.g. a pan-tilt move and a
        zoom: they must drive different actuators); returns when every one has completed.

        Sends the first, waits for its ACK (``timeouts.ack`` s), sends the second, waits for its
        ACK, then waits for the Completion of every ACKed socket, in either order: a Completion of
        one socket met while waiting for another command's ACK or Completion is kept for it, not
        dropped as stale. Each Completion obeys the rules of :meth:`command` (in its socket's stray
        window it counts only if the command's ``confirm()`` holds); an error reply raises its
        :func:`~fgloc.drivers.visca.errors.error_for` class once no other command is still running.

        Fallbacks (all commands here are idempotent absolute commands, so a resend is safe); each
        runs after every running command has its Completion, through the one-at-a-time path of
        :meth:`command` with its retries:

        * "command buffer full" for a command (a socket still held, e.g. by an abandoned command):
          that command, and any after it, runs then;
        * no ACK in time: that command (its send may still be run by the camera, so it is resent
          as after an ACK timeout in :meth:`command`) and any after it run then;
        * no Completion within a command's ``completion_timeout``: its socket gets a stray window
          and the command runs again then;
        * an ACK on a socket still waiting for its Completion (that Completion was lost on the
          wire): the earlier command runs again then;
        * over a link that tags replies (VISCA over IP) the link keeps only the newest command's
          replies, so the commands run one after another with :meth:`command`.
        """
        todo = list(commands)
        if len(todo) > SOCKETS:
            raise ValueError(f"a VISCA camera has {SOCKETS} command sockets; got {len(todo)} commands at once")
        if len(todo) == 1 or getattr(self.link, "tags_replies", False):
            for c in todo:
                self.command(c.packet, c.completion_timeout, c.name, c.confirm)
            return
        if todo:
            self._with_reconnect(lambda: self._at_once(todo))

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
                 confirm: Callable[[], bool] | None = None, unanswered: bool = False) -> None:
        """Send, wait for ACK (``ack`` s), then for the Completion on that socket; timeouts resend.
        ``unanswered``: the packet was sent already and no ACK was read, so this first send is a
        resend after an ACK timeout."""
        t = self.timeouts
        acked = not unanswered  # a resend after an ACKed attempt is a new message, not a retransmission
        echoed = False  # a send whose ACK we never read may still be run by the camera (module doc)

        def attempt(n: int) -> None:
            nonlocal acked, echoed
            retransmit = (n > 0 or unanswered) and not acked
            echoed = echoed or (retransmit and not getattr(self.link, "tags_replies", False))
            self._send(packet, retransmit=retransmit)
            acked = False
            socket = self._await_ack(name)
            acked = True
            acked_at = time.monotonic()
            try:
                self._await_completion(socket, completion_timeout, name, confirm, echoed)
            except ViscaTimeout:  # the camera may still send this command's Completion later
                self._owe(socket, acked_at + 2 * completion_timeout)
                raise

        def retryable(error: BaseException) -> bool:  # buffer full answers in place of the ACK only
            return isinstance(error, ViscaTimeout) or (isinstance(error, CommandBufferFull) and not acked)

        def wait(failures: int, error: BaseException) -> float:
            return t.buffer_full_wait if isinstance(error, CommandBufferFull) else 0.0

        RetryPolicy(t.retries + 1, retryable, wait).call(attempt, self._count_retry)
        if echoed and confirm is None:  # with a confirm, its inquiry has drained the wire (_believe)
            self._drain(name)

    def _at_once(self, commands: list[TogetherCommand]) -> None:
        """:meth:`commands_at_once` for one connection (a reconnect runs it again from the start)."""
        running: dict[int, _Running] = {}  # socket -> the command ACKed there, awaiting its Completion
        later: list[tuple[TogetherCommand, bool]] = []  # (command, sent without an ACK read): fallbacks
        failure: ViscaErrorReply | None = None
        try:
            for c in commands:
                if later or failure is not None:  # keep the order: nothing runs beside a fallback
                    if failure is None:
                        later.append((c, False))
                    continue
                self._send(c.packet)
                try:
                    socket = self._await_ack_beside(running, c.label)
                except ViscaTimeout:
                    self.stats.retries += 1
                    log.info("camera %d: no ACK to %s; it runs again alone", self.address, c.label)
                    later.append((c, True))
                    continue
                except CommandBufferFull:
                    self.stats.retries += 1
                    log.info("camera %d: %s refused (command buffer full); it runs again once the running "
                             "command is done", self.address, c.label)
                    later.append((c, False))
                    continue
                except ViscaErrorReply as exc:
                    failure = exc
                    continue
                if socket in running:  # the camera freed that socket, so the command there is over
                    before = running.pop(socket)
                    theirs = [r for r in self._held if r.socket == socket]
                    self._held[:] = [r for r in self._held if r.socket != socket]
                    errors = [r for r in theirs if r.kind is ReplyKind.ERROR]
                    if errors:
                        failure = error_for(errors[0].error_code, socket, before.command.label)
                    elif not theirs:  # its Completion was lost on the wire: run it again to be sure
                        self.stats.retries += 1
                        later.append((before.command, False))
                running[socket] = _Running(c, self._budget(c.completion_timeout), time.monotonic())
            while running:
                socket, r = min(running.items(), key=lambda item: item[1].deadline)
                reply = self._next(r.deadline)
                if reply is None:
                    del running[socket]
                    self.stats.timeouts += 1
                    self._owe(socket, r.acked_at + 2 * r.wait)
                    if failure is None:
                        self.stats.retries += 1
                        log.info("camera %d: no completion for %s within %.1f s; it runs again alone",
                                 self.address, r.command.label, r.wait)
                        later.append((r.command, False))
                    continue
                mine = running.get(reply.socket)
                if mine is None or reply.kind not in (ReplyKind.COMPLETION, ReplyKind.ERROR):
                    self.stats.stale += 1
                    continue
                if reply.kind is ReplyKind.ERROR:
                    del running[reply.socket]
                    failure = failure or error_for(reply.error_code, reply.socket, mine.command.label)
                    continue
                if self._believe(reply.socket, mine.command.confirm, mine.command.label, keep_held=True):
                    del running[reply.socket]
        except BaseException:
            for socket, r in running.items():  # abandoned: their Completions may still come
                self._owe(socket, r.acked_at + 2 * r.wait)
            raise
        finally:  # replies held past the last Completion came before it and belong to nobody here
            self.stats.stale += len(self._held)
            self._held.clear()
        if failure is not None:
            raise failure
        for c, unanswered in later:
            self._command(c.packet, self._budget(c.completion_timeout), c.label, c.confirm, unanswered)

    def _await_ack_beside(self, running: dict[int, _Running], name: str) -> int:
        """The socket of the ACK to the command just sent while the commands in ``running`` run.

        A Completion or error on a running socket met meanwhile is kept (in ``_held``) for the
        Completion wait, where it is checked like any other (stray window, ``confirm()``). An ACK
        on a running socket is returned like any other: the caller sorts out that socket."""
        deadline = time.monotonic() + self.timeouts.ack
        kept: list[Reply] = []
        try:
            while True:
                reply = self._next(deadline)
                if reply is None:
                    self.stats.timeouts += 1
                    raise ViscaTimeout(f"no ACK from camera {self.address} to {name}")
                if reply.kind in (ReplyKind.COMPLETION, ReplyKind.ERROR) and reply.socket in running:
                    kept.append(reply)
                    continue
                if reply.kind is ReplyKind.ACK:
                    return reply.socket
                if reply.kind is ReplyKind.ERROR:
                    raise error_for(reply.error_code, reply.socket, name)
                self.stats.stale += 1
        finally:
            self._held[:0] = kept

    def _budget(self, completion_timeout: float | None) -> float:
        """A command's Completion budget (s): its own, else the completion margin."""
        return completion_timeout if completion_timeout is not None else self.timeouts.completion_margin

    def _owe(self, socket: int, until: float) -> None:
        """Open (or extend) ``socket``'s stray window until ``until`` (monotonic s), unless the link tags replies."""
        if not getattr(self.link, "tags_replies", False):
            self.stray[socket] = max(self.stray.get(socket, 0.0), until)

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

    def _believe(self, socket: int, confirm: Callable[[], bool] | None, name: str, echoed: bool = False,
                 keep_held: bool = False) -> bool:
        """Is a Completion on ``socket`` ours? Yes outside a stray window; inside (or after a resend,
        ``echoed``) if ``confirm()`` holds. ``keep_held``: another command is still running, so the
        replies confirm's inquiry met (maybe its Completion) are re-read afterwards even when it holds."""
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
        if ok:
            if not keep_held:  # the command is done: what confirm's inquiry met came before its answer
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
