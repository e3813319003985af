"""TinyOS 2.x motes (MicaZ BaseStation over serial, or a SerialForwarder over TCP) as a LedController.

Modules, bottom up (byte facts from ``shared/reference/protocols.md`` section 3;
fgloc's mote firmware messages in ``docs/hardware.md``):

* :mod:`~fgloc.drivers.tinyos.errors`: the :class:`MoteError` tree;
* :mod:`~fgloc.drivers.tinyos.messages`: :class:`AmPacket`, the LED command/report messages, node addresses;
* :mod:`~fgloc.drivers.tinyos.framing`: HDLC escaping, CRC-16, frame bodies, :class:`Deframer`;
* :mod:`~fgloc.drivers.tinyos.link`: the reader-thread base shared by both links;
* :mod:`~fgloc.drivers.tinyos.serial_link`: :class:`SerialMoteLink`, 0x44 frames resent until ACKed;
* :mod:`~fgloc.drivers.tinyos.forwarder`: :class:`SerialForwarderLink`, the TCP client;
* :mod:`~fgloc.drivers.tinyos.network`: :class:`MoteNetwork` (``set_led``) and :func:`open_mote_network`.

Malformed input never raises in a reader: bad CRC, truncated frames, escape errors,
over-long frames and unparsable packets are dropped and counted in ``LinkStats``.
The names below are re-exported for callers that only switch LEDs.
"""

from fgloc.drivers.tinyos.errors import MoteDisconnected, MoteError, MoteProtocolError, MoteTimeout
from fgloc.drivers.tinyos.network import MoteNetwork, open_mote_network

__all__ = ["MoteDisconnected", "MoteError", "MoteNetwork", "MoteProtocolError", "MoteTimeout", "open_mote_network"]
