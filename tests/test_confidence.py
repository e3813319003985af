"""Confidence ellipses/ellipsoids drawn from marginal covariances (fgloc.core.confidence)."""

import numpy as np
import pytest
from scipy.stats import chi2

from fgloc.core.confidence import (
    FLAT_Z_FRACTION,
    confidence_ellipsoids,
    confidence_scale,
    rotation_to_quaternion_xyzw,
)


def random_spd(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    A = rng.normal(size=(n, d, d)) * rng.uniform(1e-4, 1e-2, size=(n, 1, 1))
    return A @ A.transpose(0, 2, 1) + 1e-10 * np.eye(d)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


@pytest.mark.parametrize("dof", [2, 3])
@pytest.mark.parametrize("p", [0.5, 0.95, 0.997])
def test_confidence_scale_is_the_chi_square_quantile(dof: int, p: float) -> None:
    """k^2 must be the chi-square(dof) quantile (truth: scipy's chi2.ppf)."""
    assert confidence_scale(dof, p) == pytest.approx(np.sqrt(chi2.ppf(p, dof)), rel=1e-9)


def test_95_percent_scales_match_the_documented_values() -> None:
    assert confidence_scale(2) == pytest.approx(2.4477, abs=1e-4)
    assert confidence_scale(3) == pytest.approx(2.7955, abs=1e-4)


@pytest.mark.parametrize("d", [2, 3])
def test_ellipsoid_reconstructs_the_covariance(d: int) -> None:
    """R diag((h/k)^2) R^T must give back C: the drawn axes are the covariance's."""
    rng = np.random.default_rng(1)
    C = random_spd(rng, 50, d)
    ell = confidence_ellipsoids(C)
    R = ell.rotations
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-12)
    lam = (ell.half_sizes[:, :d] / ell.scale) ** 2
    rebuilt = np.einsum("nij,nj,nkj->nik", R[:, :d, :d], lam, R[:, :d, :d])
    np.testing.assert_allclose(rebuilt, C, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(quaternion_to_matrix(ell.quaternions), R, atol=1e-12)
    if d == 2:
        assert np.allclose(R[:, 2], [0, 0, 1]) and np.allclose(R[:, :, 2], [0, 0, 1])
        np.testing.assert_allclose(ell.half_sizes[:, 2], FLAT_Z_FRACTION * ell.half_sizes[:, :2].max(axis=1))


@pytest.mark.parametrize("d", [2, 3])
def test_95_percent_of_samples_fall_inside(d: int) -> None:
    """Seeded Monte Carlo: 95% +- 0.6% (3.5 sigma of 40k Bernoulli draws) of Gaussian
    samples must fall inside the drawn region; the 1-D k = 1.96 would give 85% / 75%."""
    rng = np.random.default_rng(7)
    C = random_spd(rng, 1, d)
    ell = confidence_ellipsoids(C)
    x = rng.multivariate_normal(np.zeros(d), C[0], size=40_000)
    local = x @ ell.rotations[0, :d, :d]  # coordinates along the drawn axes
    inside = ((local / ell.half_sizes[0, :d]) ** 2).sum(axis=1) <= 1.0
    assert abs(inside.mean() - 0.95) < 0.006


def test_quaternion_of_awkward_rotations() -> None:
    """Shepperd pivots: 180-degree turns about each axis and random rotations."""
    rng = np.random.default_rng(3)
    Q, _ = np.linalg.qr(rng.normal(size=(200, 3, 3)))
    Q[np.linalg.det(Q) < 0, :, 0] *= -1
    R = np.concatenate([Q, np.array([np.diag([1, -1, -1]), np.diag([-1, 1, -1]), np.diag([-1, -1, 1]), np.eye(3)])])
    q = rotation_to_quaternion_xyzw(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)


def test_nan_covariance_gives_nan_axes_and_bad_shape_raises() -> None:
    C = np.stack([np.eye(2), np.full((2, 2), np.nan)])
    ell = confidence_ellipsoids(C)
    assert np.isfinite(ell.half_sizes[0]).all() and np.isnan(ell.half_sizes[1]).all()
    with pytest.raises(ValueError):
        confidence_ellipsoids(np.eye(3))
