"""Twins bind loopback only, and leave no thread, pty or port behind after their ``with`` block."""

from __future__ import annotations

import os
import socket
import threading
import time

from fgloc.drivers.twins.base_station import BaseStationSerialTwin, SerialForwarderTwin
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.drivers.twins.visca_camera import ViscaSerialTwin
from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin

TWIN_THREADS = ("visca-serial-twin", "visca-ip-twin", "sony-cgi-twin", "basestation-twin", "sf-twin")


def _twin_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name in TWIN_THREADS and t.is_alive()]


def test_pty_twins_clean_up() -> None:
    for cls in (ViscaSerialTwin, BaseStationSerialTwin):
        with cls() as twin:
            path = twin.port
            assert os.path.exists(path) and os.path.realpath(path).startswith("/dev/pts/")
        assert not os.path.exists(os.path.dirname(path))
    assert _twin_threads() == []


def test_socket_twins_bind_loopback_and_release_their_port() -> None:
    for cls, kind in ((ViscaIpTwin, socket.SOCK_DGRAM), (SonyCgiTwin, socket.SOCK_STREAM),
                      (SerialForwarderTwin, socket.SOCK_STREAM)):
        with cls() as twin:
            port = twin.port
            assert twin.url.split("//")[1].startswith("127.0.0.1:")
        deadline = time.monotonic() + 2.0
        while _twin_threads() and time.monotonic() < deadline:
            time.sleep(0.01)
        s = socket.socket(socket.AF_INET, kind)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))  # free again
        s.close()
    assert _twin_threads() == []
