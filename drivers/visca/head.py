"""The VISCA pan-tilt head: ``fgloc.core.hardware.PanTiltHead`` in spec radians over any VISCA link.

The spec-radian level (units, mounting, limits, confirmed read-back, frames) is the
shared :class:`fgloc.drivers.head_adapter.HeadAdapter`; this module adds the VISCA
counts level on a :class:`fgloc.drivers.visca.session.ViscaSession`. Times are seconds.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from fgloc.drivers.head_adapter import FrameSourceArg, HeadAdapter
from fgloc.drivers.ptz_units import EVI_D100, PanTiltUnits, PositionOutOfRangeError
from fgloc.drivers.visca.codec import (
    cmd_focus_auto,
    cmd_focus_manual,
    cmd_home,
    cmd_pan_tilt_absolute,
    cmd_pan_tilt_position_inquiry,
    cmd_pan_tilt_stop,
    cmd_version_inquiry,
    cmd_zoom_direct,
    cmd_zoom_position_inquiry,
    decode_pan_tilt,
    decode_version,
    decode_zoom,
)
from fgloc.drivers.visca.errors import ViscaError, ViscaProtocolError, ViscaTimeout
from fgloc.drivers.visca.serial_link import SerialLink
from fgloc.drivers.visca.session import Timeouts, TogetherCommand, ViscaSession

log = logging.getLogger(__name__)

#: counts a read-back may differ from the target when a possibly-stray Completion is checked
CONFIRM_COUNTS = 2


@dataclass
class HeadSettings:
    """Per-head knobs: speeds (VISCA bytes), read-back confirmation, settle time (s)."""

    pan_speed: int | None = None  # None: the model's maximum
    tilt_speed: int | None = None
    confirm_reads: bool = True  # read position until two successive inquiries agree
    max_reads: int = 5
    settle_seconds: float = 0.0


class ViscaHead(HeadAdapter):
    """``fgloc.core.hardware.PanTiltHead`` over VISCA (any link): angles in spec radians.

    The read-back position is what ``position()`` returns (never the commanded one);
    with ``confirm_reads`` it is read until two successive inquiries agree, which
    also rejects a reply whose nibbles were corrupted in transit (VISCA has no
    checksum) and a head still settling (protocols.md 1.10 item 9).
    """

    unsteady_error = ViscaProtocolError
    _last_counts: tuple[int, int] | None  # HeadAdapter's; restated for mypy run on drivers/ outside the package

    def __init__(self, session: ViscaSession, units: PanTiltUnits | None = None, frames: FrameSourceArg = None,
                 settings: HeadSettings | None = None) -> None:
        self.settings = settings or HeadSettings()
        super().__init__(units or PanTiltUnits(EVI_D100), frames, self.settings.confirm_reads,
                         self.settings.max_reads)
        self.session = session
        session._on_reconnect = self._reinit

    @property
    def where(self) -> str:
        return f"VISCA camera {self.address}"

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
        self.check_counts(pan, tilt)
        self._run_alone(self._move_command(pan, tilt))
        self._last_counts = (pan, tilt)
        if self.settings.settle_seconds > 0:
            time.sleep(self.settings.settle_seconds)

    def move_and_zoom_counts(self, pan: int, tilt: int, zoom_counts: int) -> None:
        """Absolute move to (pan, tilt) signed device counts and CAM_Zoom Direct to ``zoom_counts``
        (unsigned zoom counts, 0 wide ... ``model.zoom_max``), both at once in the camera's two
        command sockets; blocks until both have completed, then settles like :meth:`move_to_counts`.

        Each command keeps its own completion timeout and read-back check (those of
        :meth:`move_to_counts` and :meth:`set_zoom_counts`); what cannot run at once falls back to
        one after the other (:meth:`fgloc.drivers.visca.session.ViscaSession.commands_at_once`).
        Counts outside the model's ranges raise PositionOutOfRangeError before anything is sent.
        """
        self._ready()
        self.check_counts(pan, tilt)
        if not 0 <= zoom_counts <= self.model.zoom_max:
            raise PositionOutOfRangeError(f"zoom {zoom_counts} counts outside {self.model.name} range "
                                          f"0..{self.model.zoom_max}")
        self.session.commands_at_once([self._move_command(pan, tilt), self._zoom_command(zoom_counts)])
        self._last_counts = (pan, tilt)
        if self.settings.settle_seconds > 0:
            time.sleep(self.settings.settle_seconds)

    @property
    def concurrent_zoom(self) -> bool:
        """Does :meth:`move_and_zoom` run the move and the zoom at once? Over a serial line, yes;
        over VISCA over IP the link keeps one request's sequence number outstanding, so the session
        runs them one after the other (:meth:`~fgloc.drivers.visca.session.ViscaSession.commands_at_once`)."""
        return not getattr(self.session.link, "tags_replies", False)

    def move_and_zoom(self, pan: float, tilt: float, zoom: float) -> None:
        """Move to spec (pan, tilt) radians and zoom to a fraction of the optical range (0 wide ...
        1 optical tele), both at once in the camera's two command sockets; blocks until the head
        and the lens are there (:meth:`move_and_zoom_counts`)."""
        pan_counts, tilt_counts = self.units.to_counts(pan, tilt)
        self.move_and_zoom_counts(pan_counts, tilt_counts, self.units.zoom_to_counts(zoom))

    def _run_alone(self, c: TogetherCommand) -> None:
        self.session.command(c.packet, completion_timeout=c.completion_timeout, name=c.name, confirm=c.confirm)

    def _move_command(self, pan: int, tilt: int) -> TogetherCommand:
        """The absolute move to (pan, tilt) counts, its completion timeout (s) sized from the distance."""
        m = self.model
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
        return TogetherCommand(packet, wait, "pan-tilt absolute move", lambda: self._at(pan, tilt))

    def _at(self, pan: int, tilt: int) -> bool:
        """The head reads back (pan, tilt) within CONFIRM_COUNTS (checks a possibly-stray Completion)."""
        p, t = self.read_counts_once()
        return abs(p - pan) <= CONFIRM_COUNTS and abs(t - tilt) <= CONFIRM_COUNTS

    def read_counts_once(self) -> tuple[int, int]:
        """One pan-tilt position inquiry: (pan, tilt) signed device counts."""
        data = self.session.inquiry(cmd_pan_tilt_position_inquiry(self.address), self.model.pan_nibbles + 4,
                                    name="pan-tilt position inquiry")
        return decode_pan_tilt(data, self.model.pan_nibbles)

    def position_counts(self) -> tuple[int, int]:
        """Read-back (pan, tilt) in device counts (confirmed by two equal reads when enabled)."""
        self._ready()
        return super().position_counts()

    def set_zoom_counts(self, counts: int) -> None:
        """CAM_Zoom Direct to ``counts``; blocks until completion."""
        self._run_alone(self._zoom_command(counts))

    def _zoom_command(self, counts: int) -> TogetherCommand:
        """CAM_Zoom Direct to ``counts`` (unsigned zoom counts), with its completion timeout (s)."""
        wait = 3.0 + self.session.timeouts.completion_margin
        return TogetherCommand(cmd_zoom_direct(self.address, counts), wait, "zoom direct",
                               lambda: abs(self.zoom_counts() - counts) <= CONFIRM_COUNTS)

    def zoom_counts(self) -> int:
        data = self.session.inquiry(cmd_zoom_position_inquiry(self.address), 4, name="zoom position inquiry")
        return decode_zoom(data)

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
        self.session.command(cmd_home(self.address), completion_timeout=wait, name="home",
                             confirm=lambda: self._at(0, 0))
        self._last_counts = (0, 0)

    def version(self) -> tuple[int, int, int, int]:
        """CAM_VersionInq: (vendor, model, ROM version, number of sockets); vendor 0x0001 = Sony."""
        data = self.session.inquiry(cmd_version_inquiry(self.address), 7, name="version inquiry", nibbles=False)
        return decode_version(data)

    def _frame_without_source(self) -> np.ndarray:
        raise ViscaError("this head has no frame source (give --video or a FrameSource)")

    def close(self) -> None:
        self.session.link.close()


def open_serial_head(port: str, units: PanTiltUnits | None = None, address: int = 1,
                     timeouts: Timeouts | None = None, frames: FrameSourceArg = None, settings: HeadSettings | None = None,
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
