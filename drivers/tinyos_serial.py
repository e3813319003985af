"""TinyOS 2.x serial protocol (MicaZ BaseStation) and SerialForwarder client; a LedController.

Wire format (protocols.md section 3)::

    7E | P | [S] | D | dest(2) src(2) len group type | payload | crc_lo crc_hi | 7E

* ``P``: 0x43 ACK (+ the acknowledged seq), 0x44 packet-with-ack (+ seq byte S),
  0x45 packet-no-ack, 0xFF unknown-protocol reply;
* ``D`` dispatch 0x00 = Active Message; AM header big-endian;
* CRC-16/XMODEM (poly 0x1021, init 0, MSB-first) over P .. last payload byte,
  un-escaped, sent low byte first;
* every 0x7E/0x7D between the flags is sent as 0x7D, byte ^ 0x20.

SerialForwarder (TCP, default port 9002): both sides send ``55 20`` ("U "), then
each packet is one length byte + (dispatch + AM header + payload), no framing/CRC.

Application messages of fgloc's mote firmware (see docs/hardware.md):

* **LED command**, PC -> node, AM type ``0x89`` (:data:`AM_LED_COMMAND`), dest = node
  address, payload 2 bytes: ``command`` (0x00 off, 0x01 on) and ``mask`` (bit 0..2 =
  LED 0..2; fgloc sends 0x07, all LEDs).
* **LED report**, node -> PC, AM type ``0x8A`` (:data:`AM_LED_REPORT`), src = node
  address, dest 0xFFFF, payload 3 bytes: node address (2 bytes, big-endian) and
  ``state`` (0x00 LEDs off, 0x01 on). The node sends it after executing a command;
  it is the application-level confirmation (a serial ACK only means the base
  station's UART got the frame, protocols.md 3.6).

Malformed input never raises in the reader: bad CRC, truncated frames, escape
errors, over-long frames and unparsable packets are dropped and counted in
:class:`LinkStats`.
"""

from __future__ import annotations

import logging
import queue
import re
import socket
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from fgloc.core.errors import FglocError

if TYPE_CHECKING:
    import serial

log = logging.getLogger(__name__)

FLAG = 0x7E
ESCAPE = 0x7D
XOR = 0x20

PROTO_ACK = 0x43
PROTO_PACKET_ACK = 0x44
PROTO_PACKET_NOACK = 0x45
PROTO_UNKNOWN = 0xFF
DISPATCH_AM = 0x00

AM_BROADCAST = 0xFFFF
DEFAULT_GROUP = 0x22
AM_LED_COMMAND = 0x89
AM_LED_REPORT = 0x8A
LED_OFF, LED_ON = 0x00, 0x01
ALL_LEDS = 0x07

MICAZ_BAUD = 57600
SF_PORT = 9002
SF_HELLO = b"U "
MAX_FRAME = 256


class MoteError(FglocError):
    """Base of mote-network failures (one line, safe to show a user)."""


class MoteTimeout(MoteError):
    """The base station did not acknowledge a frame after all retries."""


class MoteDisconnected(MoteError):
    """The serial port or SerialForwarder connection went away."""


class MoteProtocolError(MoteError):
    """The peer spoke something else (bad SF handshake, unknown-protocol reply)."""


# ---------------------------------------------------------------------------------------------
# codec (pure)


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/XMODEM (poly 0x1021, init 0, no reflection, no final XOR); check("123456789") = 0x31C3."""
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def escape(data: bytes) -> bytes:
    """HDLC byte stuffing of everything between the flags."""
    out = bytearray()
    for b in data:
        if b in (FLAG, ESCAPE):
            out += bytes([ESCAPE, b ^ XOR])
        else:
            out.append(b)
    return bytes(out)


def frame(body: bytes) -> bytes:
    """``7E escape(body + crc_lo crc_hi) 7E`` for a body starting with the protocol byte."""
    crc = crc16(body)
    return bytes([FLAG]) + escape(body + bytes([crc & 0xFF, crc >> 8])) + bytes([FLAG])


@dataclass(frozen=True)
class AmPacket:
    """A serial Active Message: AM header fields + payload (dispatch 0x00)."""

    dest: int
    src: int
    am_type: int
    payload: bytes
    group: int = DEFAULT_GROUP

    def pack(self) -> bytes:
        """dispatch + header (big-endian) + payload: the SerialForwarder packet."""
        if len(self.payload) > 255 - 8:
            raise ValueError("AM payload too long")
        return bytes([DISPATCH_AM, self.dest >> 8, self.dest & 0xFF, self.src >> 8, self.src & 0xFF,
                      len(self.payload), self.group, self.am_type]) + self.payload

    @staticmethod
    def unpack(data: bytes) -> AmPacket:
        """Inverse of :meth:`pack`; MoteProtocolError when the length field disagrees."""
        if len(data) < 8 or data[0] != DISPATCH_AM:
            raise MoteProtocolError(f"not an AM packet: {data[:8].hex(' ')}")
        n = data[5]
        if len(data) != 8 + n:
            raise MoteProtocolError(f"AM length field {n} but {len(data) - 8} payload bytes")
        return AmPacket(dest=(data[1] << 8) | data[2], src=(data[3] << 8) | data[4], am_type=data[7],
                        payload=bytes(data[8:]), group=data[6])


def data_frame(packet: AmPacket, seq: int | None) -> bytes:
    """A wire frame: 0x44 + seq when ``seq`` is given (ACK requested), else 0x45."""
    if seq is None:
        return frame(bytes([PROTO_PACKET_NOACK]) + packet.pack())
    return frame(bytes([PROTO_PACKET_ACK, seq & 0xFF]) + packet.pack())


def ack_frame(seq: int) -> bytes:
    """The ACK ``7E 43 seq crc crc 7E``."""
    return frame(bytes([PROTO_ACK, seq & 0xFF]))


@dataclass(frozen=True)
class Frame:
    """A decoded frame body (CRC checked and removed)."""

    protocol: int
    seq: int | None
    packet: AmPacket | None
    data: bytes  # bytes after P (and S)


def parse_body(body: bytes) -> Frame:
    """Protocol byte .. payload (CRC removed) -> Frame; MoteProtocolError when malformed."""
    p = body[0]
    if p == PROTO_ACK:
        if len(body) != 2:
            raise MoteProtocolError(f"ACK frame of {len(body)} bytes")
        return Frame(p, body[1], None, body[1:])
    if p == PROTO_PACKET_ACK:
        if len(body) < 2:
            raise MoteProtocolError("packet-with-ack frame without sequence byte")
        return Frame(p, body[1], AmPacket.unpack(body[2:]), body[2:])
    if p == PROTO_PACKET_NOACK:
        return Frame(p, None, AmPacket.unpack(body[1:]), body[1:])
    return Frame(p, None, None, body[1:])


@dataclass
class LinkStats:
    """What the reader dropped or did; never reset implicitly."""

    frames: int = 0
    bad_crc: int = 0
    truncated: int = 0
    too_long: int = 0
    escape_errors: int = 0
    malformed: int = 0
    acks_sent: int = 0
    retries: int = 0
    sent: int = 0

    @property
    def dropped(self) -> int:
        return self.bad_crc + self.truncated + self.too_long + self.escape_errors + self.malformed


class Deframer:
    """HDLC receive state machine: bytes -> CRC-checked frame bodies. Never raises.

    Resyncs on every flag; ``7D 7E`` (flag right after an escape) drops the frame
    being built and starts a new one (the Java Packetizer's loss-of-sync rule).
    Flag pairs with fewer than 4 bytes between them are idle/truncated frames.
    """

    def __init__(self, stats: LinkStats | None = None) -> None:
        self.stats = stats or LinkStats()
        self._buf = bytearray()
        self._in_frame = False
        self._escaped = False

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        for b in data:
            if b == FLAG:
                if self._escaped:
                    self.stats.escape_errors += 1
                    self._buf.clear()
                    self._escaped = False
                    self._in_frame = True
                    continue
                if self._in_frame and self._buf:
                    body = self._finish()
                    if body is not None:
                        out.append(body)
                self._buf.clear()
                self._in_frame = True
                continue
            if not self._in_frame:
                continue  # garbage before the first flag
            if self._escaped:
                self._buf.append(b ^ XOR)
                self._escaped = False
            elif b == ESCAPE:
                self._escaped = True
            else:
                self._buf.append(b)
            if len(self._buf) > MAX_FRAME + 2:
                self.stats.too_long += 1
                self._buf.clear()
                self._in_frame = False  # wait for the next flag
        return out

    def _finish(self) -> bytes | None:
        raw = bytes(self._buf)
        if len(raw) < 4:
            self.stats.truncated += 1
            return None
        body, crc = raw[:-2], raw[-2] | (raw[-1] << 8)
        if crc16(body) != crc:
            self.stats.bad_crc += 1
            return None
        self.stats.frames += 1
        return body


# ---------------------------------------------------------------------------------------------
# links


class _ReaderLink:
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


class SerialMoteLink(_ReaderLink):
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
            raise MoteDisconnected(f"{self.port}: cannot open serial port ({_first_line(exc)})") from None

    def _reader(self) -> None:
        import termios

        import serial

        while not self._stop.is_set():
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError, TypeError, termios.error) as exc:
                if not self._stop.is_set():
                    self._error = MoteDisconnected(f"{self.port}: device disconnected ({_first_line(exc)})")
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
            with self._ack_cv:
                self._acks.add(f.seq)
                self._ack_cv.notify_all()
        elif f.protocol == PROTO_PACKET_ACK:
            self._write(ack_frame(f.seq))  # legal though motes never ask (protocols.md 3.9)
            self.stats.acks_sent += 1
            self._deliver(f.packet)
        elif f.protocol == PROTO_PACKET_NOACK:
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
            raise MoteDisconnected(f"{self.port}: write failed ({_first_line(exc)})") from None

    def send(self, packet: AmPacket) -> None:
        """Send as 0x44 with a fresh sequence number; resend until ACKed (MoteTimeout after retries)."""
        self._check()
        self._seq = (self._seq + 1) & 0xFF
        seq = self._seq
        data = data_frame(packet, seq)
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats.retries += 1
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
                        break
                    self._ack_cv.wait(remaining)
                if seq in self._acks:
                    return
        raise MoteTimeout(f"{self.port}: base station did not acknowledge after {self.retries + 1} tries")

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


class SerialForwarderLink(_ReaderLink):
    """A SerialForwarder TCP client: ``U `` handshake, then length-prefixed packets (no ACKs)."""

    def __init__(self, host: str, port: int = SF_PORT, timeout: float = 2.0) -> None:
        super().__init__()
        self.host, self.port, self.timeout = host, port, timeout
        self.where = f"tcp://{host}:{port}"
        self._sock = self._connect()
        self._start_reader()

    def _connect(self) -> socket.socket:
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as exc:
            raise MoteDisconnected(f"{self.where}: cannot connect ({exc.strerror or exc})") from None
        try:
            sock.sendall(SF_HELLO)
            hello = _recv_exact(sock, 2)
        except (OSError, EOFError) as exc:
            sock.close()
            raise MoteDisconnected(f"{self.where}: handshake failed ({exc})") from None
        if hello[:1] != b"U":
            sock.close()
            raise MoteProtocolError(f"{self.where}: not a TinyOS 2 SerialForwarder (handshake {hello!r})")
        sock.settimeout(0.1)
        return sock

    def _reader(self) -> None:
        buf = bytearray()
        sock = self._sock
        while not self._stop.is_set():
            try:
                chunk = sock.recv(4096)
            except TimeoutError:
                continue
            except OSError as exc:
                if not self._stop.is_set():
                    self._error = MoteDisconnected(f"{self.where}: connection lost ({exc.strerror or exc})")
                return
            if not chunk:
                if not self._stop.is_set():
                    self._error = MoteDisconnected(f"{self.where}: SerialForwarder closed the connection")
                return
            buf += chunk
            while buf:
                n = buf[0]
                if n == 0:
                    self.stats.malformed += 1  # length 0 is a protocol error; skip the byte
                    del buf[0]
                    continue
                if len(buf) < 1 + n:
                    break
                data = bytes(buf[1:1 + n])
                del buf[:1 + n]
                try:
                    packet = AmPacket.unpack(data)
                except MoteProtocolError:
                    self.stats.malformed += 1
                    continue
                self.stats.frames += 1
                self._deliver(packet)

    def send(self, packet: AmPacket) -> None:
        self._check()
        data = packet.pack()
        try:
            with self._write_lock:
                self._sock.sendall(bytes([len(data)]) + data)
        except OSError as exc:
            raise MoteDisconnected(f"{self.where}: send failed ({exc.strerror or exc})") from None
        self.stats.sent += 1

    def reopen(self) -> None:
        self.close()
        self._sock = self._connect()
        self._start_reader()

    def close(self) -> None:
        self._stop.set()
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._stop_reader()
        try:
            self._sock.close()
        except OSError:
            pass


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise EOFError("peer closed during handshake")
        data += chunk
    return data


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


# ---------------------------------------------------------------------------------------------
# the LedController


def led_command(node: int, on: bool, mask: int = ALL_LEDS, src: int = 0, group: int = DEFAULT_GROUP) -> AmPacket:
    """The LED command packet for node address ``node``."""
    return AmPacket(dest=node, src=src, am_type=AM_LED_COMMAND,
                    payload=bytes([LED_ON if on else LED_OFF, mask & 0xFF]), group=group)


def led_report(node: int, on: bool, group: int = DEFAULT_GROUP) -> AmPacket:
    """The LED report a node sends back (used by the twin and tests)."""
    return AmPacket(dest=AM_BROADCAST, src=node, am_type=AM_LED_REPORT,
                    payload=bytes([node >> 8, node & 0xFF, LED_ON if on else LED_OFF]), group=group)


def parse_led_report(packet: AmPacket) -> tuple[int, bool] | None:
    """(node address, on) from an LED report, or None if the packet is not one."""
    if packet.am_type != AM_LED_REPORT or len(packet.payload) != 3 or packet.payload[2] not in (LED_OFF, LED_ON):
        return None
    node = (packet.payload[0] << 8) | packet.payload[1]
    if node != packet.src:
        return None
    return node, packet.payload[2] == LED_ON


_TRAILING_NUMBER = re.compile(r"(\d+)$")


def node_address(node_id: str | int, address_map: Mapping[str, int] | None = None) -> int:
    """fgloc node id -> 16-bit mote address: the map if given, else the id's trailing number (``n005`` -> 5)."""
    if isinstance(node_id, int):
        address = node_id
    elif address_map is not None and node_id in address_map:
        address = int(address_map[node_id])
    else:
        m = _TRAILING_NUMBER.search(str(node_id))
        if m is None:
            raise MoteError(f"node {node_id!r}: no mote address (give an address map or an id ending in a number)")
        address = int(m.group(1))
    if not 0 <= address < AM_BROADCAST:
        raise MoteError(f"node {node_id!r}: address {address} is outside 0..65534")
    return address


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


def parse_tcp_url(url: str) -> tuple[str, int]:
    """``tcp://HOST[:PORT]`` -> (host, port); port defaults to 9002."""
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    if parts.scheme != "tcp" or not parts.hostname:
        raise MoteError(f"--port {url}: expected tcp://HOST[:PORT]")
    try:
        return parts.hostname, parts.port or SF_PORT
    except ValueError:
        raise MoteError(f"--port {url}: bad port number") from None


def open_mote_network(port: str, address_map: Mapping[str, int] | None = None, ack_timeout: float = 0.25,
                      retries: int = 5, report_timeout: float = 0.5, attempts: int = 3,
                      baudrate: int = MICAZ_BAUD) -> MoteNetwork:
    """A serial device path, or ``tcp://HOST[:PORT]`` for a SerialForwarder."""
    if port.startswith("tcp://"):
        link: SerialMoteLink | SerialForwarderLink = SerialForwarderLink(*parse_tcp_url(port))
    else:
        link = SerialMoteLink(port, baudrate, ack_timeout, retries)
    return MoteNetwork(link, address_map, report_timeout, attempts)
