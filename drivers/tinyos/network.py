"""The ``LedController`` over a mote link: LED command, wait for the node's LED report (seconds)."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.tinyos.blink import (
    BlinkBroadcast,
    BlinkCommand,
    BlinkPause,
    blink_broadcast,
    blink_command,
    parse_blink_report,
)
from fgloc.drivers.tinyos.errors import MoteDisconnected, MoteTimeout
from fgloc.drivers.tinyos.forwarder import SerialForwarderLink, parse_tcp_url
from fgloc.drivers.tinyos.messages import ALL_LEDS, DEFAULT_GROUP, AmPacket, led_command, node_address, parse_led_report
from fgloc.drivers.tinyos.serial_link import MICAZ_BAUD, SerialMoteLink

log = logging.getLogger(__name__)


class LedNotConfirmed(MoteTimeout):
    """The node sent no LED report confirming a command (``set_led`` then returns False)."""


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
        """Switch the node's LEDs; True once its LED report confirms, False if it never does."""
        node = node_address(node_id, self.address_map)

        def attempt(n: int) -> bool:
            if n:
                self.link.reopen()
            return self._set_led(node, bool(on))

        def before_retry(failures: int, error: BaseException) -> None:
            log.warning("mote link lost (%s); reconnecting (%d/%d)", error, failures, self.reconnects)

        with self._lock:
            policy = RetryPolicy(self.reconnects + 1, MoteDisconnected, self.reconnect_wait)
            return policy.call(attempt, before_retry)

    def _set_led(self, node: int, on: bool) -> bool:
        """Up to ``attempts`` sends of the LED command, each waiting ``report_timeout`` s for the report."""
        command = led_command(node, on, self.mask, group=self.group)

        def attempt(n: int) -> None:
            self._drain()
            self.link.send(command)
            deadline = time.monotonic() + self.report_timeout
            while (remaining := deadline - time.monotonic()) > 0:
                packet = self.link.receive(remaining)
                if packet is None:
                    break
                if parse_led_report(packet) == (node, on):
                    return
                self._keep(packet)
            raise LedNotConfirmed(f"node {node}: no LED report within {self.report_timeout:.2f} s")

        try:
            RetryPolicy(self.attempts, LedNotConfirmed).call(attempt)
        except LedNotConfirmed:
            return False
        return True

    def start_code(self, node_id: str, length: int, code: int, bit_period_s: float, cycles: int = 0) -> bool:
        """Start one node's coded blink (unicast, ``drivers/tinyos/blink.py``); True once its blink
        report confirms the word, False if it never does within ``attempts`` x ``report_timeout``."""
        node = node_address(node_id, self.address_map)
        packet = blink_command(node, BlinkCommand(True, length, code, bit_period_s, cycles), group=self.group)
        with self._lock:
            for _ in range(self.attempts):
                got = self._blink_reports(packet, {node}, self.report_timeout)
                if got.get(node) == (True, length, code):
                    return True
        return False

    def stop_code(self, node_id: str) -> bool:
        """Stop one node's coded blink (unicast); True once its report says stopped."""
        node = node_address(node_id, self.address_map)
        packet = blink_command(node, BlinkCommand(start=False), group=self.group)
        with self._lock:
            for _ in range(self.attempts):
                got = self._blink_reports(packet, {node}, self.report_timeout)
                if node in got and not got[node][0]:
                    return True
        return False

    def broadcast_codes(self, command: BlinkBroadcast | BlinkCommand | BlinkPause, expect: set[int] | None,
                        wait: float) -> dict[int, tuple[bool, int, int]]:
        """Broadcast a start by address, a stop or a pause by bitmap (no reports: pass
        ``expect=set()``) to every node; the blink reports (node ->
        (running, length, code)) that arrived within ``wait`` s, or as soon as every node in
        ``expect`` has answered (None: wait the whole time)."""
        with self._lock:
            return self._blink_reports(blink_broadcast(command, group=self.group), expect, wait)

    def _blink_reports(self, packet: AmPacket, expect: set[int] | None, wait: float) -> dict[int, tuple[bool, int, int]]:
        self._drain()
        self.link.send(packet)
        got: dict[int, tuple[bool, int, int]] = {}
        deadline = time.monotonic() + wait
        while (remaining := deadline - time.monotonic()) > 0 and (expect is None or not expect <= set(got)):
            reply = self.link.receive(remaining)
            if reply is None:
                break
            rep = parse_blink_report(reply)
            if rep is None:
                self._keep(reply)
                continue
            got[rep[0]] = rep[1:]
        return got

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
