"""What every mote link shares: a reader thread delivering AM packets to a queue (times in seconds)."""

from __future__ import annotations

import queue
import threading

from fgloc.drivers.tinyos.errors import MoteError
from fgloc.drivers.tinyos.framing import LinkStats
from fgloc.drivers.tinyos.messages import AmPacket


class ReaderLink:
    """Shared machinery: a reader thread delivering AM packets to a queue."""

    where = "?"

    def __init__(self) -> None:
        self.stats = LinkStats()
        self.packets: queue.Queue[AmPacket] = queue.Queue()
        self._error: MoteError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._write_lock = threading.Lock()

    def _start_reader(self) -> None:
        self._stop.clear()
        self._error = None
        self._thread = threading.Thread(target=self._reader, name=f"mote-reader {self.where}", daemon=True)
        self._thread.start()

    def _reader(self) -> None:
        raise NotImplementedError

    def _deliver(self, packet: AmPacket) -> None:
        self.packets.put(packet)

    def _check(self) -> None:
        if self._error is not None:
            raise self._error

    def receive(self, timeout: float) -> AmPacket | None:
        """Next AM packet from the network, or None after ``timeout`` s (raises if the link died)."""
        try:
            return self.packets.get(timeout=timeout)
        except queue.Empty:
            self._check()
            return None

    def _stop_reader(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)


def first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
