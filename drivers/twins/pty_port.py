"""A pseudo-terminal standing in for a serial cable, with a stable path that survives a reconnect.

``os.openpty()`` gives a master fd (the twin's end) and a slave device
(``/dev/pts/N``, the end pyserial opens). The slave's name changes on every
``openpty``; to let a driver reopen "the same port" after a simulated
disconnect, :attr:`PtyPort.path` is a symlink in a private temp directory that
always points at the current slave (like ``socat``'s ``link=`` option).

Disconnect closes both ends, so a driver reading the old slave gets EIO (pyserial
raises ``SerialException``), and removes the symlink, so opening the path fails
until :meth:`reconnect`.
"""

from __future__ import annotations

import os
import select
import shutil
import tempfile
import threading
import tty


class PtyPort:
    """The twin's end of a pseudo-terminal serial line."""

    def __init__(self, name: str = "tty") -> None:
        self._dir = tempfile.mkdtemp(prefix="fgloc-twin-")
        self.path = os.path.join(self._dir, name)
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self.connected = False
        self.reconnect()

    def reconnect(self) -> None:
        """(Re)create the pty and point :attr:`path` at its slave."""
        with self._lock:
            self._close_fds()
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no line discipline: bytes are bytes
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            tmp = self.path + ".new"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(os.ttyname(slave), tmp)
            os.replace(tmp, self.path)
            self.connected = True

    def disconnect(self) -> None:
        """Pull the cable: close both ends and remove :attr:`path`."""
        with self._lock:
            self._close_fds()
            if os.path.lexists(self.path):
                os.unlink(self.path)
            self.connected = False

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def read(self, timeout: float) -> bytes:
        """Bytes the driver wrote (possibly empty after ``timeout`` seconds or when disconnected)."""
        master = self._master
        if master is None:
            return b""
        try:
            ready, _, _ = select.select([master], [], [], max(0.0, timeout))
            if not ready:
                return b""
            return os.read(master, 4096)
        except (OSError, ValueError):
            return b""

    def write(self, data: bytes) -> None:
        """Send bytes to the driver (silently lost while disconnected)."""
        with self._lock:
            if self._master is None:
                return
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self._master, view)
                except BlockingIOError:
                    select.select([], [self._master], [], 0.1)
                    continue
                except OSError:
                    return
                view = view[n:]

    def close(self) -> None:
        """Close everything and delete the temp directory."""
        with self._lock:
            self._close_fds()
            self.connected = False
        shutil.rmtree(self._dir, ignore_errors=True)
