"""camera.json: round trip, validation errors as one line naming file, field and value."""

import json

import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.files.camera_file import IntrinsicsFormatError, read_intrinsics, write_intrinsics

INTR = CameraIntrinsics(fx=540.5, fy=545.25, cx=322.0, cy=236.5, width=640, height=480,
                        k1=-0.22, k2=0.06, p1=0.001, p2=-0.0005, k3=0.0, zoom=0.0, rms_px=0.04,
                        images=("a.png", "b.png"))


def test_round_trip(tmp_path):
    path = tmp_path / "camera.json"
    write_intrinsics(INTR, path)
    back = read_intrinsics(path)
    assert back == INTR and back.images == INTR.images
    data = json.loads(path.read_text())
    assert data["format"] == "fgloc-camera" and data["image_size"] == [640, 480]


def _write(tmp_path, mutate):
    path = tmp_path / "camera.json"
    write_intrinsics(INTR, path)
    data = json.loads(path.read_text())
    mutate(data)
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "mutate,field",
    [
        (lambda d: d.pop("fx"), "fx"),
        (lambda d: d.update(fx=-3.0), "fx"),
        (lambda d: d.update(cy="a"), "cy"),
        (lambda d: d.update(cx=700.0), "cx"),
        (lambda d: d.update(zoom=1.5), "zoom"),
        (lambda d: d.update(image_size=[640]), "image_size"),
        (lambda d: d.update(format="fgloc-survey"), "format"),
        (lambda d: d.update(version=2), "version"),
        (lambda d: d["distortion"].update(k1=None), "distortion.k1"),
    ],
)
def test_bad_fields_name_file_and_field(tmp_path, mutate, field):
    path = _write(tmp_path, mutate)
    with pytest.raises(IntrinsicsFormatError) as err:
        read_intrinsics(path)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}: {field}:")


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(IntrinsicsFormatError, match="file not found"):
        read_intrinsics(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(IntrinsicsFormatError, match="not valid JSON"):
        read_intrinsics(bad)


def test_at_zoom_scales_focal_length_only():
    tele = INTR.at_zoom(1.0)
    assert tele.fx == pytest.approx(10 * INTR.fx) and tele.cx == INTR.cx and tele.zoom == 1.0
    assert tele.at_zoom(0.0).fx == pytest.approx(INTR.fx)
