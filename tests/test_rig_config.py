"""rig.json: the example loads; every bad field fails with one line naming file, field, value."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from fgloc.cli import main
from fgloc.files.rig_config import RigConfigError, load_rig, parse_rig

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "rig-simulated.json"


def _example() -> dict:
    return json.loads(EXAMPLE.read_text())


def test_example_rig_loads():
    rig = load_rig(EXAMPLE)
    assert rig.camera_ids == ["cam0", "cam1"]
    assert rig.sigma == pytest.approx(math.radians(0.1))
    assert rig.search.tilt_min == pytest.approx(math.radians(-85))
    assert rig.cameras[0].intrinsics.fx == 440.0
    assert rig.simulation.dead_nodes == ("n007",)
    assert len(rig.hash) == 64


def test_rendered_example_rig_loads():
    """examples/rig-rendered.json: rendered frames need the on/off detector (docs/survey.md)."""
    rig = load_rig(EXAMPLE.parent / "rig-rendered.json")
    assert (rig.simulation.frames, rig.search.detection) == ("rendered", "on-off")
    assert load_rig(EXAMPLE).simulation.frames == "spot"  # the default


def test_hash_changes_with_content():
    a = parse_rig(_example())
    data = _example()
    data["sigma_deg"] = 0.2
    assert parse_rig(data).hash != a.hash
    assert parse_rig(_example()).hash == a.hash


def test_intrinsics_from_a_camera_json(tmp_path):
    """A calibrated camera.json (docs/camera-model.md) with distortion is read as is."""
    from fgloc.camera.intrinsics import CameraIntrinsics
    from fgloc.files.camera_file import write_intrinsics

    data = _example()
    write_intrinsics(CameraIntrinsics(450.0, 451.0, 160.5, 119.5, 320, 240, k1=-0.1), tmp_path / "cam0.json")
    data["cameras"][0]["intrinsics"] = "cam0.json"
    (tmp_path / "rig.json").write_text(json.dumps(data))
    k = load_rig(tmp_path / "rig.json").cameras[0].intrinsics
    assert (k.fx, k.fy, k.k1) == (450.0, 451.0, -0.1)
    (tmp_path / "cam0.json").write_text('{"format": "nope"}')
    with pytest.raises(RigConfigError, match=r"rig.json: cameras\[0\]\.intrinsics: .*cam0.json: format"):
        load_rig(tmp_path / "rig.json")


def _mutate(path: str, value):
    data = _example()
    target = data
    keys = path.split(".")
    for k in keys[:-1]:
        target = target[int(k)] if isinstance(target, list) else target[k]
    last = keys[-1]
    if value is KeyError:
        del target[last]
    elif isinstance(target, list):
        target[int(last)] = value
    else:
        target[last] = value
    return data


@pytest.mark.parametrize(
    "path, value, message",
    [
        ("cameras.0.driver", "pelco", "cameras[0].driver: expected one of"),
        ("cameras.1.id", "cam0", "cameras[1].id: duplicate camera id 'cam0'"),
        ("cameras.0.intrinsics", KeyError, "cameras[0].intrinsics: missing required field"),
        ("cameras.0.intrinsics.fx", -3, "cameras[0].intrinsics.fx: must lie in"),
        ("cameras.0.intrinsics", "missing.json", "cameras[0].intrinsics: intrinsics file not found"),
        ("cameras.0.zoom", 2, "cameras[0].zoom: must lie in [0, 1], got 2"),
        ("cameras.0.mounting", "sideways", "cameras[0].mounting: expected one of upright, ceiling"),
        ("gauge.origin", "camX", "gauge.origin: camera 'camX' is not in cameras"),
        ("gauge.baseline", "cam0", "gauge.baseline: must differ"),
        ("motes.driver", "zigbee", "motes.driver: expected one of"),
        ("node_ids", [], "node_ids: expected a non-empty list"),
        ("node_ids.1", "n000", "node_ids[1]: duplicate node id 'n000'"),
        ("sigma_deg", "0.1", "sigma_deg: expected a finite number, got \"0.1\""),
        ("search.method", "guess", "search.method: expected one of centre, pixel-offset"),
        ("search.tilt_max_deg", -90, "search.tilt_max_deg: must exceed tilt_min_deg"),
        ("simulation.dead_nodes", ["nope"], "simulation.dead_nodes: expected a list of node ids"),
        ("simulation.frames", "textured", "simulation.frames: expected one of spot, rendered, got 'textured'"),
        ("simulation.twin", "udp", "simulation.twin: expected one of inprocess, visca, got 'udp'"),
        ("nodes", "2d", "nodes: expected \"planar\" or \"3d\", got '2d'"),
    ],
)
def test_bad_rig_fields(tmp_path, path, value, message):
    data = _mutate(path, value)
    rig_path = tmp_path / "rig.json"
    rig_path.write_text(json.dumps(data))
    with pytest.raises(RigConfigError) as err:
        load_rig(rig_path)
    text = str(err.value)
    assert text.startswith(str(rig_path) + ": ") and message in text and "\n" not in text


def test_hardware_camera_needs_a_port(tmp_path):
    data = _example()
    data["cameras"][0]["driver"] = "visca-serial"
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.raises(RigConfigError, match=r"cameras\[0\]\.port: missing required field"):
        load_rig(tmp_path / "rig.json")


def test_cli_reports_bad_rig_in_one_line(tmp_path, capsys):
    (tmp_path / "rig.json").write_text("{not json")
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "out"), "--simulate"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fgloc: error: ") and "not valid JSON" in err and err.count("\n") == 1


def test_driver_and_port_must_agree(tmp_path):
    data = _example()
    data["cameras"][0] |= {"driver": "visca-ip", "port": "/dev/ttyUSB0"}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.raises(RigConfigError, match=r"cameras\[0\]\.port: driver visca-ip needs udp://HOST\[:PORT\], got '/dev/ttyUSB0'"):
        load_rig(tmp_path / "rig.json")


def test_mote_driver_and_port_must_agree(tmp_path):
    data = _example()
    data["motes"] = {"driver": "serial-forwarder", "port": "/dev/ttyUSB1"}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.raises(RigConfigError, match=r"motes\.port: driver serial-forwarder needs tcp://"):
        load_rig(tmp_path / "rig.json")


SECRET = "Hunter2-zq"


@pytest.mark.parametrize(("where", "value", "shown"), [
    (("cameras", 0, "driver", "visca-ip"), f"http://admin:{SECRET}@10.0.0.5", "got 'http://***@10.0.0.5'"),
    (("cameras", 0, "driver", "sony-cgi"), f"htp://admin:{SECRET}@10.0.0.5", "got 'htp://***@10.0.0.5'"),
    (("cameras", 0, "driver", "visca-serial"), f"http://admin:{SECRET}@10.0.0.5/", "got 'http://***@10.0.0.5/'"),
    (("motes", None, "driver", "serial-forwarder"), f"http://u:{SECRET}@h:9002", "got 'http://***@h:9002'"),
    (("motes", None, "driver", "tinyos-serial"), f"tcp://u:{SECRET}@h:9002", "got 'tcp://***@h:9002'"),
])
def test_a_password_in_a_port_is_never_echoed(tmp_path, capsys, where, value, shown):
    """The issue's case: a port with user info given to the wrong driver or with a scheme typo.
    The one-line error names the field and shows the URL with its user info as ***."""
    data = _example()
    section, index, key, driver = where
    target = data[section][index] if index is not None else data[section]
    target |= {key: driver, "port": value}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    with pytest.raises(RigConfigError) as err:
        load_rig(tmp_path / "rig.json")
    assert SECRET not in str(err.value) and shown in str(err.value)
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "out"), "--simulate"]) == 2
    out = capsys.readouterr()
    assert out.err.count("\n") == 1 and shown in out.err and SECRET not in out.err + out.out


def test_any_rig_error_hides_user_info_even_from_the_schema_check(tmp_path):
    data = _example()
    data["cameras"][0]["video"] = ""  # the schema's own message would show the value
    data["cameras"][0]["mounting"] = f"rtsp://me:{SECRET}@cam"
    with pytest.raises(RigConfigError) as err:
        parse_rig(data)
    assert "mounting" in str(err.value) and SECRET not in str(err.value) and "rtsp://***@cam" in str(err.value)


def test_meaning_and_operational_fields_split_the_rig():
    from fgloc.files.rig_config import rig_meaning, rig_operational

    data = _example()
    data["cameras"][1] |= {"driver": "sony-cgi", "port": f"http://admin:{SECRET}@10.0.0.5", "video": "0"}
    data["retry"] = {"backoff_s": 0.1}
    rig = parse_rig(data)
    meaning, operational = rig_meaning(rig, simulated=True), rig_operational(rig)
    assert meaning["cameras[cam1].intrinsics.fx"] == 440.0 and meaning["cameras[cam0].mounting"] == "upright"
    assert meaning["sigma_deg"] == pytest.approx(0.1) and meaning["simulation.seed"] == 1
    assert "simulation.seed" not in rig_meaning(rig, simulated=False)
    assert operational["cameras[cam1].port"] == "http://***@10.0.0.5"
    assert operational["cameras[cam1].video"] == "0" and operational["retry.backoff_s"] == 0.1
    assert not set(meaning) & set(operational)
    assert SECRET not in json.dumps([meaning, operational])
    # an intrinsics file and the same values inline mean the same
    assert all(not k.startswith("cameras[cam0].intrinsics") for k in operational)
