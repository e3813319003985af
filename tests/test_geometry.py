"""Pan-tilt geometry against the spec's definitions (docs/file-format.md)."""

import numpy as np
import pytest

from fgloc.core.geometry import (
    base_rotation,
    bearing_pan_tilt,
    is_rotation,
    nearest_rotation,
    pan_tilt_bearing,
    pan_tilt_jacobian,
    project_pan_tilt,
    wrap_angle,
)


def test_wrap_angle_range_and_identity() -> None:
    a = np.linspace(-20, 20, 10001)
    w = wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    assert wrap_angle(-np.pi) == np.pi and wrap_angle(np.pi) == np.pi


def test_spec_bearing_formula() -> None:
    """b = (cos t cos p, cos t sin p, sin t): pan CCW from base x, tilt up."""
    np.testing.assert_allclose(pan_tilt_bearing(0.0, 0.0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(pan_tilt_bearing(np.pi / 2, 0.0), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(pan_tilt_bearing(0.3, np.pi / 2), [0, 0, 1], atol=1e-15)


def test_bearing_round_trip_vectorized() -> None:
    rng = np.random.default_rng(0)
    pan = rng.uniform(-np.pi, np.pi, size=(50, 4))
    tilt = rng.uniform(-1.5, 1.5, size=(50, 4))
    b = pan_tilt_bearing(pan, tilt)
    assert b.shape == (50, 4, 3)
    np.testing.assert_allclose(np.linalg.norm(b, axis=-1), 1.0, atol=1e-14)
    p2, t2 = bearing_pan_tilt(b * 3.7)  # scale does not matter
    np.testing.assert_allclose(wrap_angle(p2 - pan), 0.0, atol=1e-12)
    np.testing.assert_allclose(t2, tilt, atol=1e-12)


def test_projection_matches_spec_definition() -> None:
    """R^T (x - c) / |x - c| = b for the projected (pan, tilt)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = base_rotation(*rng.uniform(-np.pi, np.pi, 3))
        c = rng.normal(size=3)
        x = rng.normal(size=(7, 3)) * 3
        pan, tilt = project_pan_tilt(R, c, x)
        expected = (x - c) @ R / np.linalg.norm(x - c, axis=1, keepdims=True)
        np.testing.assert_allclose(pan_tilt_bearing(pan, tilt), expected, atol=1e-12)


def test_pan_tilt_jacobian_numerical() -> None:
    rng = np.random.default_rng(2)
    q = rng.normal(size=(30, 3))
    jac = pan_tilt_jacobian(q)
    h = 1e-7
    for k in range(3):
        dq = np.zeros(3)
        dq[k] = h
        p1, t1 = bearing_pan_tilt(q + dq)
        p0, t0 = bearing_pan_tilt(q - dq)
        np.testing.assert_allclose(jac[:, 0, k], wrap_angle(p1 - p0) / (2 * h), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(jac[:, 1, k], (t1 - t0) / (2 * h), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("q", [[0, 0, 1.0], [0, 0, -2.0], [1e-200, 0, 1.0], [0, 0, 0]])
def test_pan_tilt_jacobian_finite_at_pole(q: list[float]) -> None:
    assert np.all(np.isfinite(pan_tilt_jacobian(np.array(q))))


def test_rotation_helpers() -> None:
    rng = np.random.default_rng(3)
    R = base_rotation(1.0, 0.2, -0.1)
    assert is_rotation(R)
    noisy = R + rng.normal(size=(3, 3)) * 1e-3
    assert not is_rotation(noisy)
    fixed = nearest_rotation(noisy)
    assert is_rotation(fixed) and np.linalg.norm(fixed - R) < 3e-3
    assert not is_rotation(-R)  # det = -1
