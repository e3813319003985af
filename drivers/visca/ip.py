"""VISCA over IP (Sony SRG/BRC, PTZOptics, ...): UDP 52381, 8-byte header, sequence numbers.

Message = header + payload, big-endian (protocols.md 2.4)::

    type(2)  length(2)  sequence(4)  payload(1..16)

The VISCA payloads are exactly the serial packets of :mod:`fgloc.drivers.visca.codec` (camera
address fixed at 1, replies ``90 ...``); this module only adds the header, the
sequence number and the retransmission rule, and plugs into the same
:class:`fgloc.drivers.visca.session.ViscaSession` / :class:`fgloc.drivers.visca.head.ViscaHead`.

Retransmission: on a timeout the session resends with ``retransmit=True`` and the
link reuses the *same* sequence number. If the original arrived and only the
reply was lost, the camera answers ``0F 01`` (sequence abnormality: already
executed); the link then gives the next resend a *new* number so the (idempotent)
command runs again and its ACK/Completion come back. Replies whose sequence
number belongs to no outstanding request are dropped as stale: a late Completion of
an earlier command can never pass for the current one's (an inquiry sent while a
command waits for its Completion keeps that command's number outstanding).

Payload type of inquiries: ``01 10`` (Sony's document) by default. Sony SRG firmware
also accepts ``01 00``; a camera that accepts only ``01 00`` answers ``0F 02``
(message-type abnormality) to a ``01 10`` inquiry, and the link then switches to
``01 00`` for inquiries and resends at once (``inquiry_type`` chooses the start).

Fixed reply port: several cameras of the family send replies to UDP port 52381 on the
controller instead of the sender's port; ``local_port=52381`` binds the link there
(with ``SO_REUSEADDR``, so several camera links can share the port: each socket is
connected to its camera, and the kernel delivers a datagram to the socket connected
to its sender).
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass

from fgloc.core.retry import RetryPolicy
from fgloc.drivers.visca.codec import is_inquiry
from fgloc.drivers.visca.errors import ViscaDisconnected, ViscaError, ViscaProtocolError, ViscaTimeout
from fgloc.drivers.visca.head import HeadSettings, ViscaHead
from fgloc.drivers.visca.session import Timeouts, ViscaSession

DEFAULT_PORT = 52381
HEADER = struct.Struct(">HHI")

TYPE_COMMAND = 0x0100
TYPE_INQUIRY = 0x0110
TYPE_REPLY = 0x0111
TYPE_SETTING = 0x0120
TYPE_CONTROL = 0x0200
TYPE_CONTROL_REPLY = 0x0201

CONTROL_RESET = b"\x01"
CONTROL_ACK = b"\x01"
ERROR_SEQUENCE = b"\x0f\x01"
ERROR_MESSAGE_TYPE = b"\x0f\x02"


@dataclass(frozen=True)
class IpMessage:
    """One VISCA-over-IP datagram."""

    payload_type: int
    sequence: int
    payload: bytes


def encode_message(payload_type: int, sequence: int, payload: bytes) -> bytes:
    """Header + payload; payload 1..16 bytes, sequence 0..2^32-1."""
    if not 1 <= len(payload) <= 16:
        raise ValueError(f"VISCA-over-IP payload must be 1..16 bytes, got {len(payload)}")
    return HEADER.pack(payload_type, len(payload), sequence & 0xFFFFFFFF) + payload


def decode_message(data: bytes) -> IpMessage:
    """Parse one datagram; ViscaProtocolError when the header is inconsistent."""
    if len(data) < HEADER.size + 1:
        raise ViscaProtocolError(f"VISCA-over-IP datagram too short ({len(data)} bytes)")
    payload_type, length, sequence = HEADER.unpack_from(data)
    payload = data[HEADER.size:]
    if length != len(payload) or not 1 <= length <= 16:
        raise ViscaProtocolError(f"VISCA-over-IP length field {length} but {len(payload)} payload bytes")
    return IpMessage(payload_type, sequence, bytes(payload))


def reset_message(sequence: int = 0) -> bytes:
    """RESET control message ``02 00 00 01 ss ss ss ss 01`` (its sequence field is ignored)."""
    return encode_message(TYPE_CONTROL, sequence, CONTROL_RESET)


def parse_udp_url(url: str) -> tuple[str, int]:
    """``udp://HOST[:PORT]`` -> (host, port); port defaults to 52381."""
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    if parts.scheme != "udp" or not parts.hostname:
        raise ViscaError(f"--port {url}: expected udp://HOST[:PORT]")
    try:
        port = parts.port or DEFAULT_PORT
    except ValueError:
        raise ViscaError(f"--port {url}: bad port number") from None
    return parts.hostname, port


class ViscaIpLink:
    """A :class:`fgloc.drivers.visca.session.ViscaLink` over UDP with sequence numbers and RESET."""

    #: replies echo their request's sequence number and replies to earlier requests are dropped here,
    #: so the session needs no stray-Completion windows on this link
    tags_replies = True

    def __init__(self, host: str, port: int = DEFAULT_PORT, local_port: int = 0,
                 reset_timeout: float = 0.3, reset_tries: int = 3, inquiry_type: int = TYPE_INQUIRY) -> None:
        self.host, self.port, self.local_port = host, port, local_port
        self.reset_timeout, self.reset_tries = reset_timeout, reset_tries
        self.inquiry_type = inquiry_type
        self._sequence = 0
        self._outstanding: set[int] = set()  # sequence numbers of the current request (and its resends)
        self._command_outstanding: set[int] = set()  # the current command's, kept while inquiries run
        self._last: bytes | None = None
        self._new_sequence_needed = False
        self.stale = 0
        self.sequence_errors = 0
        self._sock = self._open()
        self.reset()

    def _open(self) -> socket.socket:
        try:
            infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)
            family, _, _, _, address = infos[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
        except OSError as exc:
            raise ViscaDisconnected(f"udp://{self.host}:{self.port}: {exc.strerror or exc}") from None
        try:
            if self.local_port:  # a fixed reply port may be shared by the links to several cameras
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("", self.local_port) if family == socket.AF_INET else ("::", self.local_port))
        except OSError as exc:
            sock.close()
            raise ViscaDisconnected(f"udp://{self.host}:{self.port}: cannot receive on local UDP port "
                                    f"{self.local_port} ({exc.strerror or exc})") from None
        try:
            sock.connect(address)  # receive only from the camera; ICMP errors become ConnectionRefused
        except OSError as exc:
            sock.close()
            raise ViscaDisconnected(f"udp://{self.host}:{self.port}: {exc.strerror or exc}") from None
        return sock

    @property
    def where(self) -> str:
        return f"udp://{self.host}:{self.port}"

    def _raw_send(self, data: bytes) -> None:
        try:
            self._sock.send(data)
        except OSError as exc:
            raise ViscaDisconnected(f"{self.where}: send failed ({exc.strerror or exc})") from None

    def _raw_receive(self, timeout: float) -> bytes | None:
        self._sock.settimeout(max(timeout, 1e-3))
        try:
            return self._sock.recv(2048)
        except TimeoutError:
            return None
        except ConnectionRefusedError:
            raise ViscaDisconnected(f"{self.where}: camera unreachable (connection refused)") from None
        except OSError as exc:
            raise ViscaDisconnected(f"{self.where}: receive failed ({exc.strerror or exc})") from None

    def reset(self) -> None:
        """Send RESET until the camera acknowledges (``reset_tries`` tries, ``reset_timeout`` s each);
        numbering restarts at 1."""

        def attempt(n: int) -> None:
            self._raw_send(reset_message(0))
            deadline = time.monotonic() + self.reset_timeout
            while (remaining := deadline - time.monotonic()) > 0:
                data = self._raw_receive(remaining)
                if data is None:
                    break
                try:
                    msg = decode_message(data)
                except ViscaProtocolError:
                    continue
                if msg.payload_type == TYPE_CONTROL_REPLY and msg.payload == CONTROL_ACK:
                    return
            raise ViscaTimeout(f"{self.where}: no reply to the VISCA-over-IP RESET (camera off, wrong port, "
                               "or it replies to a fixed port: set reply_port)")

        RetryPolicy(self.reset_tries, ViscaTimeout).call(attempt)
        self._sequence = 0
        self._outstanding.clear()
        self._command_outstanding.clear()
        self._new_sequence_needed = False

    def send(self, packet: bytes, retransmit: bool = False) -> None:
        inquiry = is_inquiry(packet)
        if not retransmit or self._new_sequence_needed or not self._outstanding:
            self._sequence = (self._sequence + 1) & 0xFFFFFFFF
            if not retransmit:
                self._outstanding.clear()
                if not inquiry:
                    self._command_outstanding.clear()
            self._new_sequence_needed = False
        self._outstanding.add(self._sequence)
        if not inquiry:
            self._command_outstanding.add(self._sequence)
        self._last = packet
        self._raw_send(encode_message(self.inquiry_type if inquiry else TYPE_COMMAND, self._sequence, packet))

    def receive(self, timeout: float) -> bytes | None:
        deadline = time.monotonic() + timeout
        while (remaining := deadline - time.monotonic()) > 0:
            data = self._raw_receive(remaining)
            if data is None:
                return None
            try:
                msg = decode_message(data)
            except ViscaProtocolError:
                self.stale += 1
                continue
            if msg.sequence not in self._outstanding and msg.sequence not in self._command_outstanding:
                self.stale += 1
                continue
            if msg.payload_type == TYPE_CONTROL_REPLY:
                if msg.payload == ERROR_SEQUENCE:
                    self.sequence_errors += 1
                    self._new_sequence_needed = True  # already executed; rerun under a new number
                elif msg.payload == ERROR_MESSAGE_TYPE:
                    if self._last is not None and is_inquiry(self._last) and self.inquiry_type == TYPE_INQUIRY:
                        self.inquiry_type = TYPE_COMMAND  # a camera that takes inquiries only as 01 00
                        self.send(self._last)
                        continue
                    raise ViscaProtocolError(f"{self.where}: camera rejected the message type")
                continue
            if msg.payload_type == TYPE_REPLY:
                return msg.payload
            self.stale += 1
        return None

    def flush_input(self) -> None:
        while self._raw_receive(1e-3) is not None:
            pass

    def reopen(self) -> None:
        self.close()
        self._sock = self._open()
        self.reset()

    def close(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass


def open_ip_head(url_or_host: str, port: int | None = None, units=None, timeouts: Timeouts | None = None,
                 frames=None, settings: HeadSettings | None = None, local_port: int = 0) -> ViscaHead:
    """Open a VISCA-over-IP head (``udp://HOST[:PORT]`` or a host name): RESET, then IF_Clear.

    ``local_port`` (0 = any): the controller port to receive on, 52381 for cameras that send
    their replies there rather than to the sender's port."""
    if url_or_host.startswith("udp://"):
        host, p = parse_udp_url(url_or_host)
    else:
        host, p = url_or_host, port or DEFAULT_PORT
    link = ViscaIpLink(host, port or p, local_port=local_port)
    head = ViscaHead(ViscaSession(link, 1, timeouts), units, frames, settings)
    try:
        head.initialize(address_set=False)  # Address Set is not used over IP
    except ViscaError:
        link.close()
        raise
    return head
