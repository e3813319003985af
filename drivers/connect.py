"""Open rig hardware from a port string: the one place that maps ``--port`` to a driver.

* ``/dev/ttyUSB0`` (any path / ``COM3``) -> VISCA over RS-232 (:mod:`fgloc.drivers.visca.serial_link`)
  for heads, TinyOS serial BaseStation (:mod:`fgloc.drivers.tinyos`) for motes;
* ``udp://HOST[:PORT]``  -> VISCA over IP (:mod:`fgloc.drivers.visca.ip`), port 52381 by default;
  ``HeadOptions.reply_port`` (rig.json ``reply_port``) binds the controller side to a fixed
  port for cameras that send replies there (52381) instead of to the sender's port;
* ``http://[USER:PASSWORD@]HOST[:PORT]`` -> Sony CGI (:mod:`fgloc.drivers.sony_cgi`); credentials
  may instead come from ``FGLOC_CAMERA_USER`` / ``FGLOC_CAMERA_PASSWORD``;
* ``tcp://HOST[:PORT]``  -> SerialForwarder (motes only), port 9002 by default.

The camera model defaults per transport (serial: EVI-D100, udp: VISCA-IP, http:
SNC-RZ25N); the mounting defaults to ``desk``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

from fgloc.core.errors import FglocError
from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.drivers.head_adapter import FrameSourceArg
from fgloc.drivers.ptz_units import (
    EVI_D100,
    SNC_RZ25N,
    VISCA_IP_GENERIC,
    CameraModel,
    PanTiltUnits,
    camera_model,
    mounting,
)
from fgloc.drivers.visca.session import Timeouts


@dataclass(frozen=True)
class HeadOptions:
    """What a caller may choose when opening a head (all optional)."""

    camera_model: str | None = None
    mount: str = "desk"
    address: int = 1
    timeout: float = 0.3  # ACK / inquiry / HTTP timeout, seconds
    retries: int = 3
    completion_margin: float = 1.0  # added to the nominal move time before a Completion counts as lost
    http_timeout: float | None = None  # per HTTP request; None: max(timeout, 2 s)
    video: str | None = None  # cv2.VideoCapture source for grab_frame
    reply_port: int | None = None  # udp only: fixed local port the camera replies to (e.g. 52381)


def transport_of(port: str) -> str:
    """``serial``, ``udp``, ``http`` or ``tcp`` for a port string."""
    low = port.lower()
    for scheme in ("udp", "http", "https", "tcp"):
        if low.startswith(scheme + "://"):
            return "http" if scheme == "https" else scheme
    if "://" in port:
        raise FglocError(f"--port {port.split('://')[0]}://...: unknown scheme (use a serial device, udp://, http://"
                         " or tcp://)")
    return "serial"


def default_model(transport: str) -> CameraModel:
    return {"serial": EVI_D100, "udp": VISCA_IP_GENERIC, "http": SNC_RZ25N}[transport]


def open_head(port: str, options: HeadOptions | None = None, frames: FrameSourceArg = None) -> PanTiltHead:
    """A ``fgloc.core.hardware.PanTiltHead`` for ``port`` (initialised and answering), see the module doc."""
    o = options or HeadOptions()
    transport = transport_of(port)
    if transport == "tcp":
        raise FglocError(f"--port {port}: tcp:// is for a mote SerialForwarder, not a camera")
    if o.reply_port is not None and transport != "udp":
        raise FglocError(f"--port {transport}: reply_port is for VISCA over IP (udp://) only ({o.reply_port})")
    model = camera_model(o.camera_model) if o.camera_model else default_model(transport)
    units = PanTiltUnits(model, mounting(o.mount))
    if frames is None and o.video:
        from fgloc.drivers.frames import open_frame_source

        source = open_frame_source(o.video)
        try:
            return _open_head(port, transport, units, o, source)
        except BaseException:
            if source is not None:
                source.close()  # the video device is not left open when the head does not open
            raise
    return _open_head(port, transport, units, o, frames)


def _open_head(port: str, transport: str, units: PanTiltUnits, o: HeadOptions, frames: FrameSourceArg
               ) -> PanTiltHead:
    timeouts = Timeouts(ack=o.timeout, inquiry=o.timeout, completion_margin=o.completion_margin, retries=o.retries)
    if transport == "serial":
        from fgloc.drivers.visca.head import open_serial_head

        return open_serial_head(port, units, o.address, timeouts, frames)
    if transport == "udp":
        from fgloc.drivers.visca.ip import open_ip_head

        return open_ip_head(port, None, units, timeouts, frames, local_port=o.reply_port or 0)
    from fgloc.drivers.sony_cgi import Credentials, open_cgi_head, split_url

    _, url_creds = split_url(port)
    creds = url_creds
    if creds is None and os.environ.get("FGLOC_CAMERA_USER"):
        creds = Credentials(os.environ["FGLOC_CAMERA_USER"], os.environ.get("FGLOC_CAMERA_PASSWORD", ""))
    # an old network camera answers HTTP far slower than VISCA: at least 2 s per request by default
    http_timeout = o.http_timeout if o.http_timeout is not None else max(o.timeout, 2.0)
    return open_cgi_head(port, units, creds, timeout=http_timeout, retries=o.retries, frames=frames)


def open_leds(port: str, address_map: Mapping[str, int] | None = None, timeout: float = 0.25, retries: int = 5,
              report_timeout: float = 0.5, attempts: int = 3) -> LedController:
    """A ``fgloc.core.hardware.LedController`` (:class:`fgloc.drivers.tinyos.network.MoteNetwork`) for a serial port or tcp://."""
    from fgloc.drivers.tinyos.network import open_mote_network

    transport = transport_of(port)
    if transport not in ("serial", "tcp"):
        raise FglocError(f"--port {port}: motes need a serial device or tcp://HOST:PORT (SerialForwarder)")
    return open_mote_network(port, address_map, timeout, retries, report_timeout, attempts)
