"""VISCA byte stream -> packets (resyncs on a header byte, drops and counts garbage)."""

from __future__ import annotations

from fgloc.drivers.visca.codec import MAX_PACKET, TERMINATOR


class PacketSplitter:
    """Split a VISCA byte stream into packets ``(hdr) ... FF``.

    Bytes before a header (bit 7 set) are discarded; packets longer than 16 bytes
    are discarded. No byte inside a reply has bit 7 set (data are nibbles, kinds
    are 0x3y-0x6y), so a header byte in the middle of a packet means its
    terminator was lost: the partial packet is dropped and a new one starts there.
    Drops are counted in ``dropped_bytes`` / ``dropped_packets``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped_bytes = 0
        self.dropped_packets = 0

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        for b in data:
            if not self._buf:
                if b & 0x80 and b != TERMINATOR:
                    self._buf.append(b)
                else:
                    self.dropped_bytes += 1
                continue
            if b & 0x80 and b != TERMINATOR:  # a new header: the previous packet lost its FF
                self.dropped_packets += 1
                self.dropped_bytes += len(self._buf)
                self._buf.clear()
            self._buf.append(b)
            if b == TERMINATOR:
                out.append(bytes(self._buf))
                self._buf.clear()
            elif len(self._buf) >= MAX_PACKET:
                self.dropped_packets += 1
                self.dropped_bytes += len(self._buf)
                self._buf.clear()
        return out

    def reset(self) -> None:
        self._buf.clear()
