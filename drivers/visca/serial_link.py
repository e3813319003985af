"""VISCA over RS-232: a :class:`fgloc.drivers.visca.session.ViscaLink` on pyserial (9600 8N1)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from fgloc.drivers.visca.errors import ViscaDisconnected
from fgloc.drivers.visca.packets import PacketSplitter

if TYPE_CHECKING:
    import serial


class SerialLink:
    """VISCA over RS-232 via pyserial (9600 bit/s 8N1, no flow control; DTR left asserted)."""

    def __init__(self, port: str, baudrate: int = 9600) -> None:
        self.port = port
        self.baudrate = baudrate
        self._splitter = PacketSplitter()
        self._pending: list[bytes] = []
        self._serial = self._open()

    def _open(self) -> serial.Serial:
        import serial

        try:
            return serial.Serial(self.port, self.baudrate, bytesize=8, parity="N", stopbits=1,
                                 timeout=0.05, write_timeout=1.0, xonxoff=False, rtscts=False)
        except (serial.SerialException, OSError) as exc:
            raise ViscaDisconnected(f"{self.port}: cannot open serial port ({_short(exc)})") from None

    @property
    def garbage_bytes(self) -> int:
        return self._splitter.dropped_bytes

    def send(self, packet: bytes, retransmit: bool = False) -> None:
        try:
            self._serial.write(packet)
            self._serial.flush()
        except _serial_errors() as exc:
            raise ViscaDisconnected(f"{self.port}: write failed ({_short(exc)})") from None

    def receive(self, timeout: float) -> bytes | None:
        errors = _serial_errors()
        deadline = time.monotonic() + timeout
        while not self._pending:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            try:
                self._serial.timeout = min(remaining, 0.05)
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except errors as exc:
                raise ViscaDisconnected(f"{self.port}: device disconnected ({_short(exc)})") from None
            if chunk:
                self._pending.extend(self._splitter.feed(chunk))
        return self._pending.pop(0)

    def flush_input(self) -> None:
        self._pending.clear()
        self._splitter.reset()
        try:
            self._serial.reset_input_buffer()
        except Exception:  # noqa: BLE001 - a dead port is reported by the next read
            pass

    def reopen(self) -> None:
        self.close()
        self._splitter.reset()
        self._pending.clear()
        self._serial = self._open()

    def close(self) -> None:
        try:
            self._serial.close()
        except Exception:  # noqa: BLE001
            pass


def _serial_errors() -> tuple[type[BaseException], ...]:
    """Exceptions pyserial lets through when a device vanishes (termios.error on a closed pty)."""
    import termios

    import serial

    return (serial.SerialException, OSError, TypeError, termios.error)


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
