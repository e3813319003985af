"""Preflight (issue 15, item 7): a survey that cannot work is refused before anything moves.

The rigs point at the protocol twins (drivers/twins: VISCA serial on a pty, Sony CGI over
HTTP, a TinyOS base station) through rig.json port strings, as real hardware would be;
frames of the VISCA cameras come from a small video file (``video``), those of the Sony
camera from its JPEG snapshot. One refusal per camera problem, each one line naming the
camera and the field, exit status 2, no journal written, every head where it was.
"""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.drivers.twins.rig import TwinCamera, TwinRig
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.files.rig_config import parse_rig
from fgloc.survey.preflight import PreflightError, check_devices, check_rig, intrinsics_problem
from fgloc.survey.session import open_hardware
from tests.test_rig_config import EXAMPLE

W, H = 320, 240
INTRINSICS = {"fx": 440.0, "fy": 440.0, "cx": 160.0, "cy": 120.0, "width": W, "height": H}


def _video(path: Path, width: int = W, height: int = H) -> Path:
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (width, height))
    assert writer.isOpened()
    for k in range(8):
        writer.write(np.full((height, width, 3), 10 * k, np.uint8))
    writer.release()
    return path


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def twins(tmp_path):
    """A VISCA serial twin (EVI-D100), a Sony CGI twin that wants admin:Pw-right-8x, a base station."""
    render = lambda cid, pan, tilt, zoom: np.zeros((H, W), np.uint8)  # noqa: E731
    with TwinRig([TwinCamera("cam0", "serial")], render=render) as rig:
        sony = SonyCgiTwin(renderer=lambda pose: np.zeros((H, W), np.uint8), user="admin", password="Pw-right-8x")
        try:
            yield rig, sony, _video(tmp_path / "cam0.avi")
        finally:
            sony._stopped = True
            sony.disconnect()


def _rig(tmp_path: Path, twins, edit=None) -> Path:
    rig, sony, video = twins
    data = json.loads(EXAMPLE.read_text())
    data["cameras"] = [
        {"id": "cam0", "driver": "visca-serial", "port": rig.ports["cam0"], "model": "EVI-D100",
         "video": str(video), "intrinsics": dict(INTRINSICS)},
        {"id": "cam1", "driver": "sony-cgi", "port": f"http://admin:Pw-right-8x@127.0.0.1:{sony.port}",
         "model": "SNC-RZ25N", "intrinsics": dict(INTRINSICS)},
    ]
    data["motes"] = {"driver": "tinyos-serial", "port": rig.mote_port}
    data["node_ids"] = ["1", "2", "3"]
    data["search"] = {"pan_min_deg": -90, "pan_max_deg": 90, "tilt_min_deg": -20, "tilt_max_deg": 20}
    data["retry"] = {"backoff_s": 0.0, "head_attempts": 2}
    del data["simulation"]
    if edit is not None:
        edit(data)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(data))
    return path


def _poses(twins) -> list[tuple[int, int, int]]:
    rig, sony, _ = twins
    return [(p.pan_counts, p.tilt_counts, p.zoom_counts)
            for p in (rig.twins["cam0"].emulator.pose(), sony.emulator.pose())]


def test_a_healthy_twin_rig_passes_preflight_and_nothing_moves(tmp_path, twins):
    rig_path = _rig(tmp_path, twins)
    from fgloc.files.rig_config import load_rig

    rig = load_rig(rig_path)
    check_rig(rig)
    opened = open_hardware(rig)
    try:
        check_devices(rig, opened.open_head)
    finally:
        opened.close()
    assert _poses(twins) == [(0, 0, 0), (0, 0, 0)]


CASES = {
    "wrong password": (lambda d: d["cameras"][1].update(port=d["cameras"][1]["port"].replace("Pw-right-8x", "Pw-wrong-8x")),
                       "cameras[1].port: camera cam1: cannot be opened: SonyCgiError: ",
                       "HTTP 401: authentication failed"),
    "unknown model": (lambda d: d["cameras"][0].update(model="EVI-D999"),
                      "cameras[0].model: camera cam0: unknown model 'EVI-D999' (known: ", ""),
    "unreachable port": (lambda d: d["cameras"][1].update(port=f"http://admin:Pw-right-8x@127.0.0.1:{_closed_port()}"),
                         "cameras[1].port: camera cam1: cannot be opened: ViscaDisconnected: ",
                         "connection refused"),
    "missing serial device": (lambda d: d["cameras"][0].update(port="/dev/fgloc-no-such-tty"),
                              "cameras[0].port: camera cam0: cannot be opened: ", "fgloc-no-such-tty"),
    "search range outside the head's": (
        lambda d: d["search"].update(pan_min_deg=-180, pan_max_deg=180),
        "search.pan_min_deg: camera cam0 (EVI-D100, upright) can pan only -100.0..100.0 deg, "
        "the search goes to -180 deg", ""),
    "a camera's own box outside its head's range": (
        lambda d: d["cameras"][0].update(search={"pan_min_deg": -20, "pan_max_deg": 120}),
        "cameras[0].search.pan_max_deg: camera cam0 (EVI-D100, upright) can pan only -100.0..100.0 deg, "
        "the search goes to 120 deg", ""),
    "tilt range outside the head's": (
        lambda d: d["search"].update(tilt_min_deg=-30),
        "search.tilt_min_deg: camera cam0 (EVI-D100, upright) can tilt only -25.0..25.0 deg, "
        "the search goes to -30 deg", ""),
    "absurd intrinsics": (lambda d: d["cameras"][0]["intrinsics"].update(width=100000, height=100000),
                          "cameras[0].intrinsics: camera cam0: a 100000x100000 px frame is not plausible", ""),
    "intrinsics for another frame size": (
        lambda d: d["cameras"][0].update(intrinsics={**INTRINSICS, "width": 640, "height": 480, "cx": 320,
                                                     "cy": 240}),
        "cameras[0].intrinsics: camera cam0: frames are 320x240 px (width x height), the intrinsics are for "
        "640x480 px", ""),
    "unopenable video source": (lambda d: d["cameras"][0].update(video="/nonexistent/cam0.avi"),
                                "cameras[0].video: camera cam0: video source does not open: FrameError: "
                                "video /nonexistent/cam0.avi: cannot open", ""),
    "no video source for a VISCA head": (lambda d: d["cameras"][0].pop("video"),
                                         "cameras[0].video: camera cam0: no frame from the camera: ",
                                         "no frame source"),
    "unreachable base station": (lambda d: d["motes"].update(port="/dev/fgloc-no-such-base-station"),
                                 "motes.port: base station (tinyos-serial) cannot be opened: ", ""),
}


@pytest.mark.parametrize("case", list(CASES))
def test_preflight_refuses_in_one_line_naming_camera_and_field_before_anything_moves(tmp_path, twins, capsys,
                                                                                      case):
    edit, expected, also = CASES[case]
    rig_path = _rig(tmp_path, twins, edit)
    out = tmp_path / "out"
    assert main(["survey", "--rig", str(rig_path), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"fgloc: error: {rig_path}: "), err
    assert expected in err and also in err, err
    assert "Pw-right-8x" not in err and "Pw-wrong-8x" not in err  # the password is never shown
    assert not (out / "journal.jsonl").exists()
    assert _poses(twins) == [(0, 0, 0), (0, 0, 0)]


def test_absurd_intrinsics_are_refused_before_a_simulated_frame_is_allocated(tmp_path, capsys):
    data = json.loads(EXAMPLE.read_text())
    data["cameras"][1]["intrinsics"] = {"fx": 1e5, "fy": 1e5, "cx": 5e4, "cy": 5e4, "width": 100000,
                                        "height": 100000}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o"), "--simulate"]) == 2
    err = capsys.readouterr().err
    assert "cameras[1].intrinsics: camera cam1: a 100000x100000 px frame is not plausible" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("change", "problem"), [
    ({"cx": -5.0}, "principal point (-5, 120) px lies outside the 320x240 px frame"),
    ({"fx": 0.01}, "focal length 0.01 px gives a horizontal field of view of 180 deg"),
    ({"fy": 1e9}, "focal length 1e+09 px gives a vertical field of view of 1.38e-05 deg"),
    ({"fx": 440.0, "fy": 44.0}, "fx / fy = 10 is not a plausible pixel aspect"),
    ({"width": 20000}, "a 20000x240 px frame is not plausible"),
    ({"width": 9000, "height": 9000, "cx": 4500, "cy": 4500}, "a 9000x9000 px frame is not plausible"),
])
def test_implausible_intrinsics(change, problem):
    from fgloc.camera.intrinsics import CameraIntrinsics

    assert intrinsics_problem(CameraIntrinsics(**{**INTRINSICS, **change})).startswith(problem)
    assert intrinsics_problem(CameraIntrinsics(**INTRINSICS)) is None
    assert intrinsics_problem(CameraIntrinsics(1450.0, 1450.0, 960.0, 540.0, 1920, 1080)) is None  # 1080p, 67 deg


def test_in_process_twin_has_no_head_limits_but_the_visca_twin_does():
    data = json.loads(EXAMPLE.read_text())  # EVI-D100s searching pan +-180 deg
    rig = parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    check_rig(rig, simulate=True)  # in-process twin: an idealized head without limits
    data["simulation"]["twin"] = "visca"
    with pytest.raises(PreflightError, match=r"search\.pan_min_deg: camera cam0 \(EVI-D100, upright\)"):
        check_rig(parse_rig(data, str(EXAMPLE), EXAMPLE.parent), simulate=True)
    check_rig(parse_rig(json.loads((EXAMPLE.parent / "rig-visca-twins.json").read_text()), str(EXAMPLE)),
              simulate=True)
