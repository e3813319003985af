"""Per-view head offsets: the view rotation's Jacobians, the three-key factor, the survey format.

Math is checked against numerical differentiation (central differences on GTSAM's
retractions); the honesty of the covariances is checked by NEES in tests/test_blink_accuracy.py.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
import pytest

from fgloc.core.geometry import bearing_pan_tilt, rot_y, rot_z
from fgloc.core.model import Observation
from fgloc.factors.pan_tilt_batch import PanTiltFactorSet
from fgloc.factors.view_offset import rotate_by_view, view_pan_tilt_error
from fgloc.files.survey_result import FileFormatError, read_survey, survey_to_json
from fgloc.sim.scenes import PaperScenario, paper_scenario

RNG = np.random.default_rng(17)


def test_view_rotation_is_the_head_rotation_error() -> None:
    # the head read at (h + v_pan, t + v_tilt) instead of (h, t): bearings turn by Rz(h+v) Ry(-(t+w)) Ry(t) Rz(-h)
    q = RNG.normal(size=(6, 3))
    v = RNG.normal(scale=0.05, size=(6, 2))
    h, t = RNG.uniform(-3, 3, 6), RNG.uniform(-1, 1, 6)
    got, _, _ = rotate_by_view(q, v, h)
    for i in range(6):
        head = rot_z(h[i] + v[i, 0]) @ rot_y(-(t[i] + v[i, 1])) @ (rot_z(h[i]) @ rot_y(-t[i])).T
        assert np.allclose(got[i], head @ q[i], atol=1e-14)
    # at the view centre the offsets simply add to the angles
    p0, t0 = 0.7, -0.4
    centre = np.array([[math.cos(t0) * math.cos(p0), math.cos(t0) * math.sin(p0), math.sin(t0)]])
    pan, tilt = bearing_pan_tilt(rotate_by_view(centre, np.array([[0.003, -0.002]]), np.array([p0]))[0])
    assert abs(pan[0] - (p0 + 0.003)) < 1e-15 and abs(tilt[0] - (t0 - 0.002)) < 1e-15


def _error(pose: gtsam.Pose3, x: np.ndarray, v: np.ndarray, pan: float, tilt: float, h: float) -> np.ndarray:
    m = pose.matrix()
    return view_pan_tilt_error(m[None, :3, :3], m[None, :3, 3], x[None], np.array([pan]), np.array([tilt]),
                               v[None], np.array([h]))[0][0]


def test_view_pan_tilt_jacobians_against_central_differences() -> None:
    eps = 1e-6
    for _ in range(10):
        pose = gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(size=3)), RNG.normal(size=3))
        x = pose.translation() + RNG.normal(size=3) * 2.0
        v = RNG.normal(scale=0.01, size=2)
        pan, tilt, h = RNG.uniform(-3, 3), RNG.uniform(-1.2, 1.2), RNG.uniform(-3, 3)
        m = pose.matrix()
        _, hp, hx, hv = view_pan_tilt_error(m[None, :3, :3], m[None, :3, 3], x[None], np.array([pan]),
                                            np.array([tilt]), v[None], np.array([h]))
        num_pose = np.column_stack([
            (_error(pose.retract(eps * np.eye(6)[k]), x, v, pan, tilt, h)
             - _error(pose.retract(-eps * np.eye(6)[k]), x, v, pan, tilt, h)) / (2 * eps) for k in range(6)])
        num_x = np.column_stack([(_error(pose, x + eps * np.eye(3)[k], v, pan, tilt, h)
                                  - _error(pose, x - eps * np.eye(3)[k], v, pan, tilt, h)) / (2 * eps) for k in range(3)])
        num_v = np.column_stack([(_error(pose, x, v + eps * np.eye(2)[k], pan, tilt, h)
                                  - _error(pose, x, v - eps * np.eye(2)[k], pan, tilt, h)) / (2 * eps) for k in range(2)])
        np.testing.assert_allclose(hp[0], num_pose, atol=1e-7)
        np.testing.assert_allclose(hx[0], num_x, atol=1e-7)
        np.testing.assert_allclose(hv[0], num_v, atol=1e-7)


@pytest.mark.parametrize("planar", [True, False])
def test_three_key_factor_batch_equals_reference_and_numerical(planar: bool) -> None:
    # the vectorized pass and the per-reading callback agree, and GTSAM's linearization matches
    # numerical derivatives of the factor's own error (gtsam.numericalDerivative-style central differences)
    C, L, V = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L, gtsam.symbol_shorthand.V
    values = gtsam.Values()
    for i in range(2):
        values.insert(C(i), gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(scale=0.3, size=3)), np.array([i, 0.0, 0.3])))
    for j in range(5):
        p = RNG.uniform(0, 1, 3)
        values.insert(L(j), p[:2].copy() if planar else p)
    for k in range(3):
        values.insert(V(k), RNG.normal(scale=0.01, size=2))
    cams = np.array([C(0), C(0), C(1), C(1), C(0), C(1)])
    nodes = np.array([L(0), L(1), L(2), L(3), L(4), L(0)])
    views = np.array([V(0), V(0), V(1), -1, V(2), V(1)])
    pan, tilt = RNG.uniform(-3, 3, 6), RNG.uniform(-1, 0, 6)
    noise = [gtsam.noiseModel.Isotropic.Sigma(2, 0.01)] * 6
    fs = PanTiltFactorSet(cams, nodes, pan, tilt, noise, planar=planar, view_keys=views,
                          view_pans=RNG.uniform(-3, 3, 6))
    graph = gtsam.NonlinearFactorGraph()
    for f in fs.factors:
        graph.add(f)
    slow = graph.error(gtsam.Values(values))  # a copy: per-reading callbacks
    assert fs.error(values) == pytest.approx(slow, rel=1e-12)
    fs.prepare(values)
    for i, f in enumerate(fs.factors):
        lin = f.linearize(values)
        A, b = lin.jacobian()
        unwhitened = -b * 0.01
        assert np.allclose(unwhitened, fs.errors(values)[i], atol=1e-15)
        col = 0
        for key in f.keys():
            dim = values.dims()[key]
            num = np.empty((2, dim))
            for k in range(dim):
                plus, minus = gtsam.Values(values), gtsam.Values(values)
                delta = 1e-6 * np.eye(dim)[k]
                for vv, sgn in ((plus, 1.0), (minus, -1.0)):
                    if key in (C(0), C(1)):
                        vv.update(key, values.atPose3(key).retract(sgn * delta))
                    else:  # Point2 / Point3 / Vector2 values are numpy vectors
                        vv.update(key, np.asarray(values.atVector(key)) + sgn * delta)
                num[:, k] = (f.unwhitenedError(plus) - f.unwhitenedError(minus)) / 2e-6
            np.testing.assert_allclose(A[:, col:col + dim] * 0.01, num, atol=1e-6)
            col += dim
        assert len(f.keys()) == (3 if views[i] >= 0 else 2)


def _viewed_survey() -> dict:
    s = paper_scenario(PaperScenario(n_nodes=12, seed=4))
    obs = [replace(o, sigma=0.002, view=f"{o.camera}/v{k % 3}", view_sigma=0.0017, view_pan=0.1 * (k % 3))
           if k % 2 == 0 else o for k, o in enumerate(s.observations)]
    obs[1] = replace(obs[1], sigma_axes=(0.0015, 0.0025))
    return survey_to_json(replace(s, observations=obs))


def test_survey_views_round_trip(tmp_path: Path) -> None:
    data = _viewed_survey()
    assert data["views"]["cam0/v0"] == {"camera": "cam0", "sigma": 0.0017, "pan": 0.0}
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    survey = read_survey(path)
    assert survey_to_json(survey) == data
    t = survey.observation_table
    viewed = t.view_index >= 0
    assert viewed.sum() == (len(t) + 1) // 2
    assert np.allclose(t.reading_sigma[viewed], math.sqrt(0.002**2 - 0.0017**2))
    assert np.array_equal(t.sigma_axes[1], [0.0015, 0.0025]) and np.array_equal(t.reading_sigma[1], [0.0015, 0.0025])
    plain = ~viewed
    plain[1] = False  # the reading with its own pan and tilt sigma
    assert np.array_equal(t.reading_sigma[plain], np.column_stack([t.sigma, t.sigma])[plain])


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["observations"][0].update(view="nowhere"), "observations[0].view: view \"nowhere\" is not in views"),
    (lambda d: d["views"]["cam0/v0"].update(camera="cam1"), "belongs to camera \"cam1\""),
    (lambda d: d["views"]["cam0/v0"].update(sigma=0.003), "views.cam0/v0.sigma: the shared head part must be below"),
    (lambda d: d["views"]["cam0/v0"].update(camera="cam9"), "views.cam0/v0.camera: unknown camera \"cam9\""),
    (lambda d: d["observations"][0].update(sigma_axes=[0.0016, 0.003]), "sigma: the shared head part must be below"),
    (lambda d: d["observations"][1].update(sigma_axes=[0.001]), "observations[1].sigma_axes"),
])
def test_survey_view_errors_are_one_line(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    data = _viewed_survey()
    edit(data)
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError) as err:
        read_survey(path)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_observation_defaults_keep_views_off() -> None:
    o = Observation("a", "b", 0.1, 0.2)
    assert o.view is None and o.view_sigma is None and o.view_pan is None
