"""The head model and its factor: exact ideal limit, sight-line geometry, analytic Jacobians
against numerical differentiation (numpy and GTSAM tangent conventions)."""

import gtsam
import numpy as np
import pytest

from fgloc.core.geometry import bearing_pan_tilt, rot_x, rot_y, rot_z
from fgloc.core.head_model import DATASHEET_TOLERANCES, DEFAULT_PRIOR_SIGMAS, HEAD_DIM, head_pan_tilt
from fgloc.factors.pan_tilt_head_factor import HeadFactorSet
from fgloc.sim.head_errors import TYPICAL_MAGNITUDES, sample_head_errors
from fgloc.testing import assert_head_factor_jacobians

C, L, H = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L, gtsam.symbol_shorthand.H


def random_params(rng: np.random.Generator) -> np.ndarray:
    return rng.normal(size=HEAD_DIM) * np.array([0.01, 0.01, 0.01, 0.01, 0.01, 0.02, 0.02])


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 3))
    q[:, 2] *= 0.6  # keep away from the pole
    return q


def test_zero_parameters_are_the_ideal_head() -> None:
    q = random_points(np.random.default_rng(0), 50)
    pan, tilt, _, _ = head_pan_tilt(q, np.zeros(HEAD_DIM))
    ideal_pan, ideal_tilt = bearing_pan_tilt(q)
    np.testing.assert_allclose(pan, ideal_pan, atol=1e-14)
    np.testing.assert_allclose(tilt, ideal_tilt, atol=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_reading_points_the_sight_line_at_the_point(seed: int) -> None:
    """Undo the encoders, rebuild the head frame: the sight line from the optical centre hits q."""
    rng = np.random.default_rng(seed)
    p = random_params(rng)
    for q in random_points(rng, 10):
        pan, tilt, _, _ = head_pan_tilt(q, p, jacobians=False)
        phi, theta = pan / (1 + p[3]), (tilt - p[0]) / (1 + p[4])
        head = rot_z(float(phi)) @ rot_x(p[2]) @ rot_y(-float(theta))
        centre = head @ np.array([0.0, p[5], p[6]])
        sight = head @ rot_z(p[1]) @ np.array([1.0, 0.0, 0.0])
        v = q - centre
        assert np.linalg.norm(np.cross(v, sight)) < 1e-12 * np.linalg.norm(v)
        assert v @ sight > 0


def test_first_order_effects_have_the_classic_signs() -> None:
    """Index adds to tilt; collimation moves pan by -c/cos t; trunnion by +tau tan t."""
    tilt0 = np.deg2rad(30.0)
    q = np.array([np.cos(tilt0), 0.0, np.sin(tilt0)])
    eps = 1e-6
    for i, expected in ((1, -1 / np.cos(tilt0)), (2, np.tan(tilt0))):
        p = np.zeros(HEAD_DIM)
        p[i] = eps
        pan, _, _, _ = head_pan_tilt(q, p)
        assert pan / eps == pytest.approx(expected, rel=1e-4)
    p = np.zeros(HEAD_DIM)
    p[0] = eps
    assert head_pan_tilt(q, p)[1] - tilt0 == pytest.approx(eps, rel=1e-9)


@pytest.mark.parametrize("seed", range(10))
def test_jacobians_match_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    p = random_params(rng) * (seed % 2)  # even seeds: at the ideal head
    q = random_points(rng, 20)

    def f(q: np.ndarray, p: np.ndarray) -> np.ndarray:
        pan, tilt, _, _ = head_pan_tilt(q, p, jacobians=False)
        return np.stack([pan, tilt], axis=-1)

    _, _, d_q, d_p = head_pan_tilt(q, p)
    h = 1e-7
    num_q = np.stack([(f(q + h * e, p) - f(q - h * e, p)) / (2 * h) for e in np.eye(3)], axis=-1)
    num_p = np.stack([(f(q, p + h * e) - f(q, p - h * e)) / (2 * h) for e in np.eye(HEAD_DIM)], axis=-1)
    np.testing.assert_allclose(d_q, num_q, atol=1e-7)
    np.testing.assert_allclose(d_p, num_p, atol=1e-7)


@pytest.mark.parametrize("planar", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_factor_jacobians_match_gtsam_numerical(planar: bool, seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3), np.array([0.0, 0.0, 0.4]))
    point = np.array([rng.uniform(0.3, 1.0), rng.uniform(-0.5, 0.5), 0.0 if planar else rng.uniform(0, 0.3)])
    node = point[:2].copy() if planar else point
    active = (0, 1, 3, 5, 6)
    params = random_params(rng)
    q = pose.transformTo(point)
    pan, tilt = (float(a) + rng.normal() * 0.01 for a in bearing_pan_tilt(q))
    fixed = params.copy()
    fixed[list(active)] = 0.0
    heads = HeadFactorSet(np.array([C(0)]), np.array([L(0)]), np.array([H(0)]), {H(0): active}, fixed[None],
                          np.array([pan]), np.array([tilt]), [gtsam.noiseModel.Isotropic.Sigma(2, 0.01)], planar)
    assert_head_factor_jacobians(heads, (C(0), L(0), H(0)), pose, node, params[list(active)].copy(), 0.01)


def test_prior_is_the_population_the_simulator_draws_heads_from() -> None:
    """Prior sigma = datasheet tolerance / 2 = the typical errors; sampled heads have that spread."""
    np.testing.assert_allclose(DEFAULT_PRIOR_SIGMAS, DATASHEET_TOLERANCES / 2)
    np.testing.assert_allclose(TYPICAL_MAGNITUDES, DEFAULT_PRIOR_SIGMAS)
    draws = sample_head_errors([f"c{i}" for i in range(4000)], np.random.default_rng(0))
    z = np.array(list(draws.values())) / DEFAULT_PRIOR_SIGMAS
    # 4000 draws: the sample std of a unit Gaussian is within 1 +- 0.05 (4.5 sd), the mean within 0.07.
    assert np.all(np.abs(z.std(axis=0) - 1.0) < 0.05) and np.all(np.abs(z.mean(axis=0)) < 0.07)
