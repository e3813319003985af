"""Coded (off-centre) readings through an imperfect head: the blink video draws the head's
errors, survey.json records each reading's view angles, and the head model predicts a reading
from its view (:func:`fgloc.core.head_model.head_view_pan_tilt`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing
from fgloc.core.head_model import head_pan_tilt
from fgloc.drivers.imperfect_head import head_at_zoom, ideal_equivalent_directions
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


def test_blink_video_draws_the_head_errors_of_each_view(tmp_path: Path) -> None:
    """Every coded reading of an imperfect head agrees with the view model within the decoder's
    noise (0.01 degree class at 320 px), while the centred model is off by ten times more."""
    rig = head_coded_rig(30, head_errors={"cam0": CAM0_ERRORS, "cam1": "typical"})
    rig_opened, sim = opened(rig)
    run_survey(rig, tmp_path / "c", opened=rig_opened)
    err = reading_errors(sim.scene, view_records(tmp_path / "c" / "journal.jsonl"))
    for i, e in err.items():
        assert len(e) >= 15
        view_rms = np.sqrt(np.mean(e[:, :2] ** 2, axis=0))
        assert np.all(view_rms < 0.012), (i, view_rms)
        assert np.abs(e[:, :2]).max() < 0.04, (i, np.abs(e[:, :2]).max(axis=0))
        centred_rms = float(np.sqrt(np.mean(e[:, 2:] ** 2)))
        assert centred_rms > 8 * float(np.sqrt(np.mean(e[:, :2] ** 2))), (i, centred_rms, view_rms)
    assert float(np.sqrt(np.mean(err[0][:, 2:] ** 2))) > 0.05  # cam0: tilt index 0.3 degree and more


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
