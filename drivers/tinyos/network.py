"""The ``LedController`` over a mote link: LED command, wait for the node's LED report (seconds)."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

from fgloc.drivers.tinyos.errors import MoteDisconnected
from fgloc.drivers.tinyos.forwarder import SerialForwarderLink, parse_tcp_url
from fgloc.drivers.tinyos.messages import ALL_LEDS, DEFAULT_GROUP, AmPacket, led_command, node_address, parse_led_report
from fgloc.drivers.tinyos.serial_link import MICAZ_BAUD, SerialMoteLink

log = logging.getLogger(__name__)


@dataclass
class MoteNetwork:
    """``fgloc.core.hardware.LedController`` over a mote link (serial BaseStation or SerialForwarder).

    ``set_led`` sends the LED command and returns True once the node's LED report
    with the requested state arrives (application-level confirmation), False when
    the node never answers within ``report_timeout`` after ``attempts`` sends.
    Link failures (no serial ACK, disconnect) raise :class:`MoteError`; with
    ``reconnects`` > 0 a disconnect first reopens the link and tries again.
    """

    link: SerialMoteLink | SerialForwarderLink
    address_map: Mapping[str, int] | None = None
    report_timeout: float = 0.5
    attempts: int = 3
    reconnects: int = 3
    reconnect_wait: float = 0.2
    group: int = DEFAULT_GROUP
    mask: int = ALL_LEDS
    unrelated: list[AmPacket] = field(default_factory=list)  # packets received that were not our reports
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def set_led(self, node_id: str, on: bool) -> bool:
        node = node_address(node_id, self.address_map)
        with self._lock:
            for reconnect in range(self.reconnects + 1):
                try:
                    return self._set_led(node, bool(on))
                except MoteDisconnected:
                    if reconnect >= self.reconnects:
                        raise
                    log.warning("mote link lost; reconnecting")
                    time.sleep(self.reconnect_wait)
                    try:
                        self.link.reopen()
                    except MoteDisconnected:
                        if reconnect + 1 >= self.reconnects:
                            raise
        return False  # pragma: no cover

    def _set_led(self, node: int, on: bool) -> bool:
        command = led_command(node, on, self.mask, group=self.group)
        for _ in range(self.attempts):
            self._drain()
            self.link.send(command)
            deadline = time.monotonic() + self.report_timeout
            while (remaining := deadline - time.monotonic()) > 0:
                packet = self.link.receive(remaining)
                if packet is None:
                    break
                report = parse_led_report(packet)
                if report == (node, on):
                    return True
                self._keep(packet)
        return False

    def _drain(self) -> None:
        while True:
            try:
                self._keep(self.link.packets.get_nowait())
            except queue.Empty:
                return

    def _keep(self, packet: AmPacket) -> None:
        self.unrelated.append(packet)
        del self.unrelated[:-100]

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> MoteNetwork:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_mote_network(port: str, address_map: Mapping[str, int] | None = None, ack_timeout: float = 0.25,
                      retries: int = 5, report_timeout: float = 0.5, attempts: int = 3,
                      baudrate: int = MICAZ_BAUD) -> MoteNetwork:
    """A serial device path, or ``tcp://HOST[:PORT]`` for a SerialForwarder."""
    if port.startswith("tcp://"):
        link: SerialMoteLink | SerialForwarderLink = SerialForwarderLink(*parse_tcp_url(port))
    else:
        link = SerialMoteLink(port, baudrate, ack_timeout, retries)
    return MoteNetwork(link, address_map, report_timeout, attempts)
