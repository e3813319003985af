"""Sony CGI driver (SNC-RZ25N) against its HTTP twin on 127.0.0.1."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from fgloc.drivers.ptz_units import SNC_RZ25N, PanTiltUnits
from fgloc.drivers.sony_cgi import Credentials, SonyCgiClient, SonyCgiError, hex16, open_cgi_head, split_url
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.drivers.visca.errors import CommandNotExecutable, ViscaDisconnected, ViscaTimeout

KW = dict(timeout=0.3, retries=3, poll_interval=0.01, move_timeout_margin=0.5)


def test_hex_encoding_of_negative_counts() -> None:
    assert hex16(-1000) == "FC18" and hex16(-1) == "FFFF" and hex16(2448) == "0990" and hex16(-2448) == "F670"


def test_url_credentials_are_split_off_and_hidden() -> None:
    base, creds = split_url("http://admin:s3cr%40t@10.0.0.5:8080")
    assert base == "http://10.0.0.5:8080" and creds == Credentials("admin", "s3cr@t")
    assert "s3cr" not in repr(creds) and "s3cr" not in repr(SonyCgiClient("http://admin:s3cret@h"))


def test_move_read_back_zoom_home_and_frame() -> None:
    def render(pose):
        return np.full((8, 8, 3), 100, np.uint8)

    with SonyCgiTwin(time_scale=0.01, renderer=render) as twin, open_cgi_head(twin.url, **KW) as head:
        head.move_to(math.radians(-120.0), math.radians(-60.0))
        assert head.position_counts() == (1728, -864)
        assert "POST /command/ptzf.cgi" in twin.requests
        head.set_zoom(1.0)
        assert head.zoom() == pytest.approx(1.0)
        head.home()
        pan, tilt = head.position()
        assert (pan, tilt) == (0.0, 0.0)
        frame = head.grab_frame()
        assert frame.shape == (8, 8, 3) and abs(int(frame[0, 0, 0]) - 100) <= 2


def test_credentials_required_and_never_leaked(caplog) -> None:
    caplog.set_level(logging.DEBUG)
    with SonyCgiTwin(user="admin", password="hunter2") as twin:
        with pytest.raises(SonyCgiError, match="authentication failed") as info:
            open_cgi_head(f"http://admin:wrong@127.0.0.1:{twin.port}", **KW)
        assert "wrong" not in str(info.value)
        head = open_cgi_head(f"http://admin:hunter2@127.0.0.1:{twin.port}", **KW)
        head.move_to_counts(10, 10)
        assert head.position_counts() == (10, 10)
    assert "hunter2" not in caplog.text and "wrong" not in caplog.text


def test_dropped_and_garbled_replies_recover() -> None:
    with SonyCgiTwin(faults=FaultConfig(drop_rate=0.15, garble_rate=0.15, seed=5)) as twin, \
            open_cgi_head(twin.url, **KW) as head:
        for k in range(8):
            head.move_to_counts(k * 100 - 400, -k * 50)
            assert head.position_counts() == (k * 100 - 400, -k * 50)
        assert twin.faults.counts["drop"] + twin.faults.counts["garble"] >= 3


def test_error_replies() -> None:
    with SonyCgiTwin() as twin, open_cgi_head(twin.url, **KW) as head:
        twin.faults.force_error()
        with pytest.raises(CommandNotExecutable):
            head.position_counts()
        head.position_counts()
        twin.faults.config.error_rate = 1.0
        with pytest.raises(SonyCgiError, match="HTTP 500"):
            head.move_to_counts(0, 0)
        twin.faults.config.error_rate = 0.0
        with pytest.raises(SonyCgiError, match="HTTP 400"):  # the camera rejects an illegal speed
            head.client.ptzf(AbsolutePanTilt="0000,0000,25")


def test_slow_answers_time_out() -> None:
    with SonyCgiTwin(faults=FaultConfig(slow_seconds=1.0)) as twin, open_cgi_head(twin.url, **KW) as head:
        twin.faults.force(*["slow"] * 4)
        with pytest.raises(ViscaTimeout):
            head.read_counts_once()


def test_disconnect_and_reconnect() -> None:
    with SonyCgiTwin(faults=FaultConfig(disconnect_after=1)) as twin, open_cgi_head(twin.url, **KW) as head:
        with pytest.raises(ViscaDisconnected, match="connection refused"):
            for _ in range(5):
                head.read_counts_once()
    with SonyCgiTwin(faults=FaultConfig(disconnect_after=1, reconnect_after=0.2)) as twin, \
            open_cgi_head(twin.url, timeout=0.3, retries=10, poll_interval=0.01) as head:
        assert head.position_counts() == (0, 0)


def test_units_of_the_rz25n_are_marked_unverified() -> None:
    assert not SNC_RZ25N.verified and "UNVERIFIED" in SNC_RZ25N.note
    assert PanTiltUnits(SNC_RZ25N).to_counts(math.radians(-170), 0) == (2448, 0)
