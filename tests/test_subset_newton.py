"""The paper's subset-averaging Newton baseline (fgloc.baselines.subset_newton)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import fgloc.baselines.newton as newton
import fgloc.baselines.subset_guess as subset_guess
import fgloc.baselines.subset_newton as sn
import fgloc.baselines.subset_system as subset_system
from fgloc.core.model import Survey, Truth
from fgloc.sim.scenes import PaperScenario, observe, paper_scenario


def _noise_free(survey: Survey, points: np.ndarray | None = None) -> Survey:
    """The same survey with exact readings (noise 0); sigma stays the paper's for whitening."""
    assert survey.truth is not None
    cams = [survey.truth.cameras[c] for c in survey.camera_ids]
    X = survey.truth_node_array() if points is None else points
    obs = observe(survey.camera_ids, cams, survey.node_ids, X, 0.0, np.random.default_rng(0))
    truth = Truth(survey.truth.cameras, {n: p for n, p in zip(survey.node_ids, X)})
    return replace(survey, observations=obs, truth=truth)


def _packed(survey: Survey, k: int, t: int, seed: int = 0) -> tuple[list[np.ndarray], subset_system.SubsetReadings]:
    opts = sn.SubsetNewtonOptions(subset_size=k, n_subsets=t, seed=seed)
    subsets, members = sn._subset_readings(survey, opts)
    return subsets, sn._pack(survey, subsets, members)


def _true_state(survey: Survey, subsets: list[np.ndarray]) -> subset_system.SubsetState:
    assert survey.truth is not None
    cams = [survey.truth.cameras[survey.gauge.origin], survey.truth.cameras[survey.gauge.baseline]]
    X = survey.truth_node_array()
    S = len(subsets)
    R = np.tile(np.stack([c.rotation for c in cams]), (S, 1, 1, 1))
    h = np.tile([cams[0].position[2], cams[1].position[2]], (S, 1))
    xy = np.stack([X[s, :2] for s in subsets])
    return subset_system.SubsetState(R=R, h=h, xy=xy)


def test_jacobian_matches_central_differences() -> None:
    """The analytic Jacobian of the whitened residuals w.r.t. the retraction step
    (heights, rotation increments R Exp(w), node x/y) equals central differences."""
    survey = paper_scenario(PaperScenario(n_nodes=30, seed=4, max_roll_pitch_deg=5.0))
    subsets, obs = _packed(survey, 6, 3)
    rng = np.random.default_rng(1)
    state = _true_state(survey, subsets).retract(rng.normal(0, 0.02, size=(3, 8 + 12)))
    _, J = subset_system.residuals_and_jacobian(state, obs)
    eps = 1e-6
    num = np.zeros_like(J)
    for i in range(J.shape[2]):
        d = np.zeros((3, J.shape[2]))
        d[:, i] = eps
        num[:, :, i] = (subset_system.residuals(state.retract(d), obs) - subset_system.residuals(state.retract(-d), obs)) / (2 * eps)
    scale = np.max(np.abs(J))
    assert np.max(np.abs(J - num)) < 1e-6 * scale
    assert np.max(np.abs(J[:, :, 8:])) > 0 and np.max(np.abs(J[:, :, 2:8])) > 0


def test_noise_free_subsets_recover_truth() -> None:
    """With exact readings every subset's Newton solution is the true geometry
    (the planar gauge makes it unique) to 1e-8 baselines, from the generic start."""
    survey = _noise_free(paper_scenario(PaperScenario(n_nodes=30, seed=3)))
    out = sn.solve_subset_newton(survey, sn.SubsetNewtonOptions(subset_size=6, n_subsets=10))
    assert out.status == ["ok"] * 10
    X = survey.truth_node_array()
    err = np.linalg.norm(out.solutions.position - X[out.solutions.node_index, :2], axis=1)
    assert err.max() < 1e-8
    for cid in survey.camera_ids:
        assert np.allclose(out.result.cameras[cid].position, survey.truth.cameras[cid].position, atol=1e-8)
        assert np.allclose(out.result.cameras[cid].rotation, survey.truth.cameras[cid].rotation, atol=1e-8)


def test_line_search_guarantees_sufficient_decrease() -> None:
    """lnsrch: an over-long descent step is backtracked until f decreases by at least
    ALF * lambda * slope; an ascent direction leaves x unchanged and raises check."""
    survey = paper_scenario(PaperScenario(n_nodes=40, seed=5))
    subsets, obs = _packed(survey, 8, 5)
    rng = np.random.default_rng(2)
    state = _true_state(survey, subsets).retract(rng.normal(0, 0.05, size=(5, 8 + 16)))
    F, J = subset_system.residuals_and_jacobian(state, obs)
    f = 0.5 * np.sum(F**2, axis=1)
    grad = np.einsum("smn,sm->sn", J, F)
    step, _, deficient = newton.gauss_newton_step(J, F)
    assert not deficient.any()
    active = np.ones(5, dtype=bool)
    big = 40.0 * step  # far too long: must backtrack
    stpmax = np.full(5, 1e9)
    new, fnew, check = newton.line_search(state, obs, f, grad, big, stpmax, 1e-12, active)
    assert not check.any()
    assert np.all(fnew < f)
    assert np.allclose(0.5 * np.sum(subset_system.residuals(new, obs) ** 2, axis=1), fnew)
    new2, fnew2, check2 = newton.line_search(state, obs, f, grad, -step, stpmax, 1e-12, active)
    assert check2.all() and np.array_equal(fnew2, f) and np.array_equal(new2.xy, state.xy)


def test_newton_never_increases_f_and_converges_quadratically_near_truth() -> None:
    """Iterating newt from a perturbed start: f is monotone (lnsrch guarantee) and the
    final 2f is chi-square-sized (about 4kR - (8 + 2k) for an honest fit)."""
    survey = paper_scenario(PaperScenario(n_nodes=40, seed=6))
    subsets, obs = _packed(survey, 20, 2)
    state = subset_guess.level_camera_guesses(obs)[0]
    fs = []
    for max_it in range(0, 8):
        out = newton.solve_subsets(state, obs, sn.SubsetNewtonOptions(max_iterations=max_it))
        fs.append(out.f.copy())
    fs = np.array(fs)
    assert np.all(np.diff(fs, axis=0) <= 1e-9 * fs[:-1])
    dof = 4 * 20 - (8 + 40)
    assert np.all(2 * fs[-1] < 3 * dof) and list(out.status) == ["ok", "ok"]


def test_degenerate_and_underdetermined_subsets_are_detected() -> None:
    """Collinear nodes leave a camera rotation about the node line free (rank-deficient
    Jacobian); 3 nodes give 12 residuals for 14 unknowns. Both fail and nothing is averaged."""
    base = paper_scenario(PaperScenario(n_nodes=20, seed=3))
    X = base.truth_node_array()
    X[:, 1] = 0.3 + 0.2 * X[:, 0]
    collinear = _noise_free(base, X)
    out = sn.solve_subset_newton(collinear, sn.SubsetNewtonOptions(subset_size=5, n_subsets=4))
    assert out.status == ["degenerate"] * 4
    assert out.failures["degenerate"] == 4 and len(out.solutions.node_index) == 0
    assert len(out.result.nodes) == 0 and len(out.result.unlocalized) == 20
    out = sn.solve_subset_newton(base, sn.SubsetNewtonOptions(subset_size=3, n_subsets=4))
    assert out.failures["underdetermined"] == 4


def test_averaging_excludes_failed_subsets() -> None:
    """Each node's estimate is the mean of its successful subset solutions, its
    covariance the sample covariance / count; a subset with a gross error (20 deg on
    one pan) is flagged spurious (chi-square) and left out of the average."""
    survey = paper_scenario(PaperScenario(n_nodes=30, seed=7, subset_schedule=(10, 12)))
    obs = list(survey.observations)
    i = next(i for i, o in enumerate(obs) if o.subset == 0)
    obs[i] = replace(obs[i], pan=obs[i].pan + np.deg2rad(20.0))
    bad = replace(survey, observations=obs)
    out = sn.solve_subset_newton(bad)
    assert out.status[0] in ("spurious", "no-convergence", "non-physical")
    assert out.status[1:].count("ok") >= 10
    assert 0 not in set(out.solutions.subset_index.tolist())
    for j, nid in enumerate(survey.node_ids):
        pts = out.solutions.position[out.solutions.node_index == j]
        if len(pts) == 0:
            assert nid in out.result.unlocalized
            continue
        est = out.result.nodes[nid]
        assert np.allclose(est.position[:2], pts.mean(axis=0))
        if len(pts) >= 3:
            assert np.allclose(est.covariance, np.cov(pts.T) / len(pts))
        ok_subsets = [s for s, st in enumerate(out.status) if st == "ok" and j in out.subsets[s]]
        assert len(pts) == len(ok_subsets)


@pytest.mark.parametrize("k", [5, 20])
def test_subset_solutions_scatter_like_their_gauss_newton_covariance(k: int) -> None:
    """Statistical check against truth: over re-measured subsets, whitened node errors
    e^T C^-1 e (C = the subset's own (J^T J)^-1 node block) average about 2 (chi-square,
    2 dof). A Jacobian or whitening error by a factor of 2 would move it to 0.5 or 8."""
    survey = paper_scenario(PaperScenario(n_nodes=60, seed=8, subset_schedule=(k, 240 // k)))
    subsets, members = sn._subset_readings(survey, sn.SubsetNewtonOptions())
    obs = sn._pack(survey, subsets, members)
    out = sn.solve_packed(obs, sn.SubsetNewtonOptions())
    X = survey.truth_node_array()
    vals = []
    for s, nodes in enumerate(subsets):
        if out.status[s] != "ok":
            continue
        for slot, j in enumerate(nodes):
            c = 8 + 2 * slot
            e = out.state.xy[s, slot] - X[j, :2]
            vals.append(e @ np.linalg.solve(out.covariance[s, c : c + 2, c : c + 2], e))
    assert len(vals) > 150
    assert 1.4 < np.mean(vals) < 2.8
