"""Pixel <-> (pan, tilt): frame definitions, distortion model, exact composition with the head."""

import math

import cv2
import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import (
    OPTICAL_TO_HEAD,
    distort_normalized,
    optical_to_base,
    pan_tilt_to_pixel,
    pixel_to_pan_tilt,
    pixel_to_ray,
    ray_to_pixel,
    undistort_normalized,
)
from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing, wrap_angle

INTR = CameraIntrinsics(fx=540.0, fy=545.0, cx=322.0, cy=236.0, width=640, height=480,
                        k1=-0.22, k2=0.06, p1=0.001, p2=-0.0005, k3=0.01)


def test_optical_to_head_is_the_documented_rotation():
    """optical z -> base +x, optical x -> base -y, optical y -> base -z at pan = tilt = 0."""
    assert np.isclose(np.linalg.det(OPTICAL_TO_HEAD), 1.0)
    np.testing.assert_allclose(OPTICAL_TO_HEAD @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_allclose(OPTICAL_TO_HEAD @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_allclose(OPTICAL_TO_HEAD @ [0, 1, 0], [0, 0, -1])


@pytest.mark.parametrize("pan,tilt", [(0.0, 0.0), (0.7, 0.3), (-2.5, -0.4), (3.0, 1.2)])
def test_optical_axis_points_along_pan_tilt_bearing_and_image_up_is_tilt_up(pan, tilt):
    R = optical_to_base(pan, tilt)
    np.testing.assert_allclose(R @ [0, 0, 1], pan_tilt_bearing(pan, tilt), atol=1e-15)
    # Image "up" (-y optical) is the direction of increasing tilt, image "right" of decreasing pan.
    eps = 1e-6
    np.testing.assert_allclose(R @ [0, -1, 0], (pan_tilt_bearing(pan, tilt + eps) - pan_tilt_bearing(pan, tilt)) / eps,
                               atol=1e-5)
    right = (pan_tilt_bearing(pan - eps, tilt) - pan_tilt_bearing(pan, tilt)) / eps
    np.testing.assert_allclose(R @ [1, 0, 0], right / np.linalg.norm(right), atol=1e-5)


def test_principal_point_reads_the_head_angles():
    pan, tilt = pixel_to_pan_tilt(INTR, [INTR.cx, INTR.cy], 0.4, -0.2)
    assert pan == pytest.approx(0.4, abs=1e-12) and tilt == pytest.approx(-0.2, abs=1e-12)


def test_distortion_matches_opencv_project_points():
    """Independent check of the distortion formula against cv2.projectPoints."""
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, 200), rng.uniform(-0.45, 0.45, 200), np.ones(200)])
    uv_cv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), INTR.camera_matrix, INTR.dist_coeffs)
    uv, front = ray_to_pixel(INTR, pts)
    assert front.all()
    np.testing.assert_allclose(uv, uv_cv.reshape(-1, 2), atol=1e-9)


def test_undistortion_inverts_distortion_over_the_image():
    jj, ii = np.meshgrid(np.linspace(0, 639, 33), np.linspace(0, 479, 25))
    uv = np.stack([jj, ii], axis=-1)
    uv_back, _ = ray_to_pixel(INTR, pixel_to_ray(INTR, uv))
    np.testing.assert_allclose(uv_back, uv, atol=1e-9)
    xy = np.random.default_rng(1).uniform(-0.5, 0.5, (100, 2))
    np.testing.assert_allclose(undistort_normalized(INTR, distort_normalized(INTR, xy)), xy, atol=1e-12)


def test_pixel_pan_tilt_round_trip_at_many_head_poses():
    rng = np.random.default_rng(2)
    for _ in range(20):
        hp, ht = rng.uniform(-3.0, 3.0), rng.uniform(-1.0, 1.0)
        uv = np.column_stack([rng.uniform(0, 639, 50), rng.uniform(0, 479, 50)])
        pan, tilt = pixel_to_pan_tilt(INTR, uv, hp, ht)
        uv_back, front = pan_tilt_to_pixel(INTR, pan, tilt, hp, ht)
        assert front.all()
        np.testing.assert_allclose(uv_back, uv, atol=1e-8)


def test_behind_the_camera_is_not_projected():
    uv, front = pan_tilt_to_pixel(INTR, math.pi, 0.0, 0.0, 0.0)
    assert not front and np.isnan(uv).all()


def test_exact_composition_matches_the_reference_numbers_and_differs_from_adding_angles():
    """protocols.md 5.4: normalised x = 0.1 at tilt 25 deg gives azimuth 6.30 deg (to the right,
    so pan = -6.30 deg here, pan counter-clockwise) and elevation 24.87 deg; adding atan(0.1)
    to pan would be off by ~0.6 deg."""
    unit = CameraIntrinsics(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=2)
    pan, tilt = pixel_to_pan_tilt(unit, [0.1, 0.0], 0.0, math.radians(25.0))
    assert math.degrees(pan) == pytest.approx(-6.30, abs=0.005)
    assert math.degrees(tilt) == pytest.approx(24.87, abs=0.005)
    naive_pan = -math.atan(0.1)
    assert abs(math.degrees(pan - naive_pan)) > 0.55


def test_pixel_ray_is_the_direction_of_the_node_in_the_base_frame():
    """A world direction projected to a pixel and read back gives the same (pan, tilt), also
    wrapping through pan = pi."""
    hp, ht = math.pi - 0.05, 0.2
    target = (wrap_angle(math.pi + 0.1), 0.25)
    uv, front = pan_tilt_to_pixel(INTR, *target, hp, ht)
    assert front
    pan, tilt = pixel_to_pan_tilt(INTR, uv, hp, ht)
    ref = bearing_pan_tilt(pan_tilt_bearing(*target))
    assert float(wrap_angle(pan - ref[0])) == pytest.approx(0.0, abs=1e-12)
    assert tilt == pytest.approx(float(ref[1]), abs=1e-12)
