"""Active Messages (dispatch 0x00) and fgloc's LED application messages (pure).

AM header, big-endian: ``dest(2) src(2) len group type`` (protocols.md 3.3).

* **LED command**, PC -> node, AM type ``0x89`` (:data:`AM_LED_COMMAND`), dest = node
  address, payload 2 bytes: ``command`` (0x00 off, 0x01 on) and ``mask`` (bit 0..2 =
  LED 0..2; fgloc sends 0x07, all LEDs).
* **LED report**, node -> PC, AM type ``0x8A`` (:data:`AM_LED_REPORT`), src = node
  address, dest 0xFFFF, payload 3 bytes: node address (2 bytes, big-endian) and
  ``state`` (0x00 LEDs off, 0x01 on). The node sends it after executing a command;
  it is the application-level confirmation (a serial ACK only means the base
  station's UART got the frame, protocols.md 3.6).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from fgloc.drivers.tinyos.errors import MoteError, MoteProtocolError

DISPATCH_AM = 0x00
AM_BROADCAST = 0xFFFF
DEFAULT_GROUP = 0x22
AM_LED_COMMAND = 0x89
AM_LED_REPORT = 0x8A
LED_OFF, LED_ON = 0x00, 0x01
ALL_LEDS = 0x07


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
