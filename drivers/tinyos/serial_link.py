"""The MicaZ BaseStation on a serial port (57600 8N1): HDLC frames, 0x44 + ACK with retries."""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.tinyos.errors import MoteDisconnected, MoteProtocolError, MoteTimeout
from fgloc.drivers.tinyos.framing import (
    PROTO_ACK,
    PROTO_PACKET_ACK,
    PROTO_PACKET_NOACK,
    PROTO_UNKNOWN,
    Deframer,
    ack_frame,
    data_frame,
    parse_body,
)
from fgloc.drivers.tinyos.link import ReaderLink, first_line
from fgloc.drivers.tinyos.messages import AmPacket

if TYPE_CHECKING:
    import serial

MICAZ_BAUD = 57600


class SerialMoteLink(ReaderLink):
    """BaseStation on a serial port: HDLC frames, 0x44 + ACK with retries, 57600 8N1."""

    def __init__(self, port: str, baudrate: int = MICAZ_BAUD, ack_timeout: float = 0.25, retries: int = 5) -> None:
        super().__init__()
        self.port, self.baudrate = port, baudrate
        self.where = port
        self.ack_timeout, self.retries = ack_timeout, retries
        self._seq = 0
        self._acks: set[int] = set()
        self._ack_cv = threading.Condition()
        self._deframer = Deframer(self.stats)
        self._serial = self._open()
        self._start_reader()

    def _open(self) -> serial.Serial:
        import serial

        try:
            return serial.Serial(self.port, self.baudrate, timeout=0.05, write_timeout=1.0)
        except (serial.SerialException, OSError) as exc:
            raise MoteDisconnected(f"{self.port}: cannot open serial port ({first_line(exc)})") from None

    def _reader(self) -> None:
        import termios

        import serial

        while not self._stop.is_set():
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError, TypeError, termios.error) as exc:
                if not self._stop.is_set():
                    self._error = MoteDisconnected(f"{self.port}: device disconnected ({first_line(exc)})")
                with self._ack_cv:
                    self._ack_cv.notify_all()
                return
            for body in self._deframer.feed(chunk):
                self._on_body(body)

    def _on_body(self, body: bytes) -> None:
        try:
            f = parse_body(body)
        except MoteProtocolError:
            self.stats.malformed += 1
            return
        if f.protocol == PROTO_ACK:
            assert f.seq is not None  # parse_body gives ACK frames their sequence byte
            with self._ack_cv:
                self._acks.add(f.seq)
                self._ack_cv.notify_all()
        elif f.protocol == PROTO_PACKET_ACK:
            assert f.seq is not None and f.packet is not None
            self._write(ack_frame(f.seq))  # legal though motes never ask (protocols.md 3.9)
            self.stats.acks_sent += 1
            self._deliver(f.packet)
        elif f.protocol == PROTO_PACKET_NOACK:
            assert f.packet is not None
            self._deliver(f.packet)
        elif f.protocol == PROTO_UNKNOWN:
            with self._ack_cv:
                self._error_reply = f.data
                self._ack_cv.notify_all()
        else:
            self.stats.malformed += 1

    _error_reply: bytes | None = None

    def _write(self, data: bytes) -> None:
        import termios

        import serial

        try:
            with self._write_lock:
                self._serial.write(data)
                self._serial.flush()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise MoteDisconnected(f"{self.port}: write failed ({first_line(exc)})") from None

    def send(self, packet: AmPacket) -> None:
        """Send as 0x44 with a fresh sequence number; resend until ACKed within ``ack_timeout`` s
        (MoteTimeout after ``retries`` resends)."""
        self._check()
        self._seq = (self._seq + 1) & 0xFF
        seq = self._seq
        data = data_frame(packet, seq)

        def attempt(n: int) -> None:
            with self._ack_cv:
                self._acks.discard(seq)
                self._error_reply = None
            self._write(data)
            self.stats.sent += 1
            deadline = time.monotonic() + self.ack_timeout
            with self._ack_cv:
                while seq not in self._acks:
                    self._check()
                    if self._error_reply is not None:
                        raise MoteProtocolError(f"{self.port}: base station answered 'unknown protocol' "
                                                f"(0xFF {self._error_reply[:1].hex()}); is it running TinyOS 2.x?")
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise MoteTimeout(f"{self.port}: base station did not acknowledge after "
                                          f"{self.retries + 1} tries")
                    self._ack_cv.wait(remaining)

        def count_retry(failures: int, error: BaseException) -> None:
            self.stats.retries += 1

        RetryPolicy(self.retries + 1, MoteTimeout).call(attempt, count_retry)

    def reopen(self) -> None:
        self.close()
        self._deframer = Deframer(self.stats)
        self._serial = self._open()
        self._start_reader()

    def close(self) -> None:
        self._stop_reader()
        try:
            self._serial.close()
        except Exception:  # noqa: BLE001
            pass
