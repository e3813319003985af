"""Rerun view of the head calibration and the drift check: the .rrd holds the result's numbers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fgloc.cli import main
from tests.rrd_reading import last_static, load_rrd
from tests.test_head_rig import head_rig_data

MOTES = "n001,n002,n004,n005,n008"


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """A 30-node, 3-camera in-process survey with typical head errors, solved ideal and
    ``--head-model full`` (with ``--rerun``), viewed with ``fgloc view --save``, and drift
    checked (cam0's tilt index 0.3 degree higher) with ``fgloc head-check --rerun``."""
    d = tmp_path_factory.mktemp("solved")
    data = head_rig_data(n_nodes=30, sigma_deg=0.1)
    (d / "rig.json").write_text(json.dumps(data))
    data["simulation"]["head_errors"]["cam0"]["tilt_index_deg"] += 0.3
    (d / "rig-drift.json").write_text(json.dumps(data))
    assert main(["-q", "survey", "--rig", str(d / "rig.json"), "-o", str(d / "s"), "--simulate", "--no-live"]) == 0
    survey = str(d / "s" / "survey.json")
    assert main(["solve", survey, "--head-model", "full", "-o", str(d / "result.json"),
                 "--rerun", str(d / "solve.rrd")]) in (0, 3)
    assert main(["solve", survey, "-o", str(d / "ideal.json"), "--rerun", str(d / "ideal.rrd")]) in (0, 3)
    assert main(["view", str(d / "result.json"), "--survey", survey, "--save", str(d / "view.rrd")]) == 0
    assert main(["head-check", "--rig", str(d / "rig-drift.json"), "--result", str(d / "result.json"),
                 "--motes", MOTES, "-o", str(d / "check"), "--simulate", "--rerun", str(d / "check.rrd")]) == 4
    return d


def _assert_block_logged(entities, block, sub: str = "") -> None:
    for cid, cam in block["cameras"].items():
        base = f"cameras/{cid}/head" + (f"/{sub}" if sub else "")
        v, s = np.array(cam["values"]), np.array(cam["std"])
        for group, want, want_sigma in (("angles_deg", np.degrees(v[:3]), np.degrees(s[:3])),
                                        ("scales_percent", 100 * v[3:5], 100 * s[3:5]),
                                        ("lever_arm_baseline", v[5:7], s[5:7])):
            got = last_static(entities, f"{base}/{group}", "BarChart:values")[0]["buffer"]
            got_sigma = last_static(entities, f"{base}/{group}_sigma", "BarChart:values")[0]["buffer"]
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(got_sigma, want_sigma, rtol=1e-12, atol=1e-15)
        text = str(last_static(entities, f"{base}/summary", "TextDocument:text")[0])
        assert f"| tilt_index | {math.degrees(v[0]):+.5g} | {math.degrees(s[0]):.3g} | ° |" in text
        assert f"| pan_scale | {100 * v[3]:+.5g} | {100 * s[3]:.3g} | % |" in text


@pytest.mark.parametrize("rrd", ["solve.rrd", "view.rrd"])
def test_head_errors_logged_per_camera_equal_the_results(solved, rrd):
    """``fgloc solve --rerun`` (from the report) and ``fgloc view --save`` (from result.json)
    log each camera's head errors and 1-sigma, in degrees / percent / baseline units."""
    block = json.loads((solved / "result.json").read_text())["head_calibration"]
    entities = load_rrd(solved / rrd)
    assert set(block["cameras"]) == {"cam0", "cam1", "cam2"}
    _assert_block_logged(entities, block)


def test_an_ideal_solve_logs_no_head_entities(solved):
    assert not [e for e in load_rrd(solved / "ideal.rrd") if e.startswith("cameras/")]


def test_drift_check_series_equal_the_report(solved):
    """Per camera and re-read mote: the running tilt-index change, its sigma, chi2 and the flag
    on the ``head_check`` timeline; the calibration checked against and the updated one."""
    report = json.loads((solved / "check" / "head_check.json").read_text())
    entities = load_rrd(solved / "check.rrd")
    flags = []
    for cid, cam in report["cameras"].items():
        base = f"cameras/{cid}/head/drift"
        steps = cam["steps"]
        assert len(steps) == 5
        for series, key in (("tilt_index_change_deg", "tilt_index_change_deg"),
                            ("tilt_index_change_sigma_deg", "tilt_index_change_std_deg"), ("chi2", "chi2"),
                            ("pan_offset_deg", "pan_offset_deg")):
            rows = entities[f"{base}/{series}"].timed["head_check"]["Scalars:scalars"]
            assert [t for t, _ in rows] == [1, 2, 3, 4, 5]
            np.testing.assert_allclose([r[0] for _, r in rows], [s[key] for s in steps], rtol=1e-12)
        rows = entities[f"{base}/drifted"].timed["head_check"]["Scalars:scalars"]
        assert [r[0] for _, r in rows] == [1.0 if s["drifted"] else 0.0 for s in steps]
        texts = entities[f"{base}/log"].timed["head_check"]["TextLog:text"]
        assert all(t[0].startswith(s["mote"] + ":") for (_, t), s in zip(texts, steps))
        flags.append(steps[-1]["drifted"])
    assert flags == [True, False, False]  # only cam0 drifted
    _assert_block_logged(entities, json.loads((solved / "result.json").read_text())["head_calibration"])
    _assert_block_logged(entities, {"cameras": {c: v["updated"]["head_calibration"]
                                                for c, v in report["cameras"].items()}}, sub="updated")
