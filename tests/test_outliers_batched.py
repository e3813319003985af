"""The batched outlier checks equal their per-node definitions.

:func:`fgloc.solve.outliers.deletion_residuals` and
:func:`fgloc.solve.outliers.replace_by_consensus` run in a few vectorized passes over
all readings. Here each is compared with a small per-node reference written straight
from its definition, on random surveys (planar and 3d, repeats, gross readings, a
perturbed estimate so residuals are not all tiny, a previously flagged subset left out).
"""

import numpy as np
import pytest

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing, pan_tilt_jacobian, pan_tilt_residual
from fgloc.core.model import NodeMode, Observation, Survey
from fgloc.init.planar import consensus_ground_point, ground_hits
from fgloc.init.start import InitialEstimate
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.outliers import deletion_residuals, replace_by_consensus
from fgloc.testing import stress_scene


def _with_gross_readings(survey: Survey, rng: np.random.Generator, share: float) -> Survey:
    obs = list(survey.observations)
    for k in np.flatnonzero(rng.uniform(size=len(obs)) < share):
        o = obs[k]
        obs[k] = Observation(o.camera, o.node, o.pan + rng.normal(0, 0.1), o.tilt + rng.normal(0, 0.1), o.sigma)
    return Survey(survey.mode, survey.gauge, survey.sigma, survey.camera_ids, survey.node_ids, obs, survey.truth)


def _perturbed_truth(survey: Survey, rng: np.random.Generator, drop: int) -> InitialEstimate:
    """The true cameras and nodes moved by ~3 sigma-ish amounts; ``drop`` nodes and one camera missing."""
    assert survey.truth is not None
    nodes = {n: np.asarray(p, float) + (rng.normal(0, 2e-3, 3) * ([1, 1, 0] if survey.mode is NodeMode.PLANAR else 1))
             for n, p in survey.truth.nodes.items()}
    for n in list(nodes)[:drop]:
        del nodes[n]
    cameras = dict(survey.truth.cameras)
    if len(cameras) > 3:
        del cameras[survey.camera_ids[-1]]
    return InitialEstimate(cameras=cameras, nodes=nodes, unlocalized={})


def reference_deletion_residuals(survey: Survey, estimate: InitialEstimate, included: np.ndarray) -> np.ndarray:
    """Node by node, reading by reading: r^T (sigma^2 I + J Sigma_j J^T)^-1 r, Sigma_j from the node's
    other included readings (NaN when the node is not determined by them)."""
    dim = survey.mode.position_dim
    sigmas = survey.observation_table.sigma  # a reading's own sigma, else the survey's
    out = np.full(len(survey.observations), np.nan)
    by_node: dict[str, list[int]] = {}
    for k, o in enumerate(survey.observations):
        by_node.setdefault(o.node, []).append(k)
    for nid, ks in by_node.items():
        if nid not in estimate.nodes:
            continue
        x = np.asarray(estimate.nodes[nid], float)
        terms = {}
        for k in ks:
            o = survey.observations[k]
            cam = estimate.cameras.get(o.camera)
            if cam is None:
                continue
            q = cam.rotation.T @ (x - cam.position)
            pan, tilt = bearing_pan_tilt(q)
            r = np.asarray(pan_tilt_residual(o.pan, o.tilt, pan, tilt), float).reshape(2)
            jac = (pan_tilt_jacobian(q[None])[0] @ cam.rotation.T)[:, :dim]
            terms[k] = (r, jac, float(sigmas[k]))
        for k, (r, jac, sigma) in terms.items():
            info = sum((j.T @ j / s**2 for kk, (_, j, s) in terms.items() if kk != k and included[kk]),
                       np.zeros((dim, dim)))
            eig = np.linalg.eigvalsh(info)
            if not eig[0] > 1e-12 * max(eig[-1], 1e-300):
                continue
            S = sigma**2 * np.eye(2) + jac @ np.linalg.inv(info) @ jac.T
            out[k] = r @ np.linalg.solve(S, r)
    return out


def reference_consensus(survey: Survey, estimate: InitialEstimate) -> dict[str, np.ndarray]:
    """Node by node: the consensus of its readings' ground points (as the start places nodes)."""
    sigmas = survey.observation_table.sigma
    out = {}
    for nid in survey.node_ids:
        ks = [k for k, o in enumerate(survey.observations) if o.node == nid and o.camera in estimate.cameras]
        if len(ks) < 3:
            continue
        obs = [survey.observations[k] for k in ks]
        cams = [estimate.cameras[o.camera] for o in obs]
        dirs = np.array([c.rotation @ pan_tilt_bearing(o.pan, o.tilt) for c, o in zip(cams, obs)])
        pts, tol, ok = ground_hits(np.array([c.position for c in cams]), dirs,
                                   float(np.median(sigmas[ks])))
        if ok.sum() >= 3:
            xy, inliers = consensus_ground_point(pts[ok], tol[ok])
            if inliers.sum() >= 2:
                out[nid] = np.array([xy[0], xy[1], 0.0])
    return out


@pytest.mark.parametrize("mode", [NodeMode.PLANAR, NodeMode.THREE_D])
@pytest.mark.parametrize("index", [2, 5])
def test_deletion_residuals_equal_the_per_node_formula(mode: NodeMode, index: int) -> None:
    rng = np.random.default_rng(index)
    survey = _with_gross_readings(stress_scene(index, mode), rng, 0.05)
    estimate = _perturbed_truth(survey, rng, drop=3)
    included = rng.uniform(size=len(survey.observations)) > 0.1
    got = deletion_residuals(survey, estimate, included)
    want = reference_deletion_residuals(survey, estimate, included)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.isnan(got).sum() < len(got)
    finite = np.isfinite(want)
    assert np.allclose(got[finite], want[finite], rtol=1e-9, atol=1e-12)
    assert np.max(want[finite]) > 100.0  # the gross readings stand out (the check could fail)


@pytest.mark.parametrize("n_cameras", [3, 8])
def test_batched_consensus_equals_the_per_node_consensus(n_cameras: int) -> None:
    rng = np.random.default_rng(n_cameras)
    survey = _with_gross_readings(scene_survey(BenchScene(300, n_cameras, seed=n_cameras)), rng, 0.1)
    estimate = _perturbed_truth(survey, rng, drop=0)
    want = reference_consensus(survey, estimate)
    before = {n: p.copy() for n, p in estimate.nodes.items()}
    replace_by_consensus(survey, estimate)
    assert len(want) > 100
    for nid, p in estimate.nodes.items():
        expected = want.get(nid, before[nid])
        assert np.allclose(p, expected, rtol=0, atol=1e-12), nid
