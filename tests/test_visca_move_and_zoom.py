"""A pan-tilt move and a zoom at once in the camera's two command sockets (protocols.md 1.4-1.5,
pitfall 4): ViscaHead.move_and_zoom_counts / ViscaSession.commands_at_once against the twins.

Order is read from the twin's wire logs (``emulator.log``: requests; ``twin.sent``: replies,
appended before each write), never from the clock: a second command's ACK written before the
first Completion proves both commands were in the camera at once."""

from __future__ import annotations

import math
import threading
import time

import pytest

from fgloc.drivers.head_adapter import HeadAdapter
from fgloc.drivers.ptz_units import PositionOutOfRangeError
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.visca_camera import ViscaCameraEmulator, ViscaSerialTwin
from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin
from fgloc.drivers.visca.codec import cmd_pan_tilt_absolute, cmd_power, cmd_zoom_direct
from fgloc.drivers.visca.errors import ViscaTimeout
from fgloc.drivers.visca.head import ViscaHead, open_serial_head
from fgloc.drivers.visca.ip import open_ip_head
from fgloc.drivers.visca.session import SessionStats, Timeouts, TogetherCommand
from tests.test_visca_late_completion import _wait_for

H = bytes.fromhex
ACK1, ACK2, DONE1, DONE2 = H("90 41 FF"), H("90 42 FF"), H("90 51 FF"), H("90 52 FF")
BUFFER_FULL = H("90 60 03 FF")
SPEED = 0x0C  # pan and tilt speed byte: 22 deg/s on the D100, so 150 counts take 0.47 s (twin time)


def _timeouts() -> Timeouts:
    return Timeouts(ack=0.1, inquiry=0.1, completion_margin=0.3, retries=3)


def _ready(head: ViscaHead, twin: ViscaSerialTwin) -> None:
    """Head at (0, 0), wide, known to the driver (so a move asks no position first); fresh stats."""
    head.settings.pan_speed = head.settings.tilt_speed = SPEED
    head.move_to_counts(0, 0)
    head.set_zoom_counts(0)
    head.session.stats = SessionStats()


def _move(pan: int, tilt: int) -> bytes:
    return cmd_pan_tilt_absolute(1, pan, tilt, SPEED, SPEED)


def _pose(twin) -> tuple[int, int, int]:
    p = twin.emulator.pose()  # the camera's own state, read without the driver
    return p.pan_counts, p.tilt_counts, p.zoom_counts


@pytest.mark.parametrize(("target", "done_order"), [
    ((150, 20, 0x800), [DONE2, DONE1]),  # zoom 0.25 s, move 0.47 s: the zoom (socket 2) finishes first
    ((40, -10, 0x3000), [DONE1, DONE2]),  # move 0.13 s, zoom 1.5 s: the move (socket 1) finishes first
], ids=["zoom-finishes-first", "move-finishes-first"])
def test_move_and_zoom_run_at_once_and_completions_are_matched_by_socket(
        target: tuple[int, int, int], done_order: list[bytes]) -> None:
    """Both commands are ACKed (sockets 1 and 2) before either completes; the call returns only
    when both Completions are in, whichever comes first, with no resend, timeout or stale reply."""
    with ViscaSerialTwin(time_scale=1.0) as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        _ready(head, twin)
        n_log, n_sent = len(twin.emulator.log), len(twin.sent)
        head.move_and_zoom_counts(*target)
        sent = twin.sent[n_sent:]  # everything the driver could have read when it returned
        assert _pose(twin) == target
        pan, tilt, zoom = target
        assert twin.emulator.log[n_log:] == [_move(pan, tilt), cmd_zoom_direct(1, zoom)]
        assert sent == [ACK1, ACK2, *done_order], [r.hex(" ") for r in sent]
        s = head.session.stats
        assert (s.timeouts, s.retries, s.stale, s.stray) == (0, 0, 0, 0)
        assert head._last_counts == (pan, tilt)
        assert head.position_counts() == (pan, tilt) and head.zoom_counts() == zoom


def test_move_and_zoom_in_spec_units() -> None:
    """Radians and zoom fraction go through the head's units, like move_to and set_zoom."""
    with ViscaSerialTwin(time_scale=0.2) as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        head.move_and_zoom(math.radians(-45.0), math.radians(20.0), 0.25)
        assert _pose(twin) == (648, 288, 0x1000)
        assert head.position() == pytest.approx((math.radians(-45.0), math.radians(20.0)), abs=1e-3)
        assert head.zoom() == pytest.approx(0.25)
        assert head.concurrent_zoom  # a serial line: the survey zooms during its moves (lever zoom_moves)


def test_a_socket_held_by_an_abandoned_command_makes_the_zoom_wait() -> None:
    """A power-on the driver gave up on still holds socket 1, so the move takes socket 2 and the
    zoom is refused with "command buffer full": the zoom runs once the move is done, alone, and
    both targets are reached."""
    emulator = ViscaCameraEmulator(time_scale=1.0, power_on_seconds=30.0)
    with ViscaSerialTwin(emulator) as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        _ready(head, twin)
        head.session.command(cmd_power(1, False), name="power off")
        head.session.timeouts.retries = 0
        with pytest.raises(ViscaTimeout, match="no completion"):
            head.session.command(cmd_power(1, True), completion_timeout=0.05, name="power on")
        head.session.timeouts.retries = 3
        assert set(emulator.sockets) == {1}
        n_log, n_sent = len(emulator.log), len(twin.sent)
        head.move_and_zoom_counts(150, 20, 0x800)
        sent = twin.sent[n_sent:]
        assert _pose(twin) == (150, 20, 0x800)
        zoom = cmd_zoom_direct(1, 0x800)
        assert emulator.log[n_log:] == [_move(150, 20), zoom, zoom]
        assert sent == [ACK2, BUFFER_FULL, DONE2, ACK2, DONE2], [r.hex(" ") for r in sent]
        assert set(emulator.sockets) == {1}  # the power-on still runs: the refusal was the camera's own


def test_an_injected_buffer_full_for_the_zoom_falls_back_to_one_at_a_time() -> None:
    """The twin answers the zoom (the fourth camera request: position inquiry and move of the
    first move_to_counts, then our move) with "command buffer full" without running it."""
    faults = FaultConfig(error_codes=(0x03,), error_script=["ok", "ok", "ok", "error"])
    with ViscaSerialTwin(time_scale=1.0, faults=faults) as twin, \
            open_serial_head(twin.port, timeouts=_timeouts()) as head:
        head.settings.pan_speed = head.settings.tilt_speed = SPEED
        head.move_to_counts(0, 0)
        n_log, n_sent = len(twin.emulator.log), len(twin.sent)
        head.move_and_zoom_counts(-150, 0, 0x800)
        sent = twin.sent[n_sent:]
        assert twin.faults.counts["error"] == 1
        assert _pose(twin) == (-150, 0, 0x800)
        assert twin.emulator.log[n_log:] == [_move(-150, 0), cmd_zoom_direct(1, 0x800)]  # refused one never ran
        assert sent == [ACK1, BUFFER_FULL, DONE1, ACK1, DONE1], [r.hex(" ") for r in sent]


def test_a_lost_completion_is_resent_alone_after_its_timeout() -> None:
    """The move's Completion is dropped on the wire: the zoom's Completion is still taken for the
    zoom, and after the move's completion timeout the move is sent again (idempotent) and believed
    only because the head reads back its target (its socket is in a stray window then)."""
    with ViscaSerialTwin(time_scale=1.0) as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        _ready(head, twin)
        twin.faults.force("ok", "drop")  # move: ACK sent, Completion dropped
        n_log = len(twin.emulator.log)
        head.move_and_zoom_counts(60, 0, 0x400)
        assert _pose(twin) == (60, 0, 0x400)
        log = twin.emulator.log[n_log:]
        assert log[:3] == [_move(60, 0), cmd_zoom_direct(1, 0x400), _move(60, 0)]
        assert log[3:] == [H("81 09 06 12 FF")]  # the read-back that confirmed the resend's Completion
        s = head.session.stats
        assert (s.timeouts, s.retries, s.stray) == (1, 1, 0)


def test_a_stray_completion_in_the_window_is_not_believed_unless_the_head_is_there() -> None:
    """Socket 1 may still owe the Completion of an abandoned move (stray window). While the new
    move (socket 1) and the zoom (socket 2) run, a Completion ``90 51 FF`` that is not the move's
    arrives: the read-back shows the head short of the target, so it is ignored (one stray), the
    zoom's Completion is still taken for the zoom, and the call returns after the real one."""
    with ViscaSerialTwin(time_scale=1.0) as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        _ready(head, twin)
        head.session.timeouts.retries = 0
        with pytest.raises(ViscaTimeout, match="no completion"):  # 1440 counts: a 4.5 s move, given up
            head.session.command(_move(1440, 0), completion_timeout=0.3)
        head.session.timeouts.retries = 3
        assert 1 in head.session.stray
        twin.emulator.set_pose(0, 0)
        head._last_counts = (0, 0)
        n_log, n_sent = len(twin.emulator.log), len(twin.sent)
        error: list[BaseException] = []

        def run() -> None:
            try:
                head.move_and_zoom_counts(150, 0, 0x800)
            except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
                error.append(exc)

        thread = threading.Thread(target=run)
        thread.start()
        _wait_for(lambda: ACK2 in twin.sent[n_sent:], timeout=3.0)
        twin.inject_raw(DONE1)
        thread.join(timeout=10.0)
        assert not thread.is_alive() and not error, error
        assert _pose(twin) == (150, 0, 0x800)
        status = [r for r in twin.sent[n_sent:] if len(r) == 3]  # ACKs and Completions (no position replies)
        # the abandoned move's Completion comes at once (interrupted), then both ACKs, then the real ones
        assert status[:3] == [DONE1, ACK1, ACK2] and sorted(status[3:]) == [DONE1, DONE2], \
            [r.hex(" ") for r in status]
        assert head.session.stats.stray == 1
        requests = twin.emulator.log[n_log:]
        assert requests[:2] == [_move(150, 0), cmd_zoom_direct(1, 0x800)]
        assert set(requests[2:]) == {H("81 09 06 12 FF")}  # read-backs only: nothing was resent


def test_over_ip_the_commands_run_one_after_another() -> None:
    """The VISCA-over-IP link keeps only the newest command's replies (sequence numbers), so the
    move and the zoom run one after the other: both reached, no timeout, no resend."""
    with ViscaIpTwin(time_scale=0.5) as twin, open_ip_head(twin.url, timeouts=_timeouts()) as head:
        head.move_to_counts(0, 0)
        head.session.stats = SessionStats()
        n_log = len(twin.emulator.log)
        head.move_and_zoom_counts(300, -50, 0x1800)
        assert _pose(twin) == (300, -50, 0x1800)
        move = cmd_pan_tilt_absolute(1, 300, -50, head.model.max_pan_speed, head.model.max_tilt_speed)
        assert twin.emulator.log[n_log:] == [move, cmd_zoom_direct(1, 0x1800)]
        assert (head.session.stats.timeouts, head.session.stats.retries) == (0, 0)
        assert not head.concurrent_zoom  # so the survey neither uses it nor prices it as concurrent


def test_out_of_range_targets_send_nothing() -> None:
    with ViscaSerialTwin() as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        n = len(twin.emulator.log)
        with pytest.raises(PositionOutOfRangeError):
            head.move_and_zoom_counts(2000, 0, 0)
        with pytest.raises(PositionOutOfRangeError):
            head.move_and_zoom_counts(0, 0, head.model.zoom_max + 1)
        with pytest.raises(PositionOutOfRangeError):
            head.move_and_zoom(0.0, 0.0, 1.5)
        assert twin.emulator.log[n:] == []


class _ScriptedLink:
    """A link whose camera answers each send with the next scripted burst of replies (serial-like:
    no reply tags); ``receive`` returns None at once when nothing is queued (a timeout)."""

    def __init__(self, script: list[list[bytes]]) -> None:
        self.script, self.inbox, self.sent = list(script), [], []
        self.retransmits: list[bool] = []

    def send(self, packet: bytes, retransmit: bool = False) -> None:
        self.sent.append(packet)
        self.retransmits.append(retransmit)
        self.inbox.extend(self.script.pop(0) if self.script else [])

    def receive(self, timeout: float) -> bytes | None:
        return self.inbox.pop(0) if self.inbox else None

    def flush_input(self) -> None: ...

    def reopen(self) -> None: ...

    def close(self) -> None: ...


MOVE, ZOOM = _move(10, 0), cmd_zoom_direct(1, 0x100)


@pytest.mark.parametrize(("script", "resent"), [
    # the move completes while the zoom's ACK is awaited: kept for the move, not dropped as stale
    ([[ACK1], [DONE1, ACK2, DONE2]], []),
    # ... and the camera gives the freed socket 1 to the zoom: the first DONE1 is the move's, the second the zoom's
    ([[ACK1], [DONE1, ACK1, DONE1]], []),
    # the move's Completion is lost and socket 1 goes to the zoom: the move is run again alone
    ([[ACK1], [ACK1, DONE1], [ACK1, DONE1]], [MOVE]),
], ids=["completion-during-ack-wait", "socket-reused", "completion-lost-socket-reused"])
def test_session_sorts_out_completions_met_while_waiting_for_the_second_ack(
        script: list[list[bytes]], resent: list[bytes]) -> None:
    from fgloc.drivers.visca.session import ViscaSession

    link = _ScriptedLink(script)
    session = ViscaSession(link, timeouts=_timeouts())
    session.commands_at_once([TogetherCommand(MOVE, 1.0, "move"), TogetherCommand(ZOOM, 1.0, "zoom")])
    assert link.sent == [MOVE, ZOOM, *resent]
    assert link.inbox == [] and link.script == []  # every reply read, none owed
    assert (session.stats.timeouts, session.stats.stale) == (0, 0)


def test_the_other_sockets_completion_met_by_a_read_back_is_kept() -> None:
    """Socket 1 is in a stray window, so the move's Completion is checked by a position inquiry;
    the zoom's Completion arrives before that inquiry's answer and must still count for the zoom
    (not be dropped with the replies a read-back meets in the one-at-a-time path)."""
    from fgloc.drivers.visca.session import ViscaSession

    inquiry = H("81 09 06 12 FF")
    link = _ScriptedLink([[ACK1], [ACK2, DONE1], [DONE2, H("90 50 00 00 00 0A 00 00 00 00 FF")]])
    session = ViscaSession(link, timeouts=_timeouts())
    session.stray[1] = time.monotonic() + 60.0
    confirm = lambda: len(session.inquiry(inquiry, 8)) == 8  # noqa: E731 - the head is at the target
    session.commands_at_once([TogetherCommand(MOVE, 1.0, "move", confirm), TogetherCommand(ZOOM, 1.0, "zoom")])
    assert link.sent == [MOVE, ZOOM, inquiry] and link.inbox == []
    assert (session.stats.timeouts, session.stats.stale, session.stats.stray) == (0, 0, 0)


def test_a_missing_ack_resends_alone_as_a_retransmission_and_drains_the_wire() -> None:
    """The zoom's ACK never comes (the move's Completion does): once the move is done the zoom is
    resent alone as after an ACK timeout in command() (marked a retransmission; the first send may
    have run, so the wire is drained by a power inquiry afterwards)."""
    from fgloc.drivers.visca.codec import cmd_power_inquiry
    from fgloc.drivers.visca.session import ViscaSession

    link = _ScriptedLink([[ACK1], [DONE1], [ACK2, DONE2], [H("90 50 02 FF")]])
    session = ViscaSession(link, timeouts=_timeouts())
    session.commands_at_once([TogetherCommand(MOVE, 1.0, "move"), TogetherCommand(ZOOM, 1.0, "zoom")])
    assert link.sent == [MOVE, ZOOM, ZOOM, cmd_power_inquiry(1)] and link.inbox == []
    assert link.retransmits == [False, False, True, False]
    assert (session.stats.timeouts, session.stats.retries) == (1, 1)


def test_an_error_reply_is_raised_once_the_other_command_is_done() -> None:
    """The zoom is refused as not executable (its own socket 2): the move's Completion is still read
    (nothing left owed on the wire), then the error class is raised."""
    from fgloc.drivers.visca.errors import CommandNotExecutable
    from fgloc.drivers.visca.session import ViscaSession

    link = _ScriptedLink([[ACK1], [H("90 62 41 FF"), DONE1]])
    session = ViscaSession(link, timeouts=_timeouts())
    with pytest.raises(CommandNotExecutable):
        session.commands_at_once([TogetherCommand(MOVE, 1.0, "move"), TogetherCommand(ZOOM, 1.0, "zoom")])
    assert link.inbox == [] and link.sent == [MOVE, ZOOM] and session.stray == {}


def test_more_commands_than_sockets_are_refused() -> None:
    with ViscaSerialTwin() as twin, open_serial_head(twin.port, timeouts=_timeouts()) as head:
        c = TogetherCommand(cmd_zoom_direct(1, 0))
        with pytest.raises(ValueError, match="2 command sockets"):
            head.session.commands_at_once([c, c, c])


def test_only_the_visca_head_has_move_and_zoom() -> None:
    """Callers detect the capability by the method's presence: the shared base (and so the Sony
    CGI head) must not have it."""
    assert callable(getattr(ViscaHead, "move_and_zoom", None))
    assert not hasattr(HeadAdapter, "move_and_zoom") and not hasattr(HeadAdapter, "move_and_zoom_counts")
