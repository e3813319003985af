"""Sony VISCA pan-tilt heads: codec, links (RS-232, UDP), a socket-matching session, and a PanTiltHead.

Modules, bottom up (byte facts from ``shared/reference/protocols.md`` sections 1 and 2.4):

* :mod:`~fgloc.drivers.visca.errors`: the :class:`ViscaError` tree, one class per error reply;
* :mod:`~fgloc.drivers.visca.codec`: nibble encoding, ``cmd_*`` packet builders, :func:`parse_reply`;
* :mod:`~fgloc.drivers.visca.packets`: :class:`PacketSplitter`, byte stream -> packets;
* :mod:`~fgloc.drivers.visca.serial_link`: :class:`SerialLink`, RS-232 via pyserial;
* :mod:`~fgloc.drivers.visca.ip`: :class:`ViscaIpLink`, VISCA over IP (UDP 52381);
* :mod:`~fgloc.drivers.visca.session`: :class:`ViscaSession`, ACK/completion matching, retries;
* :mod:`~fgloc.drivers.visca.head`: :class:`ViscaHead`, ``PanTiltHead`` in spec radians.

The names below are re-exported for callers that only open a head.
"""

from fgloc.drivers.visca.errors import (
    ViscaDisconnected,
    ViscaError,
    ViscaErrorReply,
    ViscaProtocolError,
    ViscaTimeout,
)
from fgloc.drivers.visca.head import HeadSettings, ViscaHead, open_serial_head
from fgloc.drivers.visca.ip import open_ip_head
from fgloc.drivers.visca.session import Timeouts, ViscaSession

__all__ = [
    "HeadSettings", "Timeouts", "ViscaDisconnected", "ViscaError", "ViscaErrorReply", "ViscaHead",
    "ViscaProtocolError", "ViscaSession", "ViscaTimeout", "open_ip_head", "open_serial_head",
]
