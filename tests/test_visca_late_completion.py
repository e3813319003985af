"""Late Completions on the wire: the twin sends none after a cancel or a Stop, and the driver never
takes a stray Completion for the Completion of a newer command (socket, order, read-back check)."""

from __future__ import annotations

import threading
import time

import pytest

from fgloc.drivers.twins.visca_camera import ViscaSerialTwin
from fgloc.drivers.visca.codec import cmd_pan_tilt_absolute, cmd_pan_tilt_drive, cmd_power, cmd_power_inquiry
from fgloc.drivers.visca.errors import ViscaTimeout
from fgloc.drivers.visca.head import open_serial_head
from fgloc.drivers.visca.session import Timeouts

H = bytes.fromhex
ACK1, DONE1 = H("90 41 FF"), H("90 51 FF")


def _head(twin: ViscaSerialTwin):
    return open_serial_head(twin.port, timeouts=Timeouts(ack=0.1, inquiry=0.1, completion_margin=0.3, retries=3))


def _abandon_a_long_move(head, twin) -> float:
    """Start a 4.5 s move (1440 counts at 22 deg/s) and give up on it after 0.1 s: socket 1 is still
    busy on the camera, its Completion due at the move's end. Returns that end (monotonic s)."""
    head.session.timeouts.retries = 0
    start = time.monotonic()
    with pytest.raises(ViscaTimeout, match="no completion"):
        head.session.command(cmd_pan_tilt_absolute(1, 1440, 0, 0x0C, 0x0C), completion_timeout=0.1)
    head.session.timeouts.retries = 3
    assert 1 in head.session.stray  # the session knows a Completion may still come on socket 1
    return start + 1440 / 14.4 / 22.0


def _wait_for(predicate, timeout: float = 2.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out waiting"
        time.sleep(0.002)


def test_no_completion_after_a_cancel() -> None:
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        head.position_counts()
        twin.emulator.set_pose(1300, 0)  # 140 counts left: the move ends 0.44 s after it starts
        head.session.timeouts.retries = 0
        with pytest.raises(ViscaTimeout):
            head.session.command(cmd_pan_tilt_absolute(1, 1440, 0, 0x0C, 0x0C), completion_timeout=0.05)
        n = len(twin.sent)
        assert head.session.cancel(1) is True  # z0 61 04 FF: it was still running
        assert twin.sent[n:] == [H("90 61 04 FF")]
        time.sleep(0.6)  # past the move's original end
        assert twin.sent[n + 1:] == []  # Sony: no Completion follows a cancelled command
        assert head.session.cancel(1) is False  # z0 61 05 FF: nothing in socket 1 now


def test_no_late_completion_after_a_stop() -> None:
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        head.position_counts()
        twin.emulator.set_pose(1300, 0)
        head.session.timeouts.retries = 0
        with pytest.raises(ViscaTimeout):
            head.session.command(cmd_pan_tilt_absolute(1, 1440, 0, 0x0C, 0x0C), completion_timeout=0.05)
        n = len(twin.sent)
        head.stop()
        # the interrupted move completes at once, before the Stop's own ACK and Completion ...
        assert twin.sent[n:] == [DONE1, ACK1, DONE1]
        stopped = head.position_counts()
        m = len(twin.sent)
        time.sleep(0.6)
        assert twin.sent[m:] == []  # ... and never again at its original end time
        assert head.read_counts_once() == stopped


def _move_and_inject(head, twin, target: tuple[int, int], fake: bytes) -> list[bytes]:
    """Run move_to_counts(target) in a thread; as soon as its ACK is on the wire, inject ``fake``.
    Returns the replies the twin had sent when move_to_counts returned."""
    n = len(twin.sent)
    returned: list[list[bytes]] = []
    error: list[BaseException] = []

    def run() -> None:
        try:
            head.move_to_counts(*target)
            returned.append(list(twin.sent[n:]))
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            error.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    _wait_for(lambda: any(r[1] & 0xF0 == 0x40 for r in twin.sent[n:]))
    twin.inject_raw(fake)
    thread.join(timeout=10.0)
    assert not error, error
    return returned[0]


@pytest.mark.parametrize("how", ["timeout", "cancel"])
def test_an_injected_late_completion_is_not_taken_for_a_newer_commands(how: str) -> None:
    """A command is given up (completion timeout) or cancelled on socket 1; the next move also gets
    socket 1 and its ACK; then a Completion ``90 51 FF`` arrives that is not the new move's (the
    abandoned command's late one, as firmware that ignores the cancel would send it). The driver
    checks the head, sees it still moving, ignores the packet and returns only after the real
    Completion, with the head at the target."""
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        head.position_counts()
        _abandon_a_long_move(head, twin)
        if how == "cancel":
            assert head.session.cancel(1) is True
        head._last_counts = None
        twin.emulator.set_pose(0, 0)
        target = (150, 0)
        head.settings.pan_speed = 0x0C  # 22 deg/s: 150 counts take 0.47 s
        sent = _move_and_inject(head, twin, target, DONE1)
        acks = [i for i, r in enumerate(sent) if r == ACK1]
        assert acks and DONE1 in sent[acks[-1] + 1:], [r.hex(" ") for r in sent]  # the real one was sent
        assert head.session.stats.stray == 1
        assert head.read_counts_once() == target


def test_without_a_stray_window_no_read_back_is_spent() -> None:
    """A normal move costs no confirmation inquiry: the check runs only on a socket that may owe a Completion."""
    with ViscaSerialTwin(time_scale=0.0) as twin, _head(twin) as head:
        head.move_to_counts(10, 10)
        n = len(twin.emulator.log)
        head.move_to_counts(20, 20)
        assert twin.emulator.log[n:] == [cmd_pan_tilt_absolute(1, 20, 20, 0x18, 0x14)]
        assert head.session.stats.stray == 0


def test_power_drive_and_version_through_the_driver() -> None:
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        assert head.version() == (0x0001, 0x040D, 0x0001, 2)
        head.session.command(cmd_power(1, False), name="power off")
        assert head.session.inquiry(cmd_power_inquiry(1), 1, nibbles=False) == b"\x03"
        head.session.command(cmd_power(1, True), name="power on")
        assert head.session.inquiry(cmd_power_inquiry(1), 1, nibbles=False) == b"\x02"
        head.session.command(cmd_pan_tilt_drive(1, 2, 3, 0x10, 0x10), name="drive right")  # 52 deg/s
        time.sleep(0.2)
        head.stop()
        pan, tilt = head.position_counts()
        assert 52 * 14.4 * 0.15 < pan < 52 * 14.4 * 0.5 and tilt == 0


class _StallOnce:
    """The head's real serial link, but the host stalls once: the first ``receive`` after
    :meth:`arm` sleeps ``seconds`` and reads nothing, so the driver's ACK wait runs out while the
    camera goes on working (what a descheduled process or a slow USB-serial adapter does)."""

    def __init__(self, link) -> None:
        self.link, self.armed = link, 0.0

    def arm(self, seconds: float) -> None:
        self.armed = seconds

    def receive(self, timeout: float):
        if self.armed:
            time.sleep(self.armed)
            self.armed = 0.0
            return None
        return self.link.receive(timeout)

    def __getattr__(self, name: str):
        return getattr(self.link, name)


@pytest.mark.parametrize("stall", [0.15, 0.6], ids=["resend-interrupts-the-move", "camera-runs-the-move-twice"])
def test_a_resend_after_a_late_ack_never_leaves_the_driver_one_reply_behind(stall: float) -> None:
    """The host stalls past the ACK timeout, so the driver resends a move the camera already got:
    the camera runs it twice, and two ACKs and two Completions come back. Either the resend
    interrupts the first run (its Completion comes at once, the head half-way: stall 0.15 s of a
    0.47 s move), or the first run is over before the resend arrives (stall 0.6 s) and the
    resend's ACK and Completion are still on the wire after the move returns. Neither may be
    taken for a later command's: every move returns with the head at its target, and
    no sooner than the head can get there."""
    with ViscaSerialTwin(time_scale=1.0) as twin, _head(twin) as head:
        head.position_counts()
        link = _StallOnce(head.session.link)
        head.session.link = link
        head.settings.pan_speed = 0x0C  # 22 deg/s: 150 counts take 0.47 s
        start = head.read_counts_once()
        link.arm(stall)
        for target in [(150, 0), (0, 0), (150, 0), (300, 0)]:  # no inquiry between: moves only
            t0 = time.monotonic()
            head.move_to_counts(*target)
            took = time.monotonic() - t0
            pose = twin.emulator.pose()  # the camera's own state, read without the driver
            assert (pose.pan_counts, pose.tilt_counts) == target
            assert took >= abs(target[0] - start[0]) / 14.4 / 22.0 - 0.02
            start = target
        assert head.session.stats.retries >= 1
