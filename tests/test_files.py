"""survey.json / result.json: round trips, tolerance of unknown fields, one-line errors for bad input."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.files.survey_result import read_result, read_survey, write_result, write_survey
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey


@pytest.fixture(scope="module")
def small_survey():
    return paper_scenario(PaperScenario(n_nodes=12, seed=5))


@pytest.fixture
def survey_json(tmp_path: Path, small_survey) -> dict:
    path = tmp_path / "survey.json"
    write_survey(small_survey, path)
    return json.loads(path.read_text())


def test_survey_round_trip(tmp_path: Path, small_survey) -> None:
    path = tmp_path / "s.json"
    write_survey(small_survey, path)
    back = read_survey(path)
    assert back.camera_ids == small_survey.camera_ids and back.node_ids == small_survey.node_ids
    assert back.observations == small_survey.observations
    assert back.gauge == small_survey.gauge and back.mode == small_survey.mode and back.sigma == small_survey.sigma
    for n in small_survey.node_ids:
        np.testing.assert_array_equal(back.truth.nodes[n], small_survey.truth.nodes[n])


def test_result_round_trip(tmp_path: Path, small_survey) -> None:
    result = solve_survey(small_survey)
    path = tmp_path / "r.json"
    write_result(result, path)
    back = read_result(path)
    assert set(back.nodes) == set(result.nodes)
    for n, est in result.nodes.items():
        np.testing.assert_array_equal(back.nodes[n].position, est.position)
        np.testing.assert_array_equal(back.nodes[n].covariance, est.covariance)
        assert back.nodes[n].covariance.shape == (2, 2)
    assert back.stats is not None and back.stats.iterations == result.stats.iterations


def test_spec_example_with_unknown_fields_is_read(tmp_path: Path) -> None:
    """The spec's own example, plus extra fields anywhere, must be accepted."""
    doc = {
        "format": "fgloc-survey", "version": 1, "nodes": "planar", "x-extra": {"a": 1},
        "gauge": {"origin": "cam0", "baseline": "cam1", "note": "hi"},
        "sigma": 0.0017453,
        "cameras": [{"id": "cam0", "model": "EVI-D100"}, {"id": "cam1"}],
        "node_ids": ["n000", "n001"],
        "observations": [
            {"camera": "cam0", "node": "n000", "pan": 0.7853, "tilt": -0.3120, "t": 12.5},
            {"camera": "cam1", "node": "n000", "pan": 2.1010, "tilt": -0.2871, "sigma": 0.0035},
        ],
        "truth": {"cameras": {"cam0": {"position": [0, 0, 0.3], "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}},
                  "nodes": {"n000": [0.42, 0.17, 0.0]}},
    }
    path = tmp_path / "survey.json"
    path.write_text(json.dumps(doc))
    s = read_survey(path)
    assert s.observations[1].sigma == 0.0035 and s.observations[0].sigma is None
    assert s.observation_table.sigma.tolist() == [0.0017453, 0.0035]


def mutate(doc: dict, path: str, value) -> dict:
    """Set (or delete, when value is DELETE) a dotted/indexed field of a JSON document."""
    parts = path.replace("[", ".").replace("]", "").split(".")
    target = doc
    for p in parts[:-1]:
        target = target[int(p)] if isinstance(target, list) else target[p]
    last = int(parts[-1]) if isinstance(target, list) else parts[-1]
    if value is DELETE:
        del target[last]
    else:
        target[last] = value
    return doc


DELETE = object()

BAD_CASES = [
    # (field path, new value, expected field named in message, expected text)
    ("sigma", 0, "sigma", "must be > 0"),
    ("sigma", -1e-3, "sigma", "must be > 0"),
    ("sigma", "0.1", "sigma", "expected a number"),
    ("observations[3].camera", "cam9", "observations[3].camera", 'unknown camera "cam9"'),
    ("observations[4].node", "nope", "observations[4].node", 'unknown node "nope"'),
    ("observations[2].pan", True, "observations[2].pan", "expected a number"),
    ("observations[2].pan", DELETE, "observations[2].pan", "missing required field"),
    ("observations[0].sigma", 0.0, "observations[0].sigma", "must be > 0"),
    ("gauge.origin", "camX", "gauge.origin", 'camera "camX" is not in cameras'),
    ("gauge.baseline", "cam0", "gauge.baseline", "must differ"),
    ("cameras[1].id", "cam0", "cameras[1]", 'duplicate id "cam0"'),
    ("node_ids[2]", "n000", "node_ids[2]", 'duplicate id "n000"'),
    ("node_ids[1]", "", "node_ids[1]", "non-empty string"),
    ("nodes", "flat", "nodes", 'expected "planar" or "3d"'),
    ("version", 2, "version", "unsupported version 2"),
    ("format", "other", "format", "expected"),
    ("observations", {}, "observations", "expected an array"),
    ("cameras", DELETE, "cameras", "missing required field"),
    ("truth.cameras.cam0.rotation", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "truth.cameras.cam0.rotation", "rotation"),
]


@pytest.mark.parametrize("field,value,named,text", BAD_CASES)
def test_bad_survey_gives_one_line_and_exit_2(tmp_path, survey_json, capsys, field, value, named, text) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(mutate(survey_json, field, value)))
    rc = main(["solve", str(path), "-o", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert str(path) in err and named in err and text in err
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_angles_rejected(tmp_path, survey_json, capsys, literal) -> None:
    text = json.dumps(mutate(survey_json, "observations[1].tilt", 12345.5)).replace("12345.5", literal)
    path = tmp_path / "nan.json"
    path.write_text(text)
    rc = main(["solve", str(path), "-o", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "observations[1].tilt" in err and "finite" in err and literal in err


def test_malformed_json_and_missing_file(tmp_path, capsys) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{"format": "fgloc-survey", ')
    assert main(["solve", str(path), "-o", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "broken.json: not valid JSON" in err and err.count("\n") == 1
    assert main(["score", str(tmp_path / "absent.json"), str(path)]) == 2
    assert "absent.json: file not found" in capsys.readouterr().err


def test_result_write_is_atomic(tmp_path, small_survey, monkeypatch) -> None:
    """A failure while writing leaves the previous file intact and no temporary file behind."""
    result = solve_survey(small_survey)
    path = tmp_path / "result.json"
    write_result(result, path)
    before = path.read_bytes()
    bad = next(iter(result.cameras.values()))
    object.__setattr__(bad, "position", np.array([math.nan, 0.0, 0.0]))  # JSON cannot hold NaN
    with pytest.raises(ValueError):
        write_result(result, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_written_files_get_normal_permissions(tmp_path, small_survey) -> None:
    import os

    path = tmp_path / "s.json"
    write_survey(small_survey, path)
    umask = os.umask(0)
    os.umask(umask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_unknown_solver_errors_are_written_as_null(tmp_path, small_survey) -> None:
    """An incremental estimate does not know its total error: the file stays valid JSON."""
    result = solve_survey(small_survey)
    result.stats.initial_error = float("nan")
    result.stats.final_error = float("nan")
    path = tmp_path / "r.json"
    write_result(result, path)
    doc = json.loads(path.read_text())
    assert doc["solver"]["initial_error"] is None and doc["solver"]["final_error"] is None
    assert set(read_result(path).nodes) == set(result.nodes)
