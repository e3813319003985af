"""The skeleton the serial (pseudo-terminal) twins share: a reply queue and a served pty.

:class:`ScheduledReplies` is a time-ordered queue of outgoing bytes (the UDP twin
uses it too). :class:`PtyTwin` is a device on a :class:`~fgloc.drivers.twins.pty_port.PtyPort`
served from a background thread: it reads what the driver wrote, hands it to the
subclass (:meth:`PtyTwin._on_bytes`), writes scheduled replies when they are due,
and pulls/plugs the cable on :meth:`PtyTwin.disconnect`. Subclasses hold the
device itself (framing, emulator, fault decisions per request).
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from typing import Generic, Self, TypeVar

from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.pty_port import PtyPort

T = TypeVar("T")


class ScheduledReplies(Generic[T]):
    """A time-ordered queue of outgoing items (byte strings, or bytes with routing data; thread-safe)."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, T]] = []
        self._seq = itertools.count()
        self._lock = threading.Lock()

    def put(self, due: float, payload: T) -> None:
        with self._lock:
            heapq.heappush(self._heap, (due, next(self._seq), payload))

    def pop_one(self, now: float) -> T | None:
        with self._lock:
            if self._heap and self._heap[0][0] <= now:
                return heapq.heappop(self._heap)[2]
            return None

    def pop_due(self, now: float) -> list[T]:
        out: list[T] = []
        with self._lock:
            while self._heap and self._heap[0][0] <= now:
                out.append(heapq.heappop(self._heap)[2])
        return out

    def next_due(self) -> float | None:
        with self._lock:
            return self._heap[0][0] if self._heap else None

    def clear(self) -> None:
        with self._lock:
            self._heap.clear()


class PtyTwin(Generic[T]):
    """A simulated serial device on a pty, served by a daemon thread; open :attr:`port` with pyserial.

    ``T`` is the type of a scheduled reply (bytes unless the subclass routes more with it).
    A subclass sets up its own state, then calls ``super().__init__`` (which starts the
    thread), and implements :meth:`_on_bytes`; it may override :meth:`_reset_link`,
    :meth:`_read_timeout` and :meth:`_write_due`. Use as a context manager.
    """

    def __init__(self, pty_name: str, thread_name: str, faults: FaultConfig | None = None) -> None:
        self.faults = FaultInjector(faults)
        self._pty = PtyPort(pty_name)
        self._out: ScheduledReplies[T] = ScheduledReplies()
        self._stop = threading.Event()
        self._reconnect_at: float | None = None
        self._thread = threading.Thread(target=self._serve, name=thread_name, daemon=True)
        self._thread.start()

    @property
    def port(self) -> str:
        """Serial device path for pyserial (a symlink to the current pty slave)."""
        return self._pty.path

    def inject_raw(self, data: bytes) -> None:
        """Write arbitrary bytes to the driver (line noise, truncated frames, unsolicited packets)."""
        self._pty.write(data)

    def disconnect(self, reconnect_after: float | None = None) -> None:
        """Pull the cable now; plug it back after ``reconnect_after`` seconds (never if None)."""
        self._pty.disconnect()
        self._out.clear()
        self._reset_link()
        self._reconnect_at = None if reconnect_after is None else time.monotonic() + reconnect_after

    # -- what a subclass provides
    def _reset_link(self) -> None:
        """Forget partial input (framing state) when the cable is pulled."""

    def _on_bytes(self, data: bytes) -> None:
        """Handle bytes the driver wrote (schedule replies on ``self._out``)."""
        raise NotImplementedError

    def _read_timeout(self, now: float, wait: float) -> float:
        """How long to wait for input, given ``wait`` until the next reply is due."""
        return wait

    def _write_due(self) -> None:
        """Write every reply that is due."""
        for out in self._out.pop_due(time.monotonic()):
            assert isinstance(out, bytes)  # subclasses scheduling other items override this
            self._pty.write(out)

    # -- the serving thread
    def _serve(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            if not self._pty.connected:
                if self._reconnect_at is not None and now >= self._reconnect_at:
                    self._reconnect_at = None
                    self._pty.reconnect()
                else:
                    self._stop.wait(0.01)
                    continue
            due = self._out.next_due()
            wait = 0.02 if due is None else min(0.02, max(0.0, due - now))
            data = self._pty.read(self._read_timeout(now, wait))
            if data:
                self._on_bytes(data)
            self._write_due()

    def close(self) -> None:
        """Stop the thread and remove the pty."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._pty.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
