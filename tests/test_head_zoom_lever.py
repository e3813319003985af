"""One lever arm per zoom: the head model of a camera whose readings were taken at several zooms.

Truths: GTSAM's numerical derivatives (factor Jacobians), the reference graph (the
node-eliminated fast path must reach its optimum and marginals), the injected per-zoom lever
arms of seeded surveys whose heads are drawn from the prior's population (joint NEES of the
lever arms, which a covariance 1.5x too large or too small fails), and the one-zoom head
model itself (a survey at one zoom gives bit-identical results with or without zooms).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import C, H, L
from scipy.stats import chi2

import fgloc  # noqa: F401  (first: importing factors.* before fgloc is circular)
from fgloc.core.errors import FglocError
from fgloc.core.geometry import bearing_pan_tilt
from fgloc.core.head_model import (
    DEFAULT_PRIOR_SIGMAS,
    HEAD_DIM,
    HEAD_PARAMETERS,
    head_dim,
    parameter_names,
    reading_params,
    zoom_groups,
)
from fgloc.core.model import Survey
from fgloc.factors.pan_tilt_head_factor import HeadFactorSet
from fgloc.files.survey_result import read_survey, write_result, write_survey
from fgloc.init.start import InitialEstimate
from fgloc.sim.head_errors import inject_head_errors, sample_head_errors, sample_zoom_levers
from fgloc.sim.scenes import RandomScene, random_scene
from fgloc.solve.eliminated import (
    HeadSpec,
    build_eliminated,
    camera_covariance,
    collect_eliminated,
    optimize_eliminated,
)
from fgloc.solve.joint import SolverOptions, auto_gauge_sigma, initialize, solve_survey
from fgloc.solve.levenberg_marquardt import LMParams
from fgloc.solve.self_calibration import (
    HeadModel,
    SelfCalibrationError,
    build_self_calibration_problem,
    determinable_subset,
    head_observability,
    optimize,
    solve_self_calibrated,
    solve_with_head_model,
)
from fgloc.survey.head_check import read_head_calibrations
from fgloc.testing import assert_head_factor_jacobians

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

#: Lever-arm prior and population of the recovery tests: 0.5 % of the baseline per component,
#: ten times the typical size, so that the readings (nodes 0.3-1.5 baselines away, sigma 0.1
#: degree) and not the prior determine the lever arms (posterior std 0.3-0.7 of the prior).
LEVER = 0.005
SIGMAS = DEFAULT_PRIOR_SIGMAS.copy()
SIGMAS[5:7] = LEVER
TIGHT = LMParams(relative_error_tol=1e-14, absolute_error_tol=0.0)


def two_zooms(seed: int, n_nodes: int = 40, zooms: tuple[float, float] = (0.0, 0.5)) -> Survey:
    """A planar 3-camera survey, each camera reading every node twice: once at each zoom."""
    s = random_scene(RandomScene(n_cameras=3, n_nodes=n_nodes, visibility=1.0, ceiling_share=0.0,
                                 height_range=(0.3, 0.6), repeats=2, seed=seed))
    seen: dict[tuple[str, str], int] = {}
    obs = []
    for o in s.observations:
        k = seen.get((o.camera, o.node), 0)
        seen[(o.camera, o.node)] = k + 1
        obs.append(replace(o, zoom=zooms[k % 2]))
    return replace(s, observations=obs)


def with_head(s: Survey, seed: int) -> tuple[Survey, dict[str, np.ndarray]]:
    """``s`` with heads drawn from the population ``SIGMAS`` describes, the second zoom's lever
    arm drawn on its own; returns the survey and each camera's true extended vector."""
    rng = np.random.default_rng(seed + 50)
    heads = sample_head_errors(s.camera_ids, rng, SIGMAS)
    levers = sample_zoom_levers(s.camera_ids, [0.5], rng, LEVER)
    truth = {c: np.concatenate([heads[c], levers[c][0.5]]) for c in s.camera_ids}
    return inject_head_errors(s, heads, zoom_levers=levers), truth


def truth_start(s: Survey) -> InitialEstimate:
    assert s.truth is not None
    return InitialEstimate(cameras=dict(s.truth.cameras), nodes=dict(s.truth.nodes))


# ----- model and factor


def test_extended_vector_layout() -> None:
    assert head_dim(1) == HEAD_DIM and head_dim(3) == 11
    assert parameter_names([0.25]) == HEAD_PARAMETERS
    assert parameter_names([None, 0.5])[5:] == ("lever_y@-", "lever_z@-", "lever_y@0.5", "lever_z@0.5")
    ext = np.arange(9.0)
    np.testing.assert_array_equal(reading_params(ext, np.array([0, 1])), [[0, 1, 2, 3, 4, 5, 6], [0, 1, 2, 3, 4, 7, 8]])
    s = two_zooms(1, 6)
    zooms, group = zoom_groups(s)
    assert zooms == {c: (0.0, 0.5) for c in s.camera_ids}
    np.testing.assert_array_equal(group, [0 if o.zoom == 0.0 else 1 for o in s.observations])


@pytest.mark.parametrize("planar", [True, False])
@pytest.mark.parametrize("group", [0, 1])
@pytest.mark.parametrize("seed", range(3))
def test_factor_jacobians_match_gtsam_numerical(planar: bool, group: int, seed: int) -> None:
    """A reading of zoom group ``group`` against a camera vector holding both groups' lever arms:
    the analytic Jacobian (zero columns for the other group's lever arm) against numerical ones."""
    rng = np.random.default_rng(seed)
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3), np.array([0.0, 0.0, 0.4]))
    point = np.array([rng.uniform(0.3, 1.0), rng.uniform(-0.5, 0.5), 0.0 if planar else rng.uniform(0, 0.3)])
    node = point[:2].copy() if planar else point
    active = (0, 1, 3, 5, 6, 7, 8)
    ext = SIGMAS[:HEAD_DIM].tolist() + [LEVER, LEVER]
    values_ext = rng.normal(size=9) * np.array(ext)
    q = pose.transformTo(point)
    pan, tilt = (float(a) + rng.normal() * 0.01 for a in bearing_pan_tilt(q))
    fixed = reading_params(values_ext, np.array([group]))
    fixed[0, [0, 1, 3, 5, 6]] = 0.0  # active entries come from the Vector
    heads = HeadFactorSet(np.array([C(0)]), np.array([L(0)]), np.array([H(0)]), {H(0): active}, fixed,
                          np.array([pan]), np.array([tilt]), [gtsam.noiseModel.Isotropic.Sigma(2, 0.01)], planar,
                          zoom_group=np.array([group]))
    A, num_h = assert_head_factor_jacobians(heads, (C(0), L(0), H(0)), pose, node, values_ext[list(active)].copy(),
                                            0.01)
    dp = 2 if planar else 3
    own, other = ([3, 4], [5, 6]) if group == 0 else ([5, 6], [3, 4])  # lever-arm positions in ``active``
    assert np.all(A[:, 6 + dp + np.array(other)] == 0.0)
    assert np.max(np.abs(num_h[:, own])) > 1e-3


def test_predicted_readings_use_the_lever_arm_of_their_zoom() -> None:
    """At the truth, the head model with the true extended vectors leaves exactly the noise of the
    clean survey (same draw, ideal heads) as residuals; one lever arm for both zooms does not."""
    clean = two_zooms(3, 12)
    s, truth = with_head(clean, 3)
    ideal = build_self_calibration_problem(clean, truth_start(clean), {}, with_prior=False)
    exact = build_self_calibration_problem(s, truth_start(s), {}, truth, with_prior=False)
    assert ideal.heads is not None and exact.heads is not None
    noise = ideal.heads.errors(ideal.initial)
    np.testing.assert_allclose(exact.heads.errors(exact.initial), noise, atol=1e-10)
    one = {c: np.concatenate([v[:7], v[5:7]]) for c, v in truth.items()}  # zoom 0's lever arm for both
    wrong = build_self_calibration_problem(s, truth_start(s), {}, one, with_prior=False)
    assert wrong.heads is not None
    off = np.abs(wrong.heads.errors(wrong.initial) - noise)
    zoomed = np.array([o.zoom == 0.5 for o in s.observations])[wrong.observation_index]
    assert np.max(off[~zoomed]) < 1e-10 and np.max(off[zoomed]) > 1e-3


# ----- fast path


@pytest.mark.parametrize("seed", [1, 2])
def test_fast_path_same_optimum_and_marginals_with_two_zooms(seed: int) -> None:
    survey, _ = with_head(two_zooms(seed, 30), seed)
    init = initialize(survey)
    options = SolverOptions(lm=TIGHT, gauge_sigma=auto_gauge_sigma(survey, init))
    active = {c: tuple(range(9)) for c in survey.camera_ids}
    active[survey.camera_ids[-1]] = (0, 3, 7, 8)  # a partial model holding only zoom 0.5's lever arm
    ref = build_self_calibration_problem(survey, init, active, None, options, frozenset(), SIGMAS)
    ref_out = optimize(ref, options)
    fast = build_eliminated(survey, init, options, heads=HeadSpec(active, None, SIGMAS))
    outcome = optimize_eliminated(fast, options)
    result = collect_eliminated(fast, outcome, options)
    ref_cost = ref_out.error_history[-1]
    assert abs(result.stats.final_error - ref_cost) <= 1e-9 * ref_cost
    values = fast.node_values(outcome.values)
    ref.prepare(values)
    marginals = gtsam.Marginals(ref.graph.linearize(values), values)
    for nid, key in ref.node_keys.items():
        cov = marginals.marginalCovariance(key)
        assert np.linalg.norm(result.nodes[nid].covariance - cov) <= 1e-8 * np.linalg.norm(cov)
    sigma = camera_covariance(fast, outcome.values)
    offset = 6 * len(fast.camera_keys)
    for cid, key in fast.head_keys.items():
        n = len(active[cid])
        np.testing.assert_allclose(np.asarray(outcome.values.atVector(key)), np.asarray(ref_out.values.atVector(key)),
                                   atol=1e-6 * LEVER)
        block, cov = sigma[offset:offset + n, offset:offset + n], marginals.marginalCovariance(key)
        assert np.linalg.norm(block - cov) <= 1e-8 * np.linalg.norm(cov)
        offset += n
    fit = solve_self_calibrated(survey, init, active, options, prior_sigmas=SIGMAS, fast_path=True)
    assert fit.heads[survey.camera_ids[0]][0].shape == (9,)


# ----- recovery and covariance


def test_per_zoom_lever_arms_recovered_within_their_intervals() -> None:
    """16 seeded two-zoom surveys, heads and each zoom's lever arm drawn from the prior's
    population: joint NEES of the 4 lever-arm components per camera (192 dof) under their
    marginal covariance inside the chi-square 99 % interval, which 1.5x too large or too small
    leaves; 95 % intervals cover. The one-lever model (zooms ignored) on the same data is not
    consistent with either zoom's lever arm."""
    nees, dof, inside, one_lever = 0.0, 0, 0, 0.0
    for seed in range(16):
        s, truth = with_head(two_zooms(seed), seed)
        fit = solve_self_calibrated(s, truth_start(s), {c: tuple(range(9)) for c in s.camera_ids},
                                    prior_sigmas=SIGMAS)
        flat = replace(s, observations=[replace(o, zoom=None) for o in s.observations])
        single = solve_self_calibrated(flat, truth_start(flat), {c: tuple(range(7)) for c in s.camera_ids},
                                       prior_sigmas=SIGMAS)
        for c in s.camera_ids:
            v, cov = fit.heads[c]
            assert v.shape == (9,)
            e = (v - truth[c])[5:]
            nees += float(e @ np.linalg.solve(cov[5:, 5:], e))
            dof += 4
            inside += int(np.sum(np.abs(e) < 1.96 * np.sqrt(np.diag(cov)[5:])))
            v1, cov1 = single.heads[c]
            for lever in (truth[c][5:7], truth[c][7:9]):  # the one lever arm against each zoom's
                d = v1[5:7] - lever
                one_lever += float(d @ np.linalg.solve(cov1[5:7, 5:7], d))
    lo, hi = chi2.ppf([0.005, 0.995], dof) / dof
    anees = nees / dof
    assert lo < anees < hi, (anees, lo, hi)
    assert not lo < anees * 1.5 < hi and not lo < anees / 1.5 < hi
    assert 0.9 <= inside / dof <= 0.99, inside / dof
    assert one_lever / dof > 1.5 * hi, one_lever / dof  # measured 2.7: one lever arm cannot be both zooms'


def test_one_zoom_survey_gives_exactly_the_results_without_zooms() -> None:
    """Readings all at one zoom are one group: the extended vector is the 7-vector, and the solve,
    the report and the result block are bit-identical to the survey without zooms."""
    s = random_scene(RandomScene(n_cameras=3, n_nodes=30, visibility=1.0, ceiling_share=0.0,
                                 height_range=(0.3, 0.6), seed=5))
    s = inject_head_errors(s, sample_head_errors(s.camera_ids, np.random.default_rng(5)))
    zoomed = replace(s, observations=[replace(o, zoom=0.3) for o in s.observations])
    res_a, rep_a = solve_with_head_model(s, HeadModel.FULL)
    res_b, rep_b = solve_with_head_model(zoomed, HeadModel.FULL)
    for nid, est in res_a.nodes.items():
        np.testing.assert_array_equal(est.position, res_b.nodes[nid].position)
        np.testing.assert_array_equal(est.covariance, res_b.nodes[nid].covariance)
    for cid, est in rep_a.cameras.items():
        np.testing.assert_array_equal(est.values, rep_b.cameras[cid].values)
        np.testing.assert_array_equal(est.std, rep_b.cameras[cid].std)
        assert est.estimated == rep_b.cameras[cid].estimated == HEAD_PARAMETERS
    assert rep_a.to_json() == rep_b.to_json()
    assert all("lever_arm_per_zoom" not in c for c in rep_b.to_json()["cameras"].values())


# ----- observability and selection


def thin_zoom(seed: int) -> Survey:
    """Two zooms; cam1 read only two nodes at zoom 0.8 (its other readings at zoom 0)."""
    s = two_zooms(seed, 30)
    obs, n = [], 0
    for o in s.observations:
        if o.camera == "cam1" and o.zoom == 0.5:
            if n >= 2:
                continue
            n += 1
            o = replace(o, zoom=0.8)
        obs.append(o)
    return replace(s, observations=obs)


def test_thin_zoom_group_is_pinned_by_auto_and_refused_by_full() -> None:
    s = thin_zoom(4)
    start = truth_start(s)
    ranks, data_std = head_observability(s, start, SIGMAS)
    assert ranks["cam1"]["lever_arm@0.8"] == 0 and ranks["cam1"]["lever_arm@0"] == 2
    assert ranks["cam0"]["lever_arm@0.5"] == 2
    assert np.all(np.isinf(data_std["cam1"][7:9])) and np.all(np.isfinite(data_std["cam1"][:7]))
    assert np.all(np.isfinite(data_std["cam0"]))
    chosen = determinable_subset(s, start, prior_sigmas=SIGMAS)
    assert chosen["cam1"] == tuple(range(7)) and chosen["cam0"] == tuple(range(9))
    with pytest.raises(SelfCalibrationError) as err:
        solve_with_head_model(s, HeadModel.FULL, prior_sigmas=SIGMAS)
    msg = str(err.value)
    assert "\n" not in msg and "cam1" in msg and "lever_y@0.8, lever_z@0.8" in msg and "zoom 0.8 has 2 readings" in msg
    # AUTO on the same geometry with head errors: estimates everything but the thin zoom's lever arm.
    _, report = solve_with_head_model(with_head(s, 4)[0], HeadModel.AUTO, prior_sigmas=SIGMAS)
    assert report.cameras["cam1"].estimated == parameter_names((0.0, 0.8))[:7]
    assert report.cameras["cam0"].estimated == parameter_names((0.0, 0.5))
    assert report.cameras["cam1"].std[7] == 0.0 and report.cameras["cam1"].values[7] == 0.0


# ----- files


def test_survey_zoom_round_trip_and_a_reader_that_ignores_it(tmp_path: Path) -> None:
    s = two_zooms(2, 8)
    path = tmp_path / "survey.json"
    write_survey(s, path)
    back = read_survey(path)
    assert [o.zoom for o in back.observations] == [o.zoom for o in s.observations]
    data = json.loads(path.read_text())
    assert {o["zoom"] for o in data["observations"]} == {0.0, 0.5}
    # A version-1 reader knows no zoom: without the field the survey is the same readings, and
    # the ideal solve (which has no use for zooms) is unchanged.
    for o in data["observations"]:
        del o["zoom"]
    (tmp_path / "plain.json").write_text(json.dumps(data))
    plain = read_survey(tmp_path / "plain.json")
    assert all(o.zoom is None for o in plain.observations)
    a, b = solve_survey(back), solve_survey(plain)
    for nid, est in a.nodes.items():
        np.testing.assert_array_equal(est.position, b.nodes[nid].position)
    bad = json.loads(path.read_text())
    bad["observations"][3]["zoom"] = 1.5
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(FglocError) as err:
        read_survey(tmp_path / "bad.json")
    assert "observations[3].zoom" in str(err.value) and "\n" not in str(err.value)


def test_result_block_lists_the_lever_arm_per_zoom_and_old_readers_keep_working(tmp_path: Path) -> None:
    s, truth = with_head(two_zooms(6, 30), 6)
    result, report = solve_with_head_model(s, HeadModel.FULL, prior_sigmas=SIGMAS)
    block = report.to_json()
    cam = block["cameras"]["cam0"]
    assert len(cam["values"]) == len(cam["std"]) == HEAD_DIM and cam["estimated"] == list(HEAD_PARAMETERS)
    per_zoom = cam["lever_arm_per_zoom"]
    assert [z["zoom"] for z in per_zoom] == [0.0, 0.5] and all(z["estimated"] for z in per_zoom)
    est = report.cameras["cam0"]
    assert cam["values"][5:7] == per_zoom[0]["values"] == est.values[5:7].tolist()
    assert per_zoom[1]["values"] == est.values[7:9].tolist() and per_zoom[1]["std"] == est.std[7:9].tolist()
    assert set(cam["fisher_rank"]) >= {"lever_arm@0", "lever_arm@0.5"}
    summary = report.summary()
    assert "lever_y@0.5" in summary and "lever_z@0" in summary
    path = tmp_path / "result.json"
    write_result(result, path, {"head_calibration": block})
    cals = read_head_calibrations(path, s.camera_ids)  # a reader that knows one lever arm per camera
    np.testing.assert_allclose(cals["cam0"][0].values, cam["values"])
    assert math.isfinite(float(np.sum(cals["cam1"][0].values)))


# ----- simulated rigs


def test_rig_json_lever_by_zoom_and_the_in_process_head_at_each_zoom() -> None:
    """rig.json's ``lever_by_zoom`` parses (baseline units), enters the rig's meaning, is refused
    in one line when bad; the in-process scene shows a camera's LEDs through the lever arm of the
    zoom its head is at (the directions the head model predicts with that zoom's lever arm)."""
    from fgloc.core.geometry import pan_tilt_bearing
    from fgloc.core.head_model import head_pan_tilt
    from fgloc.drivers.imperfect_head import ideal_equivalent_directions
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.files.rig_config import parse_rig, rig_meaning
    from tests.test_head_rig import CAM0_ERRORS, EXAMPLE, head_rig_data

    errors = {"cam0": CAM0_ERRORS | {"lever_by_zoom": [{"zoom": 0.5, "lever_y_baseline": 0.004,
                                                         "lever_z_baseline": -0.002}]}}
    rig = parse_rig(head_rig_data(n_nodes=8, cameras=2, head_errors=errors), str(EXAMPLE), EXAMPLE.parent)
    assert rig.simulation.head_zoom_levers == {"cam0": {0.5: (0.004, -0.002)}}
    assert rig_meaning(rig, simulated=True)["simulation.head_errors.lever_by_zoom"] == {"cam0": [[0.5, 0.004, -0.002]]}
    sim = InProcessRig(rig)
    scene = sim.scene
    head = sim.open_head("cam0")
    i, j = rig.camera_ids.index("cam0"), 3
    assert scene.zoom[i] == rig.cameras[i].zoom
    head.set_zoom(0.5)  # the head tells the scene its zoom
    assert scene.zoom[i] == 0.5
    base = np.array(scene.heads[i])
    q = np.linalg.norm(scene.nodes[j] - scene.cameras[i].position) * pan_tilt_bearing(*scene.apparent[i, j])
    for zoom, lever in ((None, base[5:7]), (0.5, (0.004, -0.002)), (0.2, base[5:7])):
        scene.zoom[i] = zoom
        p = base.copy()
        p[5:7] = lever
        np.testing.assert_array_equal(scene.head(i), p)
        pan, tilt, _, _ = head_pan_tilt(q, p, jacobians=False)
        shown = scene.led_directions(i, [j], float(pan), float(tilt))[0]
        np.testing.assert_allclose(shown, ideal_equivalent_directions(p, float(pan), float(tilt), q)[0], atol=1e-12)
    bad = head_rig_data(n_nodes=8, cameras=2, head_errors={"cam0": {"lever_by_zoom": [{"zoom": 1.5}]}})
    with pytest.raises(FglocError) as err:
        parse_rig(bad, "rig.json", EXAMPLE.parent)
    assert "simulation.head_errors.cam0.lever_by_zoom[0].zoom" in str(err.value) and "\n" not in str(err.value)


def test_injected_lever_arm_follows_the_reading_zoom() -> None:
    """inject_head_errors: a reading at a listed zoom moves by that zoom's lever arm, others by the head's."""
    s = two_zooms(7, 10)
    heads = {c: np.zeros(HEAD_DIM) for c in s.camera_ids}
    heads["cam0"][5] = 0.003
    moved = inject_head_errors(s, heads, zoom_levers={"cam0": {0.5: (-0.003, 0.0)}})
    for o, m in zip(s.observations, moved.observations):
        if o.camera != "cam0":
            assert (o.pan, o.tilt) == (m.pan, m.tilt)
        else:  # opposite lever arms turn the pan reading opposite ways
            sign = 1.0 if o.zoom == 0.0 else -1.0
            assert sign * (m.pan - o.pan) < -1e-4


def test_known_motes_of_a_two_zoom_survey_are_predicted_at_the_first_zoom() -> None:
    """The drift check's predictions after a two-zoom survey: the head at its first zoom (the
    survey zoom, where motes are re-read), against the truth under their joint covariance
    (pooled over 4 surveys: measured 0.99 per dof; against the head at the other zoom 32)."""
    from fgloc.core.head_model import head_pan_tilt, reading_index
    from fgloc.solve.head_drift import known_motes_from_survey

    stat, other, dof = 0.0, 0.0, 0
    for seed in range(4):
        s, truth = with_head(two_zooms(seed, 30), seed)
        result, report = solve_with_head_model(s, HeadModel.FULL, prior_sigmas=SIGMAS)
        known = known_motes_from_survey(s, result, report, "cam0")
        assert s.truth is not None
        pose = s.truth.cameras["cam0"]
        q = np.array([pose.rotation.T @ (s.truth.nodes[n] - pose.position) for n in known.ids])
        true_pan, true_tilt, _, _ = head_pan_tilt(q, truth["cam0"][:7], jacobians=False)
        e = known.tilt - true_tilt
        stat += float(e @ np.linalg.solve(known.tilt_covariance, e))
        _, tele_tilt, _, _ = head_pan_tilt(q, truth["cam0"][list(reading_index(1))], jacobians=False)
        e = known.tilt - tele_tilt
        other += float(e @ np.linalg.solve(known.tilt_covariance, e))
        dof += len(e)
    lo, hi = chi2.ppf([0.005, 0.995], dof) / dof
    assert lo < stat / dof < hi, (stat / dof, lo, hi)
    assert other / dof > 5 * hi
