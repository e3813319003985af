"""Intrinsic calibration on rendered checkerboards with a known camera, and the CLI."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from fgloc.camera.calibration import BoardSpec, CalibrationError, calibrate, find_corners
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.cli import main
from fgloc.drivers.checkerboard_renderer import board_poses, project_corners, render_checkerboard
from fgloc.files.camera_file import read_intrinsics

TRUE = CameraIntrinsics(fx=540.0, fy=545.0, cx=322.0, cy=236.0, width=640, height=480,
                        k1=-0.22, k2=0.06, p1=0.001, p2=-0.0005)
BOARD = BoardSpec(9, 6, 0.025)


@pytest.fixture(scope="module")
def rendered():
    """15 board images through TRUE (seeded), with their poses."""
    rng = np.random.default_rng(0)
    poses = board_poses(BOARD, 15, rng, distance=0.3, intrinsics=TRUE)
    return [(f"img{i:02d}.png", render_checkerboard(TRUE, BOARD, r, t, rng), (r, t)) for i, (r, t) in enumerate(poses)]


def test_rendered_corners_are_where_the_camera_model_puts_them(rendered):
    """The renderer is a valid truth source: OpenCV's sub-pixel corners agree with
    cv2.projectPoints through the true model to < 0.1 px RMS."""
    for _, image, (r, t) in rendered[:5]:
        corners = find_corners(image, BOARD)
        truth = project_corners(TRUE, BOARD, r, t)
        err = np.linalg.norm(corners - truth, axis=1)
        err_rev = np.linalg.norm(corners[::-1] - truth, axis=1)  # OpenCV may list them reversed
        assert min(np.sqrt(np.mean(err**2)), np.sqrt(np.mean(err_rev**2))) < 0.1


def test_acceptance_calibration_recovers_the_camera(rendered):
    """Acceptance (issue 6): from 15 rendered board images the focal lengths are within 0.5 %
    and the principal point within 2 px of the camera the images were rendered with."""
    result = calibrate([(n, img) for n, img, _ in rendered], BOARD, zoom=0.0)
    est = result.intrinsics
    assert sum(r.used for r in result.reports) == 15
    assert abs(est.fx / TRUE.fx - 1) < 0.005 and abs(est.fy / TRUE.fy - 1) < 0.005
    assert abs(est.cx - TRUE.cx) < 2.0 and abs(est.cy - TRUE.cy) < 2.0
    assert abs(est.k1 - TRUE.k1) < 0.02
    assert result.rms_px < 0.15 and all(r.rms_px < 0.15 for r in result.reports)
    assert (est.width, est.height, est.zoom) == (640, 480, 0.0)


def test_inconsistent_image_is_rejected_and_calibration_redone(rendered):
    """An image taken through a different lens (strong pincushion instead of barrel) fits
    badly, is rejected with its RMS, and the re-calibration still meets the acceptance."""
    rng = np.random.default_rng(1)
    other = replace(TRUE, k1=0.35, k2=0.0)
    bad = render_checkerboard(other, BOARD, *rendered[3][2], rng)
    images = [(n, img) for n, img, _ in rendered] + [("other_lens.png", bad)]
    blank = np.full((480, 640), 128, np.uint8)
    images.append(("blank.png", blank))
    result = calibrate(images, BOARD)
    by_name = {r.name: r for r in result.reports}
    assert not by_name["other_lens.png"].used and by_name["other_lens.png"].rms_px > 1.0
    assert not by_name["blank.png"].found and by_name["blank.png"].reason == "board not found"
    assert abs(result.intrinsics.fx / TRUE.fx - 1) < 0.005
    assert "other_lens.png" not in result.intrinsics.images


def test_too_few_boards_and_mixed_sizes_are_errors(rendered):
    with pytest.raises(CalibrationError, match="found in 2 distinct views of 2 images"):
        calibrate([(n, img) for n, img, _ in rendered[:2]], BOARD)
    with pytest.raises(CalibrationError, match="small.png: image size"):
        calibrate([(rendered[0][0], rendered[0][1]), ("small.png", np.zeros((100, 100), np.uint8))], BOARD)


def test_cli_writes_camera_json_and_warns_at_zoom(rendered, tmp_path, capsys):
    names = []
    for n, img, _ in rendered:
        cv2.imwrite(str(tmp_path / n), img)
        names.append(str(tmp_path / n))
    out = tmp_path / "camera.json"
    code = main(["calibrate", *names, "-o", str(out), "--board", "9x6", "--square", "0.025", "--zoom", "0.3"])
    captured = capsys.readouterr()
    assert code == 0
    assert "widest zoom" in captured.err
    assert "used 15 of 15 images" in captured.out
    model = read_intrinsics(out)
    assert model.zoom == 0.3 and abs(model.fx / TRUE.fx - 1) < 0.005 and len(model.images) == 15


@pytest.mark.parametrize(
    "args,message",
    [
        (["--board", "9by6", "--square", "0.025"], "--board: expected COLSxROWS"),
        (["--board", "9x6", "--square", "-1"], "--square: must be > 0"),
        (["--board", "9x6", "--square", "0.025", "--zoom", "2"], "--zoom: must lie in [0, 1]"),
    ],
)
def test_cli_bad_arguments_are_one_line_errors(rendered, tmp_path, capsys, args, message):
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), rendered[0][1])
    code = main(["calibrate", str(img), "-o", str(tmp_path / "c.json"), *args])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1


def test_cli_unreadable_image(tmp_path, capsys):
    bad = tmp_path / "not_an_image.png"
    bad.write_text("hello")
    code = main(["calibrate", str(bad), "-o", str(tmp_path / "c.json"), "--board", "9x6", "--square", "1"])
    err = capsys.readouterr().err
    assert code == 2 and f"{bad}: not an image OpenCV can decode" in err and err.count("\n") == 1


# ---- calibration sanity (issue 15) -------------------------------------------------------


def test_same_image_eight_times_is_refused(rendered):
    """Eight copies of one view are one board pose: named as duplicates, and refused."""
    name, img, _ = rendered[0]
    images = [(f"copy{i}.png", img) for i in range(8)]
    with pytest.raises(CalibrationError, match=r"found in 1 distinct views.*near-duplicates not counted: copy1.png"):
        calibrate(images, BOARD)


def test_near_duplicates_are_named_and_not_used(rendered):
    """A view re-rendered from the same pose (different sensor noise) and an exact copy are
    named as the same pose as the original; the calibration from the rest meets the acceptance."""
    rng = np.random.default_rng(7)
    again = render_checkerboard(TRUE, BOARD, *rendered[2][2], rng)
    images = [(n, img) for n, img, _ in rendered] + [("again.png", again), ("copy.png", rendered[5][1])]
    result = calibrate(images, BOARD)
    by_name = {r.name: r for r in result.reports}
    assert by_name["again.png"].reason == f"same board pose as {rendered[2][0]} (not used)"
    assert by_name["copy.png"].reason == f"same board pose as {rendered[5][0]} (not used)"
    assert sum(r.used for r in result.reports) == 15
    assert abs(result.intrinsics.fx / TRUE.fx - 1) < 0.005


def test_views_that_do_not_determine_the_intrinsics_are_refused():
    """Five boards all facing the camera squarely, merely shifted: the focal length trades
    against the distance, so the fit is refused rather than written."""
    rng = np.random.default_rng(3)
    images = []
    for i, (dx, dy) in enumerate([(-0.04, -0.03), (0.04, -0.03), (0.0, 0.0), (-0.04, 0.03), (0.04, 0.03)]):
        rvec = np.zeros(3)
        tvec = np.array([dx - 0.1, dy - 0.06, 0.3])
        images.append((f"flat{i}.png", render_checkerboard(TRUE, BOARD, rvec, tvec, rng)))
    with pytest.raises(CalibrationError, match="do not determine the intrinsics|distinct views"):
        calibrate(images, BOARD, min_images=5)


def test_cli_names_corrupt_and_duplicate_images(rendered, tmp_path, capsys):
    names = []
    for n, img, _ in rendered[:8]:
        cv2.imwrite(str(tmp_path / n), img)
        names.append(str(tmp_path / n))
    ok, jpg = cv2.imencode(".jpg", rendered[9][1])
    (tmp_path / "cut.jpg").write_bytes(jpg.tobytes()[: len(jpg) // 2])  # truncated JPEG
    png = (tmp_path / rendered[10][0]).with_name("cut.png")
    ok, data = cv2.imencode(".png", rendered[10][1])
    png.write_bytes(data.tobytes()[:-30])
    cv2.imwrite(str(tmp_path / "dup.png"), rendered[0][1])
    out = tmp_path / "camera.json"
    code = main(["calibrate", *names, str(tmp_path / "cut.jpg"), str(png), str(tmp_path / "dup.png"),
                 "-o", str(out), "--board", "9x6", "--square", "0.025"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "corrupt JPEG" in captured.out and "corrupt PNG" in captured.out
    assert f"same board pose as {names[0]}" in captured.out
    assert "used 8 of 11 images" in captured.out
    assert len(read_intrinsics(out).images) == 8


@pytest.mark.parametrize("board", ["2x2", "2x6", "9x1"])
def test_cli_board_below_3x3_is_a_usage_error(rendered, tmp_path, capsys, board):
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), rendered[0][1])
    code = main(["calibrate", str(img), "-o", str(tmp_path / "c.json"), "--board", board, "--square", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "--board: need at least 3x3" in err and err.count("\n") == 1


def test_cli_image_over_the_pixel_limit_is_named(tmp_path, capsys, monkeypatch):
    """OpenCV refuses images above CV_IO_MAX_IMAGE_PIXELS with its own exception: named, one line."""
    from fgloc.camera import image_files

    big = tmp_path / "big.png"
    cv2.imwrite(str(big), np.zeros((64, 64), np.uint8))

    def refuse(*_a, **_k):
        raise cv2.error("OpenCV(4.x) grfmt_base.cpp:1:validateInputImageSize error: (-215:Assertion failed) "
                        "pixels <= CV_IO_MAX_IMAGE_PIXELS in function 'validateInputImageSize'")

    monkeypatch.setattr(image_files.cv2, "imdecode", refuse)
    code = main(["calibrate", str(big), "-o", str(tmp_path / "c.json"), "--board", "9x6", "--square", "1"])
    err = capsys.readouterr().err
    assert code == 2 and f"{big}: OpenCV cannot decode it" in err and "CV_IO_MAX_IMAGE_PIXELS" in err
    assert err.count("\n") == 1
