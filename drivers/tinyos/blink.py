"""The blink-code command: start (or stop) a mote's coded LED sequence, as a TinyOS Active Message.

**Command**, PC -> node, AM type ``0x8B`` (:data:`AM_BLINK_CODE`), dest = node address,
payload 10 bytes, multi-byte fields big-endian (``nx_`` types)::

    offset size field
    0      1    command      0x00 stop (LED off), 0x01 start
    1      1    length       code length L in bits, 8..32 (0 with stop)
    2      4    code         the code word in the low L bits; bit L-1 is sent first
    6      2    bit_period   one bit lasts bit_period x 10 us (e.g. 3337 = 33.37 ms,
                             one NTSC frame); 0 with stop
    8      2    cycles       how many times the word is repeated, 0 = until stopped

The node repeats the word from the moment the command arrives, LED on for a 1 bit,
and confirms with a **blink report**, node -> PC, AM type ``0x8C``
(:data:`AM_BLINK_REPORT`), dest 0xFFFF, src = node, payload 8 bytes: node address (2),
state (0x00 stopped, 0x01 running), length (1), code (4), so the base station knows
that the node runs the right word. Start times need no coordination: the code book
(:mod:`fgloc.camera.blink_codes`) is rotation-free.

**Broadcast start by address**, PC -> all nodes, the same AM type ``0x8B``, dest
``0xFFFF`` (:func:`blink_broadcast`), payload 10 bytes::

    offset size field
    0      1    command      0x02 start by address
    1      1    length       code length L in bits (the book's length)
    2      2    first        address A0 of book word 0
    4      2    count        N: addresses A0 .. A0 + N - 1 take book words 0 .. N - 1
    6      2    bit_period   as above, units of 10 us
    8      2    cycles       as above, 0 = until stopped

A node with address ``A`` in ``A0 .. A0 + N - 1`` runs word ``A - A0`` of the
``L``-bit book (:func:`word_for_address`); any other node stays dark. The book's words
are a deterministic greedy prefix (word ``k`` of the ``L``-bit book is the same for
every book size, :func:`fgloc.camera.blink_codes.code_book`), so the firmware holds one
generated table per length (1112 words x 4 bytes for L = 20) and never needs a word
from the radio. One broadcast replaces N unicast starts; a node that misses it is not
decoded, is reported missed and is started again by a unicast. Nodes still send their
blink report, after a random backoff, while the cameras record; nobody waits for them.
A stop for all nodes is the 10-byte stop payload sent to ``0xFFFF``.

**Synchronized start by address**: the same layout with command ``0x03``
(``BlinkBroadcast(..., synchronized=True)``). Node ``A`` runs word ``A - A0`` of the
*synchronized* ``L``-bit book (:func:`fgloc.camera.blink_codes.sync_code_book`) and
starts bit 0 of it when the packet arrives (the epoch); a node already running the
same word re-aligns its bit clock to that moment (the base station repeats the
packet at whole words of the nominal schedule, so the re-alignment only removes
crystal drift). Old payloads (0x00, 0x01, 0x02) are unchanged.

**Pause by bitmap** (radio separation of crowded motes, :class:`BlinkPause`), PC -> all
nodes, the same AM type ``0x8B``, dest ``0xFFFF`` only, payload ``4 + B`` bytes::

    offset size field
    0      1    command      0x04 pause by bitmap
    1      1    B            bitmap length in bytes, 1..24 (payload <= 28 bytes, TinyOS's
                             default TOSH_DATA_LENGTH)
    2      2    first        address of bitmap bit 0
    4      B    bitmap       bit k (byte k // 8, most significant bit first) is address
                             first + k: 1 paused, 0 running (resumed)

A node whose address the bitmap covers sets its *paused* flag from its bit; others
ignore the packet. A paused node keeps its word and its bit clock running but keeps
the LED dark; a resumed node lights its LED again from the current bit (the book is
rotation-free, so the phase does not matter). "Resume" is the same packet with the
node's bit 0. Nodes send no report (a pause is repeated instead: nobody waits for
hundreds of reports); a node that missed every repeat stays lit, its blob stays
ambiguous and is refused by the decoder, never guessed. A stop or a unicast start
clears the flag. Up to 192 addresses per packet (:func:`pause_packets` splits a range).
All earlier payloads (0x00-0x03) are unchanged.

Example (protocols.md 3.4 framing): start node 5 with the 16-bit word 0x0A5F at
33.37 ms per bit until stopped, seq 0x01::

    AM packet  00 00 05 00 00 0A 22 8B 01 10 00 00 0A 5F 0D 09 00 00
    on wire    7E 44 01 <the packet> 25 4A 7E   (CRC-16/XMODEM 0x4A25, low byte first)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fgloc.camera.blink_codes import CodeBook
from fgloc.drivers.tinyos.errors import MoteProtocolError
from fgloc.drivers.tinyos.messages import AM_BROADCAST, DEFAULT_GROUP, AmPacket

AM_BLINK_CODE = 0x8B
AM_BLINK_REPORT = 0x8C
BLINK_STOP, BLINK_START, BLINK_START_BY_ADDRESS, BLINK_START_SYNCHRONIZED = 0x00, 0x01, 0x02, 0x03
BLINK_PAUSE = 0x04
PAUSE_MAX_BYTES = 24  #: bitmap bytes per pause packet (4 + 24 = 28 bytes of payload)
MAX_CODE_BITS = 32
BIT_PERIOD_UNIT_S = 1e-5


@dataclass(frozen=True)
class BlinkCommand:
    """A blink-code command: ``start`` or stop, code word ``code`` of ``length`` bits,
    ``bit_period_s`` seconds per bit (10 us resolution), ``cycles`` repeats (0 = forever)."""

    start: bool
    length: int = 0
    code: int = 0
    bit_period_s: float = 0.0
    cycles: int = 0

    def payload(self) -> bytes:
        """The 10-byte payload (see the module docstring)."""
        if not self.start:
            return bytes(10)
        if not 8 <= self.length <= MAX_CODE_BITS:
            raise ValueError(f"code length {self.length} not in 8..{MAX_CODE_BITS}")
        if not 0 <= self.code < (1 << self.length):
            raise ValueError(f"code {self.code:#x} does not fit in {self.length} bits")
        period = round(self.bit_period_s / BIT_PERIOD_UNIT_S)
        if not 1 <= period <= 0xFFFF:
            raise ValueError(f"bit period {self.bit_period_s} s not in 10 us .. 655.35 ms")
        if not 0 <= self.cycles <= 0xFFFF:
            raise ValueError(f"cycles {self.cycles} not in 0..65535")
        return (bytes([BLINK_START, self.length]) + self.code.to_bytes(4, "big")
                + period.to_bytes(2, "big") + self.cycles.to_bytes(2, "big"))

    @staticmethod
    def from_payload(payload: bytes) -> BlinkCommand:
        """Inverse of :meth:`payload`; MoteProtocolError on a malformed payload."""
        if len(payload) != 10 or payload[0] not in (BLINK_STOP, BLINK_START):
            raise MoteProtocolError(f"not a blink command payload: {payload.hex(' ')}")
        if payload[0] == BLINK_STOP:
            return BlinkCommand(start=False)
        length = payload[1]
        code = int.from_bytes(payload[2:6], "big")
        period = int.from_bytes(payload[6:8], "big")
        if not 8 <= length <= MAX_CODE_BITS or code >> length or period == 0:
            raise MoteProtocolError(f"blink command: bad length/code/period: {payload.hex(' ')}")
        return BlinkCommand(True, length, code, period * BIT_PERIOD_UNIT_S, int.from_bytes(payload[8:10], "big"))


@dataclass(frozen=True)
class BlinkBroadcast:
    """Broadcast start by address: nodes ``first .. first + count - 1`` run words ``0 .. count - 1``
    of the ``length``-bit book, ``bit_period_s`` seconds per bit, ``cycles`` repeats (0 = forever)."""

    length: int
    first: int
    count: int
    bit_period_s: float
    cycles: int = 0
    synchronized: bool = False  #: command 0x03: the synchronized book, bit 0 at the packet's arrival

    def payload(self) -> bytes:
        """The 10-byte payload (see the module docstring)."""
        if not 8 <= self.length <= MAX_CODE_BITS:
            raise ValueError(f"code length {self.length} not in 8..{MAX_CODE_BITS}")
        if not 0 <= self.first <= 0xFFFE or not 1 <= self.count <= 0xFFFF - self.first:
            raise ValueError(f"addresses {self.first} + {self.count} not in 0..0xFFFE")
        period = round(self.bit_period_s / BIT_PERIOD_UNIT_S)
        if not 1 <= period <= 0xFFFF:
            raise ValueError(f"bit period {self.bit_period_s} s not in 10 us .. 655.35 ms")
        if not 0 <= self.cycles <= 0xFFFF:
            raise ValueError(f"cycles {self.cycles} not in 0..65535")
        command = BLINK_START_SYNCHRONIZED if self.synchronized else BLINK_START_BY_ADDRESS
        return (bytes([command, self.length]) + self.first.to_bytes(2, "big")
                + self.count.to_bytes(2, "big") + period.to_bytes(2, "big") + self.cycles.to_bytes(2, "big"))

    @staticmethod
    def from_payload(payload: bytes) -> BlinkBroadcast:
        """Inverse of :meth:`payload`; MoteProtocolError on a malformed payload."""
        if len(payload) != 10 or payload[0] not in (BLINK_START_BY_ADDRESS, BLINK_START_SYNCHRONIZED):
            raise MoteProtocolError(f"not a broadcast blink payload: {payload.hex(' ')}")
        length = payload[1]
        first, count, period, cycles = (int.from_bytes(payload[i:i + 2], "big") for i in (2, 4, 6, 8))
        if not 8 <= length <= MAX_CODE_BITS or count == 0 or period == 0 or first + count > 0xFFFF:
            raise MoteProtocolError(f"broadcast blink: bad length/addresses/period: {payload.hex(' ')}")
        return BlinkBroadcast(length, first, count, period * BIT_PERIOD_UNIT_S, cycles,
                              payload[0] == BLINK_START_SYNCHRONIZED)

    def word_index(self, address: int) -> int | None:
        """Book index node ``address`` runs, or None (the node stays dark)."""
        k = address - self.first
        return k if 0 <= k < self.count else None


@dataclass(frozen=True)
class BlinkPause:
    """Pause by bitmap: of addresses ``first .. first + 8 nbytes - 1``, those in ``paused``
    pause (LED dark, word and bit clock kept) and the others resume."""

    first: int
    nbytes: int
    paused: frozenset[int] = frozenset()

    def covers(self, address: int) -> bool:
        return self.first <= address < self.first + 8 * self.nbytes

    def payload(self) -> bytes:
        """The ``4 + nbytes``-byte payload (see the module docstring)."""
        if not 1 <= self.nbytes <= PAUSE_MAX_BYTES:
            raise ValueError(f"pause bitmap of {self.nbytes} bytes not in 1..{PAUSE_MAX_BYTES}")
        if not 0 <= self.first or self.first + 8 * self.nbytes > 0xFFFF:
            raise ValueError(f"pause addresses {self.first} + {8 * self.nbytes} not in 0..0xFFFE")
        outside = sorted(a for a in self.paused if not self.covers(a))
        if outside:
            raise ValueError(f"paused addresses {outside[:3]} outside the bitmap")
        bits = bytearray(self.nbytes)
        for a in self.paused:
            k = a - self.first
            bits[k // 8] |= 0x80 >> (k % 8)
        return bytes([BLINK_PAUSE, self.nbytes]) + self.first.to_bytes(2, "big") + bytes(bits)

    @staticmethod
    def from_payload(payload: bytes) -> BlinkPause:
        """Inverse of :meth:`payload`; MoteProtocolError on a malformed payload."""
        if len(payload) < 5 or payload[0] != BLINK_PAUSE or not 1 <= payload[1] <= PAUSE_MAX_BYTES \
                or len(payload) != 4 + payload[1]:
            raise MoteProtocolError(f"not a pause payload: {payload.hex(' ')}")
        nbytes = payload[1]
        first = int.from_bytes(payload[2:4], "big")
        if first + 8 * nbytes > 0xFFFF:
            raise MoteProtocolError(f"pause: addresses beyond 0xFFFE: {payload.hex(' ')}")
        paused = frozenset(first + k for k in range(8 * nbytes) if payload[4 + k // 8] & (0x80 >> (k % 8)))
        return BlinkPause(first, nbytes, paused)


def pause_packets(paused: set[int] | frozenset[int], addresses: range) -> list[BlinkPause]:
    """The fewest pause packets that set every address of ``addresses`` (a step-1 range):
    paused if in ``paused``, resumed otherwise (192 addresses per packet)."""
    per = 8 * PAUSE_MAX_BYTES
    out = []
    for a0 in range(addresses.start, addresses.stop, per):
        n = min(per, addresses.stop - a0)
        out.append(BlinkPause(a0, math.ceil(n / 8), frozenset(a for a in paused if a0 <= a < a0 + n)))
    return out


def blink_broadcast(command: BlinkBroadcast | BlinkCommand | BlinkPause, src: int = 0, group: int = DEFAULT_GROUP) -> AmPacket:
    """The AM packet broadcasting a start by address, or a stop (``BlinkCommand(start=False)``), to all nodes."""
    if isinstance(command, BlinkCommand) and command.start:
        raise ValueError("a unicast start carries one node's word; broadcast a BlinkBroadcast instead")
    return AmPacket(dest=AM_BROADCAST, src=src, am_type=AM_BLINK_CODE, payload=command.payload(), group=group)


def word_for_address(book: CodeBook, command: BlinkBroadcast, address: int) -> int | None:
    """The code word node ``address`` runs after ``command`` (what the firmware's table gives),
    or None when the node stays dark or ``book`` has another length or too few words."""
    k = command.word_index(address)
    if k is None or book.length != command.length or k >= len(book) or book.synchronized != command.synchronized:
        return None
    return book.words[k]


def blink_command(node: int, command: BlinkCommand, src: int = 0, group: int = DEFAULT_GROUP) -> AmPacket:
    """The AM packet carrying ``command`` to node address ``node``."""
    return AmPacket(dest=node, src=src, am_type=AM_BLINK_CODE, payload=command.payload(), group=group)


def parse_blink_command(packet: AmPacket) -> BlinkCommand | BlinkBroadcast | BlinkPause | None:
    """The command in ``packet``, or None when it is not a (well-formed) blink command.
    A start by address and a pause are only valid broadcast (dest 0xFFFF)."""
    if packet.am_type != AM_BLINK_CODE:
        return None
    try:
        if packet.payload[:1] == bytes([BLINK_PAUSE]):
            return BlinkPause.from_payload(packet.payload) if packet.dest == AM_BROADCAST else None
        if packet.payload[:1] in (bytes([BLINK_START_BY_ADDRESS]), bytes([BLINK_START_SYNCHRONIZED])):
            return BlinkBroadcast.from_payload(packet.payload) if packet.dest == AM_BROADCAST else None
        return BlinkCommand.from_payload(packet.payload)
    except MoteProtocolError:
        return None


def blink_report(node: int, running: bool, length: int, code: int, group: int = DEFAULT_GROUP) -> AmPacket:
    """The report a node sends after a blink command (used by the twin and tests)."""
    payload = node.to_bytes(2, "big") + bytes([0x01 if running else 0x00, length]) + code.to_bytes(4, "big")
    return AmPacket(dest=AM_BROADCAST, src=node, am_type=AM_BLINK_REPORT, payload=payload, group=group)


def parse_blink_report(packet: AmPacket) -> tuple[int, bool, int, int] | None:
    """(node, running, length, code) from a blink report, or None if the packet is not one."""
    p = packet.payload
    if packet.am_type != AM_BLINK_REPORT or len(p) != 8 or p[2] not in (0x00, 0x01):
        return None
    node = int.from_bytes(p[0:2], "big")
    if node != packet.src:
        return None
    return node, p[2] == 0x01, p[3], int.from_bytes(p[4:8], "big")


class BlinkField:
    """The motes' side of blink commands (the firmware's behaviour, used by the base-station twin).

    ``running[node] = (length, code)`` for every node blinking. A unicast start runs the
    word it carries, a start by address runs the node's word of the generated book table,
    a stop (unicast or broadcast) stops; every node that acted sends its blink report.
    A pause (:class:`BlinkPause`) sets ``paused`` for the addresses it covers (no report):
    a paused node stays in ``running`` (its bit clock runs) but its LED is dark
    (:meth:`lit`). ``nodes``: the addresses present (None: any address a command names exists).
    """

    def __init__(self, nodes: set[int] | None = None, silent: set[int] | None = None) -> None:
        self.nodes = nodes
        self.silent = silent or set()
        self.running: dict[int, tuple[int, int]] = {}
        self.paused: set[int] = set()

    def lit(self) -> dict[int, tuple[int, int]]:
        """``(length, code)`` of the nodes whose LED blinks now: running and not paused."""
        return {a: w for a, w in self.running.items() if a not in self.paused}

    def _present(self, node: int) -> bool:
        return (self.nodes is None or node in self.nodes) and node not in self.silent

    def handle(self, packet: AmPacket) -> list[AmPacket]:
        """Reports for one received AM packet (empty when it is no blink command)."""
        cmd = parse_blink_command(packet)
        if cmd is None:
            return []
        if isinstance(cmd, BlinkPause):
            for a in range(cmd.first, cmd.first + 8 * cmd.nbytes):
                if not self._present(a):
                    continue
                if a in cmd.paused:
                    self.paused.add(a)
                else:
                    self.paused.discard(a)
            return []
        if isinstance(cmd, BlinkBroadcast):
            from fgloc.camera.blink_codes import code_book, sync_code_book

            book = (sync_code_book if cmd.synchronized else code_book)(cmd.count, cmd.length)
            addrs = range(cmd.first, cmd.first + cmd.count) if self.nodes is None else sorted(self.nodes)
            out = []
            for a in addrs:
                word = word_for_address(book, cmd, a)
                if word is not None and self._present(a):
                    self.running[a] = (cmd.length, word)
                    out.append(blink_report(a, True, cmd.length, word, packet.group))
            return out
        targets = ([packet.dest] if packet.dest != AM_BROADCAST
                   else sorted(self.running) if self.nodes is None else sorted(self.nodes))
        out = []
        for node in targets:
            if not self._present(node):
                continue
            self.paused.discard(node)
            if cmd.start:
                self.running[node] = (cmd.length, cmd.code)
            else:
                self.running.pop(node, None)
            out.append(blink_report(node, cmd.start, cmd.length, cmd.code, packet.group))
        return out
