"""Coded (off-centre) readings through an imperfect head: the blink video draws the head's
errors, survey.json records each reading's view angles, and the head model predicts a reading
from its view (:func:`fgloc.core.head_model.head_view_pan_tilt`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing
from fgloc.core.head_model import head_pan_tilt
from fgloc.drivers.imperfect_head import head_at_zoom, ideal_equivalent_directions
from fgloc.files.journal import read_journal
from fgloc.files.survey_result import read_survey
from fgloc.survey.session import run_survey
from tests.test_head_rig import CAM0_ERRORS
from tests.test_survey_coded import coded_rig, opened, parsed, view_records


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def head_coded_rig(n_nodes: int = 30, head_errors: dict | None = None, **kw):
    """The coded test rig (wide 320 px cameras) with head errors and a small pair noise."""
    data = coded_rig(n_nodes, **kw)
    data["sigma_deg"] = 0.03
    if head_errors is not None:
        data["simulation"]["head_errors"] = head_errors
    return parsed(data)


def reading_errors(scene, records: list[dict]) -> dict[int, np.ndarray]:
    """Per camera index (K, 4) degrees: each decoded reading minus the view model's prediction
    (pan * cos tilt, tilt) and minus the centred model's ``head_pan_tilt`` (pan * cos tilt, tilt).

    The view model, written out here from the head's kinematics: at the view's encoder readings
    (pan0, tilt0) the LED at base point q shows where the ideal head sees ``M^T (q - o)``
    (:func:`fgloc.drivers.imperfect_head.ideal_equivalent_directions`); the ideal pixel
    composition reads that direction's bearing. q: the node's range along its apparent bearing."""
    out: dict[int, list] = {}
    for rec in records:
        i = scene.camera_ids.index(rec["camera"])
        pan0, tilt0 = rec["head"]
        p = head_at_zoom(scene.heads[i], scene.zoom_levers.get(i), rec["zoom"])
        for r in rec["readings"]:
            j = scene.node_ids.index(r["node"])
            q = np.linalg.norm(scene.nodes[j] - scene.cameras[i].position) * pan_tilt_bearing(*scene.apparent[i, j])
            vp, vt = bearing_pan_tilt(ideal_equivalent_directions(p, pan0, tilt0, q[None])[0])
            cp, ct, _, _ = head_pan_tilt(q, p, jacobians=False)
            out.setdefault(i, []).append([_wrap(r["pan"] - vp) * math.cos(vt), r["tilt"] - vt,
                                          _wrap(r["pan"] - float(cp)) * math.cos(float(ct)), r["tilt"] - float(ct)])
    return {i: np.degrees(np.array(v)) for i, v in out.items()}


@pytest.fixture(scope="module")
def head_survey(tmp_path_factory: pytest.TempPathFactory):
    """One coded survey of a 30-node rig whose heads have errors (cam0: issue 17's typical sizes)."""
    out = tmp_path_factory.mktemp("coded-head")
    rig = head_coded_rig(30, head_errors={"cam0": CAM0_ERRORS, "cam1": "typical"})
    rig_opened, sim = opened(rig)
    run_survey(rig, out / "c", opened=rig_opened)
    return rig, sim.scene, out / "c"


def test_blink_video_draws_the_head_errors_of_each_view(head_survey) -> None:  # type: ignore[no-untyped-def]
    """Every coded reading of an imperfect head agrees with the view model within the decoder's
    noise (0.01 degree class at 320 px), while the centred model is off by ten times more."""
    _, scene, out = head_survey
    err = reading_errors(scene, view_records(out / "journal.jsonl"))
    for i, e in err.items():
        assert len(e) >= 15
        view_rms = np.sqrt(np.mean(e[:, :2] ** 2, axis=0))
        assert np.all(view_rms < 0.012), (i, view_rms)
        assert np.abs(e[:, :2]).max() < 0.04, (i, np.abs(e[:, :2]).max(axis=0))
        centred_rms = float(np.sqrt(np.mean(e[:, 2:] ** 2)))
        assert centred_rms > 8 * float(np.sqrt(np.mean(e[:, :2] ** 2))), (i, centred_rms, view_rms)
    assert float(np.sqrt(np.mean(err[0][:, 2:] ** 2))) > 0.05  # cam0: tilt index 0.3 degree and more


def test_survey_json_records_each_coded_reading_s_view_angles(head_survey) -> None:  # type: ignore[no-untyped-def]
    """survey.json gives every reading decoded in a view that view's read-back encoder angles
    (``view_pan``, ``view_tilt``); the sequential fallback's centred readings have none."""
    _, _, out = head_survey
    survey = read_survey(out / "survey.json")
    state = read_journal(out / "journal.jsonl")
    want = {(r["camera"], o["node"], o["pan"], o["tilt"]): tuple(r["head"])
            for r in view_records(out / "journal.jsonl") for o in r["readings"]}
    got = {(o.camera, o.node, o.pan, o.tilt): o.view_angles for o in survey.observations if o.view_angles}
    assert got and got == want
    centred = [o for o in survey.observations if o.view_angles is None]
    assert len(centred) == sum(o.view is None for o in state.observations.values())
    assert all(o.view_tilt is None and o.view_pan is None for o in centred)
    raw = json.loads((out / "survey.json").read_text())["observations"]
    assert sum("view_pan" in o and "view_tilt" in o for o in raw) == len(want)


def test_ideal_heads_render_bit_identically(tmp_path: Path) -> None:
    """A head without errors (none given, or all zero) draws every mote along its apparent
    bearing exactly as before the view's angles were passed: same positions, same frames."""
    from fgloc.camera.blink_codes import code_book
    from fgloc.drivers.blink_frames import render_view
    from fgloc.drivers.blink_scene import _seed
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.drivers.tinyos.blink import BlinkBroadcast

    zeros = {"tilt_index_deg": 0.0}
    for errors in (None, {"cam0": zeros, "cam1": zeros}):
        rig = head_coded_rig(8, head_errors=errors)
        sim = InProcessRig(rig)
        assert not sim.scene.has_head_errors(0)
        sim.leds.broadcast_codes(BlinkBroadcast(code_book(8).length, 1, 8, 0.1))
        head = sim.open_head("cam0")
        head.move_to(0.3, -0.4)
        frames = sim.record_blinks("cam0", 6, 0.0, "k")
        blinks = sim._blinks
        old = blinks.motes("cam0")  # type: ignore[attr-defined]
        new = blinks.motes("cam0", *head.pointing)  # type: ignore[attr-defined]
        assert len(old) >= 4 and [m.node for m in old] == [m.node for m in new]
        assert all(np.array_equal(a.position, b.position) for a, b in zip(old, new))
        cam = blinks.cameras["cam0"]  # type: ignore[attr-defined]
        rng = np.random.default_rng(_seed(rig.simulation.seed, "cam0", "k", "blink-video"))
        want = render_view(cam, rig.cameras[0].intrinsics, *head.pointing, old, 6, rng,
                           blinks.config, statics=None, t_start=0.0)  # type: ignore[attr-defined]
        assert len(want) == len(frames) and all(
            ta == tb and np.array_equal(fa, fb) for (ta, fa), (tb, fb) in zip(want, frames))


# -- survey.json: the view angles of off-centre readings -----------------------------------------

def _survey_dict() -> dict:
    return {"format": "fgloc-survey", "version": 1, "nodes": "planar", "gauge": {"origin": "c0", "baseline": "c1"},
            "sigma": 0.002, "cameras": [{"id": "c0"}, {"id": "c1"}], "node_ids": ["n0", "n1"],
            "observations": [
                {"camera": "c0", "node": "n0", "pan": 0.4, "tilt": -0.3},
                {"camera": "c0", "node": "n1", "pan": 0.5, "tilt": -0.2, "view_pan": 0.45, "view_tilt": -0.25},
                {"camera": "c1", "node": "n1", "pan": 2.0, "tilt": -0.2, "sigma": 0.003, "view": "c1/v0",
                 "view_pan": 2.1, "view_tilt": -0.1}],
            "views": {"c1/v0": {"camera": "c1", "sigma": 0.001, "pan": 2.1}}}


def test_view_angles_round_trip_and_old_readers_see_the_same_readings(tmp_path: Path) -> None:
    from fgloc.files.survey_result import survey_to_json, write_survey

    path = tmp_path / "s.json"
    path.write_text(json.dumps(_survey_dict()))
    s = read_survey(path)
    assert [o.view_angles for o in s.observations] == [None, (0.45, -0.25), (2.1, -0.1)]
    assert s.observations[2].view_sigma == 0.001 and s.observations[0].view_pan is None
    write_survey(s, tmp_path / "back.json")
    back = read_survey(tmp_path / "back.json")
    assert back.observations == s.observations
    data = survey_to_json(s)
    assert "view_pan" not in data["observations"][0] and data["observations"][1]["view_tilt"] == -0.25
    # a reader that ignores the optional fields reads the same (camera, node, pan, tilt, sigma)
    plain = _survey_dict()
    for o in plain["observations"]:
        o.pop("view_pan", None)
        o.pop("view_tilt", None)
    path.write_text(json.dumps(plain))
    old = read_survey(path)
    assert [(o.camera, o.node, o.pan, o.tilt, o.sigma) for o in old.observations] == [
        (o.camera, o.node, o.pan, o.tilt, o.sigma) for o in s.observations]
    assert old.observations[2].view_pan == 2.1 and old.observations[2].view_tilt is None  # the views block's pan


@pytest.mark.parametrize("edit, message", [
    (lambda o: o.pop("view_tilt"), "observations[1]: 'view_tilt' is a dependency of 'view_pan'"),
    (lambda o: o.pop("view_pan"), "observations[1]: 'view_pan' is a dependency of 'view_tilt'"),
    (lambda o: o.update(view_tilt=2.0), "observations[1].view_tilt: must lie in"),
    (lambda o: o.update(view_pan="x"), "observations[1].view_pan: expected a number"),
])
def test_bad_view_angles_are_one_line(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    from fgloc.core.errors import FglocError

    data = _survey_dict()
    edit(data["observations"][1])
    path = tmp_path / "s.json"
    path.write_text(json.dumps(data))
    with pytest.raises(FglocError) as err:
        read_survey(path)
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


# -- the view model: off-centre readings through an imperfect head -------------------------------

def _random_heads(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS

    return scale * rng.normal(size=(n, 7)) * DEFAULT_PRIOR_SIGMAS * np.array([3, 3, 3, 3, 3, 20, 20])


def _off_centre_case(seed: int, n: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points, heads, and views up to 26 (pan) / 17 (tilt) degrees off the ideal bearing."""
    rng = np.random.default_rng(seed)
    pan = rng.uniform(-3.0, 3.0, n)
    tilt = rng.uniform(-1.2, 0.6, n)
    q = pan_tilt_bearing(pan, tilt) * rng.uniform(0.2, 2.0, n)[:, None]
    view = np.column_stack([pan + rng.uniform(-0.45, 0.45, n), np.clip(tilt + rng.uniform(-0.3, 0.3, n), -1.5, 1.5)])
    return q, _random_heads(rng, n, float(seed % 2)), view[:, 0], view[:, 1]  # even seeds: ideal heads


@pytest.mark.parametrize("seed", range(4))
def test_view_model_is_what_the_simulated_head_shows(seed: int) -> None:
    """The reading equals the bearing of ``M^T (q - o)`` of the simulator's head
    (drivers/imperfect_head.py), an independent implementation of the kinematics."""
    from fgloc.core.head_model import head_view_pan_tilt

    q, p, vp, vt = _off_centre_case(seed)
    pan, tilt, _, _ = head_view_pan_tilt(q, p, vp, vt, jacobians=False)
    for k in range(len(q)):
        want = bearing_pan_tilt(ideal_equivalent_directions(p[k], vp[k], vt[k], q[k:k + 1])[0])
        assert abs(_wrap(float(pan[k]) - float(want[0]))) < 1e-12 and abs(float(tilt[k]) - float(want[1])) < 1e-12


@pytest.mark.parametrize("seed", range(6))
def test_view_model_jacobians_match_central_differences(seed: int) -> None:
    from fgloc.core.head_model import HEAD_DIM, head_view_pan_tilt

    q, p, vp, vt = _off_centre_case(seed)

    def f(q: np.ndarray, p: np.ndarray) -> np.ndarray:
        pan, tilt, _, _ = head_view_pan_tilt(q, p, vp, vt, jacobians=False)
        return np.stack([pan, tilt], axis=-1)

    _, _, d_q, d_p = head_view_pan_tilt(q, p, vp, vt)
    h = 1e-7
    num_q = np.stack([(f(q + h * e, p) - f(q - h * e, p)) / (2 * h) for e in np.eye(3)], axis=-1)
    num_p = np.stack([(f(q, p + h * e) - f(q, p - h * e)) / (2 * h) for e in np.eye(HEAD_DIM)], axis=-1)
    scale = np.linalg.norm(q, axis=1)[:, None, None]  # d/dq scales as 1 / range
    np.testing.assert_allclose(d_q * scale, num_q * scale, atol=1e-6)
    np.testing.assert_allclose(d_p, num_p, atol=1e-6)


@pytest.mark.parametrize("seed", range(4))
def test_a_centred_reading_is_the_centred_model(seed: int) -> None:
    """At the view that centres the point (``head_pan_tilt``) the off-centre reading is that
    view's readings: the view model reduces to the centred one (lever arms included)."""
    from fgloc.core.head_model import head_view_pan_tilt

    q, p, _, _ = _off_centre_case(seed)
    p = p + (seed % 2 == 0) * _random_heads(np.random.default_rng(seed + 100), len(q))  # non-ideal heads too
    cp, ct, _, _ = head_pan_tilt(q, p, jacobians=False)
    vp, vt, _, _ = head_view_pan_tilt(q, p, cp, ct, jacobians=False)
    np.testing.assert_allclose(np.vectorize(_wrap)(vp - cp), 0.0, atol=1e-12)
    np.testing.assert_allclose(vt, ct, atol=1e-12)
    # off-centre it is not: a view 10 degrees away reads differently from the centred model
    op, ot, _, _ = head_view_pan_tilt(q, p, cp + 0.17, ct - 0.1, jacobians=False)
    assert np.max(np.abs(np.vectorize(_wrap)(op - cp)) + np.abs(ot - ct)) > 1e-4


@pytest.mark.parametrize("planar", [True, False])
@pytest.mark.parametrize("seed", range(3))
def test_factor_jacobians_with_view_angles_match_gtsam_numerical(planar: bool, seed: int) -> None:
    import gtsam
    from gtsam.symbol_shorthand import C, H, L

    from fgloc.factors.pan_tilt_head_factor import HeadFactorSet
    from fgloc.testing import assert_head_factor_jacobians

    rng = np.random.default_rng(seed)
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3), np.array([0.0, 0.0, 0.4]))
    point = np.array([rng.uniform(0.3, 1.0), rng.uniform(-0.5, 0.5), 0.0 if planar else rng.uniform(0, 0.3)])
    node = point[:2].copy() if planar else point
    active = (0, 1, 2, 3, 4, 5, 6)
    params = _random_heads(rng, 1)[0]
    pan, tilt = (float(a) for a in bearing_pan_tilt(pose.transformTo(point)))
    view = np.array([[pan + rng.uniform(-0.4, 0.4), tilt + rng.uniform(-0.25, 0.25)]])
    heads = HeadFactorSet(np.array([C(0)]), np.array([L(0)]), np.array([H(0)]), {H(0): active}, np.zeros((1, 7)),
                          np.array([pan + 0.01]), np.array([tilt - 0.01]),
                          [gtsam.noiseModel.Isotropic.Sigma(2, 0.01)], planar, view=view)
    assert heads.view is not None
    assert_head_factor_jacobians(heads, (C(0), L(0), H(0)), pose, node, params.copy(), 0.01)


# -- the self-calibrated solve on off-centre readings ---------------------------------------------

@pytest.fixture(scope="module")
def off_centre():
    """A seeded paper scene (two cameras 0.3 above the floor, 100 nodes) read off-centre as a coded
    survey reads it (views 26 x 18 degrees apart, 0.03 degree noise), heads of the typical sizes."""
    from fgloc.sim.coded_head import off_centre_survey
    from fgloc.sim.head_errors import typical_head_errors
    from fgloc.sim.scenes import PaperScenario, paper_scenario

    base = paper_scenario(PaperScenario(heights=(0.3, 0.3), seed=3))
    heads = typical_head_errors(base.camera_ids, np.random.default_rng(5))
    survey = off_centre_survey(base, heads, np.random.default_rng(5), math.radians(0.03),
                               (math.radians(13.0), math.radians(9.0)))
    return survey, heads


def _scores(survey, result, report, heads) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(joint NEES of the head parameters of all cameras, node RMS error)."""
    nees = sum(float((e.values - heads[c]) @ np.linalg.solve(e.covariance, e.values - heads[c]))
               for c, e in report.cameras.items())
    rms = math.sqrt(np.mean([np.sum((result.nodes[n].position[:2] - survey.truth.nodes[n][:2]) ** 2)
                             for n in result.nodes]))
    return nees, rms


def test_full_head_model_on_off_centre_readings_is_consistent_and_the_centred_one_biased(off_centre) -> None:  # type: ignore[no-untyped-def]
    """``--head-model full`` with the view angles recovers the heads within their covariance
    (joint NEES of 14 parameters below the chi-square 99.9 % point); the same readings taken as
    centred give head estimates far outside theirs and nodes several times worse."""
    from fgloc.sim.coded_head import centred_view
    from fgloc.solve.self_calibration import HeadModel, solve_with_head_model

    survey, heads = off_centre
    assert all(o.view_angles is not None for o in survey.observations)
    view = solve_with_head_model(survey, HeadModel.FULL, fast_path=False)
    centred = solve_with_head_model(centred_view(survey), HeadModel.FULL, fast_path=False)
    nees_v, rms_v = _scores(survey, *view, heads)
    nees_c, rms_c = _scores(survey, *centred, heads)
    chi2_999_14 = 36.12
    assert nees_v < chi2_999_14 and not view[0].flagged, nees_v
    assert nees_c > 10 * chi2_999_14 and rms_c > 3 * rms_v, (nees_c, rms_c, rms_v)


def test_off_centre_readings_never_take_the_node_eliminated_fast_path(off_centre) -> None:  # type: ignore[no-untyped-def]
    """The fast path models centred readings only: with view angles it is never chosen, and
    asking for it gives the reference graph's result."""
    from fgloc.solve.self_calibration import HeadModel, fast_path_is_safe, has_off_centre, solve_with_head_model

    survey, _ = off_centre
    assert has_off_centre(survey) and not fast_path_is_safe(survey)
    assert not has_off_centre(survey, frozenset(range(len(survey.observations))))
    forced, _ = solve_with_head_model(survey, HeadModel.FULL, fast_path=True)
    reference, _ = solve_with_head_model(survey, HeadModel.FULL, fast_path=False)
    for n, e in reference.nodes.items():
        np.testing.assert_array_equal(forced.nodes[n].position, e.position)


def test_few_wide_views_can_leave_the_head_undetermined_and_full_says_why() -> None:
    """Off-centre readings see a head only through each view's orientation: a camera with a
    handful of wide views can leave angular parameters undetermined. ``full`` refuses in one
    line naming the views; ``auto`` estimates the determinable subset."""
    from fgloc.core.errors import FglocError
    from fgloc.core.model import NodeMode
    from fgloc.sim.coded_head import off_centre_survey
    from fgloc.sim.head_errors import sample_head_errors
    from fgloc.sim.scenes import RandomScene, random_scene
    from fgloc.solve.self_calibration import HeadModel, solve_with_head_model

    base = random_scene(RandomScene(n_cameras=3, n_nodes=100, mode=NodeMode.PLANAR, visibility=1.0,
                                    ceiling_share=0.0, height_range=(0.3, 0.6), seed=3))
    heads = sample_head_errors(base.camera_ids, np.random.default_rng(2000))
    survey = off_centre_survey(base, heads, np.random.default_rng(0), math.radians(0.03))
    with pytest.raises(FglocError) as err:
        solve_with_head_model(survey, HeadModel.FULL)
    assert "cannot determine" in str(err.value) and "off-centre readings come from" in str(err.value)
    assert "\n" not in str(err.value)
    assert "camera cam2" in str(err.value) and "from 3 views" in str(err.value)
    _, report = solve_with_head_model(survey, HeadModel.AUTO)
    estimated = {c: e.estimated for c, e in report.cameras.items()}
    assert 0 < len(estimated["cam2"]) < 7 and len(estimated["cam0"]) == len(estimated["cam1"]) == 7, estimated
