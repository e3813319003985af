"""Analytic Jacobians of the pan-tilt factor against GTSAM's numerical differentiation.

Truth used: central differences in GTSAM's own tangent conventions
(``gtsam.utils.numerical_derivative``, Pose3 right perturbation, [omega, v]).
"""

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22

from fgloc.core.geometry import bearing_pan_tilt, wrap_angle
from fgloc.factors.pan_tilt_factor import pan_tilt_error, pan_tilt_factor, planar_pan_tilt_factor

C, L = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L


def random_pose(rng: np.random.Generator) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 2.0), rng.normal(size=3))


def factor_error(factor: gtsam.CustomFactor, values: gtsam.Values) -> np.ndarray:
    """Unwhitened error vector of a custom factor."""
    return factor.unwhitenedError(values)


def linearized_jacobians(factor, values, dims):
    """(A blocks) of the factor's linearization, unwhitened by sigma."""
    A, _ = factor.linearize(values).jacobian()
    sigma = factor.noiseModel().sigmas()[0]
    A = A * sigma
    return A[:, : dims[0]], A[:, dims[0] :]


@pytest.mark.parametrize("seed", range(40))
def test_point3_factor_jacobians_match_numerical(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = random_pose(rng)
    point = pose.transformFrom(rng.normal(size=3) * 3.0)
    # Measurement near the truth but across the pan wrap for some seeds.
    q = pose.transformTo(point)
    pan, tilt = bearing_pan_tilt(q)
    pan_meas = float(wrap_angle(pan + rng.normal() * 0.05))
    tilt_meas = float(tilt + rng.normal() * 0.05)
    factor = pan_tilt_factor(C(0), L(0), pan_meas, tilt_meas, 0.01)

    def f(p: gtsam.Pose3, x: np.ndarray) -> np.ndarray:
        v = gtsam.Values()
        v.insert(C(0), p)
        v.insert(L(0), x)
        return factor_error(factor, v)

    v = gtsam.Values()
    v.insert(C(0), pose)
    v.insert(L(0), point)
    h_pose, h_point = linearized_jacobians(factor, v, (6, 3))
    np.testing.assert_allclose(h_pose, numericalDerivative21(f, pose, point, 1e-6), atol=1e-6, rtol=1e-5)
    np.testing.assert_allclose(h_point, numericalDerivative22(f, pose, point, 1e-6), atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("seed", range(20))
def test_planar_factor_jacobians_match_numerical(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), np.array([*rng.normal(size=2), rng.uniform(0.05, 1)]))
    xy = rng.uniform(-2, 2, size=2)
    factor = planar_pan_tilt_factor(C(0), L(0), float(rng.uniform(-np.pi, np.pi)), float(rng.uniform(-1, 1)), 0.01)

    def f(p: gtsam.Pose3, x: np.ndarray) -> np.ndarray:
        v = gtsam.Values()
        v.insert(C(0), p)
        v.insert(L(0), x)
        return factor_error(factor, v)

    v = gtsam.Values()
    v.insert(C(0), pose)
    v.insert(L(0), xy)
    h_pose, h_point = linearized_jacobians(factor, v, (6, 2))
    np.testing.assert_allclose(h_pose, numericalDerivative21(f, pose, xy, 1e-6), atol=1e-6, rtol=1e-5)
    np.testing.assert_allclose(h_point, numericalDerivative22(f, pose, xy, 1e-6), atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("pan_true", [np.pi - 1e-4, -np.pi + 1e-4, np.pi, 3.0, -3.0])
def test_pan_error_wraps_across_pi(pan_true: float) -> None:
    """A reading just across +-pi from the prediction gives a small error, not ~2 pi."""
    point = np.array([np.cos(pan_true), np.sin(pan_true), 0.2])
    pan_meas = float(wrap_angle(pan_true + 2e-4))
    e, _, _ = pan_tilt_error(np.eye(3), np.zeros(3), point, pan_meas, float(np.arctan2(0.2, 1.0)))
    assert abs(e[0] - 2e-4) < 1e-9
    assert abs(e[1]) < 1e-12


def test_error_sign_is_measured_minus_predicted() -> None:
    e, _, _ = pan_tilt_error(np.eye(3), np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.1, -0.2)
    np.testing.assert_allclose(e, [0.1, -0.2], atol=1e-15)


@pytest.mark.parametrize("offset", [1e-3, 1e-8, 1e-14, 0.0])
def test_stays_finite_as_tilt_approaches_90_degrees(offset: float) -> None:
    """Straight above the head pan is undefined: error and Jacobians must stay finite."""
    rng = np.random.default_rng(3)
    R = gtsam.Rot3.Expmap(rng.normal(size=3)).matrix()
    c = rng.normal(size=3)
    point = c + R @ np.array([offset, 0.0, 1.0])
    e, h_pose, h_point = pan_tilt_error(R, c, point, 0.3, 1.5)
    for arr in (e, h_pose, h_point):
        assert np.all(np.isfinite(arr))
    assert abs(e[0]) <= np.pi and abs(e[1] - (1.5 - np.arctan2(1.0, offset))) < 1e-12


def test_agrees_with_gtsam_bearing_direction() -> None:
    """Cross-check the prediction with GTSAM's own Pose3.bearing (a Unit3 in the body frame)."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        pose = random_pose(rng)
        point = rng.normal(size=3) * 2
        b = pose.bearing(point).point3()
        pan, tilt = bearing_pan_tilt(b)
        e, _, _ = pan_tilt_error(pose.rotation().matrix(), pose.translation(), point, float(pan), float(tilt))
        np.testing.assert_allclose(e, 0.0, atol=1e-12)
