"""``fgloc ptz`` and ``fgloc motes`` in-process against the twins (serial pty, UDP, HTTP, SerialForwarder)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from fgloc.cli import main
from fgloc.drivers.ptz_units import EVI_D30
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, MoteFieldEmulator, SerialForwarderTwin
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.drivers.twins.visca_camera import ViscaSerialTwin
from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin

POS = re.compile(r"^pan (-?\d+\.\d{3}) deg  tilt (-?\d+\.\d{3}) deg$")


def _pos(out: str) -> tuple[float, float]:
    m = POS.match(out.strip().splitlines()[-1])
    assert m, out
    return float(m.group(1)), float(m.group(2))


def test_ptz_serial_goto_and_position(capsys) -> None:
    with ViscaSerialTwin(time_scale=0.001) as twin:
        assert main(["ptz", "--port", twin.port, "--timeout", "0.1", "goto", "30", "-10"]) == 0
        assert _pos(capsys.readouterr().out) == (30.0, -10.0)
        assert twin.emulator.pose().pan_counts == -432  # +30 deg spec = 30 deg left = -432 counts
        assert main(["ptz", "--port", twin.port, "position"]) == 0
        assert _pos(capsys.readouterr().out) == (30.0, -10.0)
        # quantisation: 12.34 deg is not a whole count; the read-back is the nearest count
        assert main(["ptz", "--port", twin.port, "--mount", "ceiling", "goto", "12.34", "5"]) == 0
        pan, tilt = _pos(capsys.readouterr().out)
        assert abs(pan - 12.34) <= 0.5 / 14.4 and tilt == 5.0
        assert twin.emulator.pose().pan_counts == round(12.34 * 14.4)  # ceiling: no pan sign flip


def test_ptz_camera_model_option(capsys) -> None:
    with ViscaSerialTwin(model=EVI_D30) as twin:
        assert main(["ptz", "--port", twin.port, "--camera-model", "EVI-D30", "goto", "-50", "10"]) == 0
        assert _pos(capsys.readouterr().out) == (-50.0, 10.0)
        assert twin.emulator.pose().pan_counts == 440


def test_ptz_udp_and_http(capsys) -> None:
    with ViscaIpTwin() as twin:
        assert main(["ptz", "--port", twin.url, "goto", "-150", "45"]) == 0
        assert _pos(capsys.readouterr().out) == (-150.0, 45.0)
    with SonyCgiTwin() as twin:
        assert main(["ptz", "--port", twin.url, "goto", "100", "-80"]) == 0
        assert _pos(capsys.readouterr().out) == (100.0, -80.0)
        assert main(["ptz", "--port", twin.url, "zoom", "0.5"]) == 0
        assert capsys.readouterr().out.strip() == "zoom 0.5000"


def test_ptz_errors_are_one_line(capsys, tmp_path) -> None:
    assert main(["ptz", "--port", str(tmp_path / "ttyNONE"), "position"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fgloc: error: ") and "cannot open serial port" in err
    with ViscaSerialTwin() as twin:
        assert main(["ptz", "--port", twin.port, "goto", "120", "0"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "outside the EVI-D100 range" in err
        twin.faults.config.drop_rate = 1.0
        assert main(["ptz", "--port", twin.port, "--timeout", "0.05", "--retries", "1", "position"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "no reply" in err
    assert main(["ptz", "--port", "ftp://x", "position"]) == 2
    assert "unknown scheme" in capsys.readouterr().err
    assert main(["ptz", "--port", "/dev/null", "--camera-model", "EVI-X", "position"]) == 2
    assert "unknown model" in capsys.readouterr().err


def test_ptz_http_credentials_not_printed(capsys) -> None:
    with SonyCgiTwin(user="admin", password="pw-XYZ") as twin:
        url = f"http://admin:bad-XYZ@127.0.0.1:{twin.port}"
        assert main(["ptz", "--port", url, "position"]) == 2
        captured = capsys.readouterr()
        assert "authentication failed" in captured.err and "XYZ" not in captured.err + captured.out


def test_motes_led_serial_and_sf(capsys) -> None:
    field = MoteFieldEmulator(silent=[9])
    with BaseStationSerialTwin(field) as twin:
        assert main(["motes", "--port", twin.port, "led", "n005", "on"]) == 0
        assert capsys.readouterr().out.strip() == "node n005: LED on (confirmed by the node)"
        assert field.led_on == {5: True}
        assert main(["motes", "--port", twin.port, "--timeout", "0.05", "led", "n009", "on"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "no LED report" in err
    with SerialForwarderTwin(faults=FaultConfig(drop_rate=0.3, seed=4)) as twin:
        assert main(["motes", "--port", twin.url, "--timeout", "0.1", "--attempts", "8", "led", "7", "off"]) == 0
        assert twin.field.led_on == {7: False}


def test_motes_errors(capsys) -> None:
    assert main(["motes", "--port", "tcp://127.0.0.1:1", "led", "n1", "on"]) == 2
    assert "cannot connect" in capsys.readouterr().err
    assert main(["motes", "--port", "udp://x", "led", "n1", "on"]) == 2
    assert "serial device or tcp://" in capsys.readouterr().err
    with BaseStationSerialTwin() as twin:
        assert main(["motes", "--port", twin.port, "led", "kitchen", "on"]) == 2
        assert "no mote address" in capsys.readouterr().err


def test_ptz_subprocess_on_the_pty() -> None:
    """The installed entry point, as a person at the rig would run it, on the twin's pty path."""
    with ViscaSerialTwin() as twin:
        run = subprocess.run([sys.executable, "-c", "import sys; from fgloc.cli import main; sys.exit(main())", "ptz", "--port", twin.port, "goto", "-20", "5"],
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        assert _pos(run.stdout) == pytest.approx((-20.0, 5.0), abs=1e-3)
