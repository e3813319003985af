"""A simulated MicaZ BaseStation + motes: on a pty (HDLC frames) and as a SerialForwarder (TCP).

:class:`MoteFieldEmulator` is the radio side: nodes that execute the LED command
(:data:`fgloc.drivers.tinyos.messages.AM_LED_COMMAND`) and answer with an LED report after
``radio_delay`` seconds. Nodes listed in ``silent`` never answer (a dead mote or
one out of radio range); ``led_on`` holds every node's LED state and ``on_led`` is
called on each change, so a simulated scene can light the LED in rendered frames.

:class:`BaseStationSerialTwin` speaks the serial protocol on a pty: it ACKs every
0x44 frame whose CRC is right (as SerialP does, before the application sees it),
ignores frames with a bad CRC, and sends reports as 0x45 frames.
:class:`SerialForwarderTwin` is a SerialForwarder on 127.0.0.1 (``U `` handshake,
length-prefixed packets); like the real one it forwards every packet from the motes to
*every* connected client, not only to the client whose command caused it (a packet a
client sends goes to the motes only, as in TinyOS 2's SerialForwarder). Both take a :class:`~fgloc.drivers.twins.faults.FaultConfig`:
``drop`` loses an outgoing ACK/report, ``garble`` corrupts one byte of it, ``error``
answers with an unknown-protocol (0xFF) frame (serial) or drops the command (SF),
``slow`` delays it, ``disconnect`` closes the pty / TCP connection.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterable

from fgloc.drivers.tinyos.blink import AM_BLINK_CODE, BlinkField
from fgloc.drivers.tinyos.errors import MoteProtocolError
from fgloc.drivers.tinyos.forwarder import SF_HELLO
from fgloc.drivers.tinyos.framing import (
    PROTO_ACK,
    PROTO_PACKET_ACK,
    PROTO_PACKET_NOACK,
    PROTO_UNKNOWN,
    Deframer,
    ack_frame,
    data_frame,
    frame,
    parse_body,
)
from fgloc.drivers.tinyos.messages import AM_LED_COMMAND, LED_OFF, LED_ON, AmPacket, led_report
from fgloc.drivers.twins.faults import FaultConfig, FaultInjector
from fgloc.drivers.twins.pty_twin import PtyTwin


class MoteFieldEmulator:
    """The motes behind the base station: AM packet in -> [(delay s, AM packet out)]."""

    def __init__(self, nodes: Iterable[int] | None = None, silent: Iterable[int] = (), radio_delay: float = 0.0,
                 on_led: Callable[[int, bool], None] | None = None) -> None:
        self.nodes = None if nodes is None else set(nodes)
        self.silent = set(silent)
        self.radio_delay = radio_delay
        self.on_led = on_led
        self.led_on: dict[int, bool] = {}
        self.received: list[AmPacket] = []
        self.blink = BlinkField()
        self._lock = threading.Lock()

    def handle(self, packet: AmPacket) -> list[tuple[float, AmPacket]]:
        with self._lock:
            self.received.append(packet)
            if packet.am_type == AM_BLINK_CODE:  # coded blink sequences (drivers/tinyos/blink.py)
                self.blink.nodes, self.blink.silent = self.nodes, self.silent
                return [(self.radio_delay, r) for r in self.blink.handle(packet)]
            if packet.am_type != AM_LED_COMMAND or len(packet.payload) != 2 or packet.payload[0] not in (LED_OFF,
                                                                                                         LED_ON):
                return []
            node = packet.dest
            if (self.nodes is not None and node not in self.nodes) or node in self.silent:
                return []
            on = packet.payload[0] == LED_ON
            changed = self.led_on.get(node) != on
            self.led_on[node] = on
        if changed and self.on_led is not None:
            self.on_led(node, on)
        return [(self.radio_delay, led_report(node, on, packet.group))]


class BaseStationSerialTwin(PtyTwin[bytes]):
    """Base station on a pty at the byte level; open :attr:`port` with pyserial. Context manager."""

    def __init__(self, field: MoteFieldEmulator | None = None, faults: FaultConfig | None = None) -> None:
        self.field = field or MoteFieldEmulator()
        self.deframer = Deframer()
        self.acks_received: list[int] = []
        super().__init__("basestation", "basestation-twin", faults)

    def _reset_link(self) -> None:
        self.deframer = Deframer(self.deframer.stats)

    def _emit(self, due: float, data: bytes, can_be_slow: bool = True) -> None:
        sent = self.faults.faulted_reply(data, can_be_slow, garble=self._garble_inside_flags)
        if sent is not None:
            self._out.put(due + sent[0], sent[1])

    def _garble_inside_flags(self, data: bytes) -> bytes:
        """``data`` with one byte between its HDLC flags garbled."""
        return data[:1] + self.faults.garble(data[1:-1]) + data[-1:]

    def _on_bytes(self, data: bytes) -> None:
        for body in self.deframer.feed(data):
            self._on_body(body)

    def _on_body(self, body: bytes) -> None:
        try:
            f = parse_body(body)
        except MoteProtocolError:
            return
        if f.protocol == PROTO_ACK:  # the PC acknowledging a 0x44 frame we sent
            assert f.seq is not None  # parse_body sets it for ACK frames
            self.acks_received.append(f.seq)
            return
        if f.protocol not in (PROTO_PACKET_ACK, PROTO_PACKET_NOACK):
            self._out.put(time.monotonic(), frame(bytes([PROTO_UNKNOWN, f.protocol])))
            return
        if self.faults.count_request():
            self.disconnect(self.faults.config.reconnect_after)
            return
        now = time.monotonic()
        if self.faults.request_error() is not None:
            self._out.put(now, frame(bytes([PROTO_UNKNOWN, f.protocol])))
            return
        assert f.packet is not None  # a data frame
        if f.protocol == PROTO_PACKET_ACK:
            assert f.seq is not None
            self._emit(now, ack_frame(f.seq))
        for delay, packet in self.field.handle(f.packet):
            self._emit(now + delay, data_frame(packet, None))


class SerialForwarderTwin:
    """A TinyOS 2 SerialForwarder on ``127.0.0.1:port`` in front of a :class:`MoteFieldEmulator`."""

    def __init__(self, field: MoteFieldEmulator | None = None, faults: FaultConfig | None = None,
                 port: int = 0, hello: bytes = SF_HELLO) -> None:
        self.field = field or MoteFieldEmulator()
        self.faults = FaultInjector(faults)
        self.hello = hello
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind(("127.0.0.1", port))
        self._server.listen(4)
        self._server.settimeout(0.05)
        self.port = self._server.getsockname()[1]
        self._stop = threading.Event()
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._ready: set[socket.socket] = set()  # clients past the handshake (they get forwarded packets)
        self._down_until: float | None = None
        self.malformed = 0
        self._thread = threading.Thread(target=self._accept, name="sf-twin", daemon=True)
        self._thread.start()

    @property
    def clients_ready(self) -> int:
        """Connected clients past the handshake: the ones packets are forwarded to."""
        with self._lock:
            return len(self._ready)

    @property
    def url(self) -> str:
        return f"tcp://127.0.0.1:{self.port}"

    def disconnect(self, reconnect_after: float | None = None) -> None:
        """Drop every client; refuse new ones for ``reconnect_after`` s (forever if None)."""
        with self._lock:
            for c in self._clients:
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                c.close()
            self._clients.clear()
            self._ready.clear()
            self._down_until = float("inf") if reconnect_after is None else time.monotonic() + reconnect_after

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except (TimeoutError, OSError):
                continue
            if self._down_until is not None and time.monotonic() < self._down_until:
                client.close()
                continue
            with self._lock:
                self._clients.append(client)
            threading.Thread(target=self._serve, args=(client,), daemon=True).start()

    def _forward(self, packet: AmPacket) -> None:
        """One packet from the motes to every connected client (its faults decided once, as for a
        radio packet the base station received once)."""
        # line noise included: TCP itself never corrupts; it models a bad radio packet
        sent = self.faults.faulted_reply(packet.pack(), can_be_slow=True)
        if sent is None:
            return
        delay, data = sent
        if delay:
            time.sleep(delay)
        with self._lock:
            clients = [c for c in self._clients if c in self._ready]
        with self._send_lock:  # whole packets: two serving threads never interleave their bytes
            for client in clients:
                try:
                    client.sendall(bytes([len(data)]) + data)
                except OSError:
                    pass

    def _serve(self, client: socket.socket) -> None:
        try:
            client.settimeout(1.0)
            client.sendall(self.hello)
            peer = b""
            while len(peer) < 2:
                chunk = client.recv(2 - len(peer))
                if not chunk:
                    return
                peer += chunk
            if peer[:1] != b"U":
                return
            with self._lock:
                self._ready.add(client)
            client.settimeout(0.05)
            buf = bytearray()
            while not self._stop.is_set():
                try:
                    chunk = client.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                buf += chunk
                while buf and len(buf) >= 1 + buf[0]:
                    n = buf[0]
                    data = bytes(buf[1:1 + n])
                    del buf[:1 + n]
                    if n == 0:
                        self.malformed += 1
                        continue
                    try:
                        packet = AmPacket.unpack(data)
                    except MoteProtocolError:
                        self.malformed += 1
                        continue
                    if self.faults.count_request():
                        self.disconnect(self.faults.config.reconnect_after)
                        return
                    if self.faults.request_error() is not None:
                        continue
                    for delay, reply in self.field.handle(packet):
                        if delay:
                            time.sleep(delay)
                        self._forward(reply)
        except OSError:
            return
        finally:
            with self._lock:
                self._ready.discard(client)
                if client in self._clients:
                    self._clients.remove(client)
            try:
                client.close()
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self.disconnect(None)
        self._thread.join(timeout=2.0)
        self._server.close()

    def __enter__(self) -> SerialForwarderTwin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
