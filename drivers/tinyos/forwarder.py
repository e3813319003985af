"""A SerialForwarder TCP client (default port 9002): ``U `` handshake, then length-prefixed packets.

Each packet is one length byte + (dispatch + AM header + payload), no framing, no
CRC, no ACKs (protocols.md 3.8).
"""

from __future__ import annotations

import socket
from urllib.parse import urlsplit

from fgloc.drivers.tinyos.errors import MoteDisconnected, MoteError, MoteProtocolError
from fgloc.drivers.tinyos.link import ReaderLink
from fgloc.drivers.tinyos.messages import AmPacket

SF_PORT = 9002
SF_HELLO = b"U "


class SerialForwarderLink(ReaderLink):
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


def parse_tcp_url(url: str) -> tuple[str, int]:
    """``tcp://HOST[:PORT]`` -> (host, port); port defaults to 9002."""
    parts = urlsplit(url)
    if parts.scheme != "tcp" or not parts.hostname:
        raise MoteError(f"--port {url}: expected tcp://HOST[:PORT]")
    try:
        return parts.hostname, parts.port or SF_PORT
    except ValueError:
        raise MoteError(f"--port {url}: bad port number") from None
