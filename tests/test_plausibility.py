"""Goodness of fit and physical plausibility, checked on surveys with known truth."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.core.model import CameraPose, NodeMode
from fgloc.files.survey_result import read_result, write_survey
from fgloc.sim.scenes import PaperScenario, RandomScene, paper_scenario, random_scene
from fgloc.solve.joint import solve_survey
from fgloc.solve.plausibility import assess, chi2_upper_tail


def test_chi2_tail_matches_scipy() -> None:
    scipy_stats = pytest.importorskip("scipy.stats")
    for dof in (10, 37, 200, 5000):
        for q in (0.5, 0.9, 0.999, 0.999999):
            x = float(scipy_stats.chi2.ppf(q, dof))
            assert chi2_upper_tail(x, dof) == pytest.approx(1 - q, abs=2e-3, rel=0.1)


@pytest.mark.parametrize("mode", [NodeMode.PLANAR, NodeMode.THREE_D])
def test_clean_surveys_fit(mode) -> None:
    """Over seeded clean scenes chi2/dof is about 1 (the dof count is right) and none is flagged."""
    ratios = []
    for seed in range(6):
        survey = random_scene(RandomScene(n_cameras=4, n_nodes=60, mode=mode, seed=seed))
        report = assess(survey, solve_survey(survey))
        assert report.plausible, report.problems
        ratios.append(report.chi2 / report.dof)
    # Sum of 6 chi2 over the summed dof: mean 1, sd about sqrt(2 / total dof) ~ 0.04.
    assert 0.85 < float(np.mean(ratios)) < 1.15


def test_dof_count_is_exact_for_noise_free_truth() -> None:
    """At the truth, chi2 is the sum of the injected noise: E = 2 M, the parameters don't enter."""
    survey = paper_scenario(PaperScenario(n_nodes=40, seed=1))
    truth = survey.truth
    assert truth is not None
    from fgloc.core.model import NodeEstimate, Result

    result = Result(mode=survey.mode, cameras=dict(truth.cameras),
                    nodes={n: NodeEstimate(truth.nodes[n], np.eye(2)) for n in survey.node_ids})
    report = assess(survey, result)
    assert report.readings == 80
    assert report.dof == 2 * 80 - (6 * 2 + 2 * 40 - 4)
    assert 80 < report.chi2 < 250  # chi2 with 160 dof: 160 +- 18


def test_understated_sigma_is_a_poor_fit() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=60, repeats=2, seed=2))
    wrong = replace(survey, sigma=survey.sigma / 4)
    report = assess(wrong, solve_survey(wrong))
    assert not report.plausible and "do not fit" in report.problems[0]
    assert report.chi2 / report.dof > 3  # 16 before the solver flags the widest readings


def test_random_noise_survey_is_flagged() -> None:
    """Readings of nothing in particular: the solve must not look like a good one."""
    survey = random_scene(RandomScene(n_cameras=4, n_nodes=40, mode=NodeMode.PLANAR, seed=3))
    rng = np.random.default_rng(0)
    noise = [replace(o, pan=float(rng.uniform(-np.pi, np.pi)), tilt=float(rng.uniform(-1.4, -0.05)))
             for o in survey.observations]
    bad = replace(survey, observations=noise)
    try:
        result = solve_survey(bad)
    except FglocError:  # refusing is also an answer (anything else fails the test)
        return
    report = assess(bad, result)
    assert not report.plausible or len(result.flagged) > len(bad.observations) // 3


def test_camera_below_the_plane_is_a_problem() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=20, seed=3))
    result = solve_survey(survey)
    cam = result.cameras["cam1"]
    result.cameras["cam1"] = CameraPose(cam.position * np.array([1, 1, -1]), cam.rotation)
    report = assess(survey, result)
    assert any("cam1 is not above the node plane" in p for p in report.problems)


def test_flipped_tilt_is_not_silent(tmp_path, capsys) -> None:
    """Every tilt negated: bearings are explained exactly by upside-down heads (a mirror scene);
    level-mounted heads turning upside down is named in the summary and the result."""
    survey = paper_scenario(PaperScenario(n_nodes=30, seed=5))
    flipped = replace(survey, observations=[replace(o, tilt=-o.tilt) for o in survey.observations])
    write_survey(flipped, tmp_path / "s.json")
    status = main(["solve", str(tmp_path / "s.json"), "-o", str(tmp_path / "r.json")])
    out = capsys.readouterr().out
    result = read_result(tmp_path / "r.json")
    assert result.fit is not None
    below = [c for c in result.cameras.values() if c.position[2] <= 0]
    if below:
        assert status == 3 and "IMPLAUSIBLE" in out
    else:
        assert "hang upside down" in out and any("tilt sign" in n for n in result.fit.notes)
    # The clean survey carries no note and exits 0.
    write_survey(survey, tmp_path / "c.json")
    assert main(["solve", str(tmp_path / "c.json"), "-o", str(tmp_path / "rc.json")]) == 0
    out = capsys.readouterr().out
    assert "fit: chi2" in out and "note:" not in out and "IMPLAUSIBLE" not in out
    doc = json.loads((tmp_path / "rc.json").read_text())
    assert doc["fit"]["plausible"] is True and doc["fit"]["dof"] == 2 * 60 - (12 + 60 - 4)
    assert math.isfinite(doc["fit"]["chi2"]) and 0 < doc["fit"]["p_value"] <= 1
