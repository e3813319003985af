"""One rule for every reader: accepted and meaning what it says, or one line naming file,
field and value (exit 2). Each malformed-input class of issue 15 has a case here."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.files.journal import JournalError, journal_to_survey, read_journal, survey_to_journal
from fgloc.files.survey_result import (
    read_result,
    read_survey,
    result_to_json,
    survey_to_json,
    write_result,
    write_survey,
)
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey


@pytest.fixture(scope="module")
def solved(tmp_path_factory) -> tuple[Path, Path, dict, dict]:
    """A simulated planar survey, its result, and both as JSON documents."""
    d = tmp_path_factory.mktemp("contract")
    survey = paper_scenario(PaperScenario(n_nodes=15, seed=4))
    result = solve_survey(survey)
    write_survey(survey, d / "s.json")
    write_result(result, d / "r.json")
    return d / "s.json", d / "r.json", survey_to_json(survey), result_to_json(result)


def _write(tmp_path: Path, name: str, doc: Any) -> Path:
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


def _one_line_error(argv: list[str], capsys, *fragments: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fgloc: error: "), err
    for f in fragments:
        assert f in err, err
    return err


def _first_node(doc: dict) -> str:
    return next(iter(doc["nodes"]))


# (name, how to break the result document, fragments of the expected error)
RESULT_CASES = [
    ("cov3_in_planar", lambda d, n: d["nodes"][n].update(covariance=np.eye(3).tolist()),
     ("covariance", "planar result needs a 2x2 covariance, got 3x3")),
    ("negative_definite", lambda d, n: d["nodes"][n].update(covariance=[[-1e-6, 0], [0, -1e-6]]),
     ("covariance", "not positive definite")),
    ("asymmetric", lambda d, n: d["nodes"][n].update(covariance=[[1e-6, 5e-7], [0, 1e-6]]),
     ("covariance", "not symmetric")),
    ("singular", lambda d, n: d["nodes"][n].update(covariance=[[1e-6, 1e-6], [1e-6, 1e-6]]),
     ("covariance", "singular")),
    ("huge_position", lambda d, n: d["nodes"][n].update(position=[1e308, 0.0, 0.0]),
     ("position[0]", "1e+308")),
    ("huge_integer_position", lambda d, n: d["nodes"][n].update(position=[10**400, 0, 0]),
     ("position[0]", "finite number")),
    ("both_localized_and_not", lambda d, n: d.update(unlocalized={n: "lost"}),
     ("unlocalized.", "also in nodes")),
    ("planar_node_off_plane", lambda d, n: d["nodes"][n].update(position=[0.1, 0.2, 0.5]),
     ("position", "z = 0")),
]


@pytest.mark.parametrize("name, breaks, fragments", RESULT_CASES, ids=[c[0] for c in RESULT_CASES])
def test_bad_result_refused_by_score_and_view(tmp_path, capsys, solved, name, breaks, fragments) -> None:
    s_path, _, _, r_doc = solved
    doc = copy.deepcopy(r_doc)
    breaks(doc, _first_node(doc))
    text = json.dumps(doc).replace("1e+308", "1e308")
    if name == "huge_integer_position":
        text = json.dumps({**doc, "nodes": {**doc["nodes"], _first_node(doc): {
            **doc["nodes"][_first_node(doc)], "position": [0, 0, 0]}}}).replace("[0, 0, 0]", "[" + "9" * 400 + ", 0, 0]")
    bad = _write(tmp_path, "bad.json", text)
    _one_line_error(["score", str(s_path), str(bad)], capsys, "bad.json", *fragments)
    _one_line_error(["view", str(bad), "--survey", str(s_path), "--save", str(tmp_path / "v.rrd")], capsys,
                    "bad.json", *fragments)
    assert not (tmp_path / "v.rrd").exists()


def test_3d_result_for_planar_survey_refused_without_mode_field(tmp_path, capsys, solved) -> None:
    """A contract-only result (no fgloc `mode`) whose 3x3 covariances do not fit the planar survey."""
    s_path, _, _, r_doc = solved
    doc = copy.deepcopy(r_doc)
    del doc["mode"]
    for v in doc["nodes"].values():
        v["covariance"] = (np.eye(3) * 1e-6).tolist()
    bad = _write(tmp_path, "r3.json", doc)
    assert read_result(bad).mode.value == "3d"  # alone it is a valid 3d result
    _one_line_error(["score", str(s_path), str(bad)], capsys, "r3.json", "3d result", "planar survey")
    _one_line_error(["view", str(bad), "--survey", str(s_path), "--save", str(tmp_path / "v.rrd")], capsys,
                    "r3.json", "3d result")


def test_result_naming_other_survey_ids_refused(tmp_path, capsys, solved) -> None:
    s_path, _, _, r_doc = solved
    doc = copy.deepcopy(r_doc)
    doc["cameras"]["camX"] = doc["cameras"].pop("cam1")
    _one_line_error(["score", str(s_path), str(_write(tmp_path, "r.json", doc))], capsys, "cameras.camX", "camX")
    doc = copy.deepcopy(r_doc)
    doc["flagged_observations"] = [{"camera": "cam0", "node": "n000", "index": 10**6}]
    _one_line_error(["score", str(s_path), str(_write(tmp_path, "r.json", doc))], capsys,
                    "flagged_observations[0].index")


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "-inf"])
def test_baseline_m_must_be_positive_finite(capsys, solved, value) -> None:
    s_path, r_path, _, _ = solved
    _one_line_error(["score", str(s_path), str(r_path), f"--baseline-m={value}"], capsys, "--baseline-m")


def test_good_result_scores(capsys, solved) -> None:
    s_path, r_path, _, _ = solved
    assert main(["score", str(s_path), str(r_path), "--json"]) == 0
    score = json.loads(capsys.readouterr().out)
    assert 0 < score["anees"] < 10 and score["n_nodes"] == 15


SURVEY_CASES = [
    ("truth_rotation_2x2", lambda d: d["truth"]["cameras"]["cam0"].update(rotation=[[1, 0], [0, 1]]),
     ("truth.cameras.cam0.rotation",)),
    ("truth_node_2_numbers", lambda d: d["truth"]["nodes"].update(n000=[0.1, 0.2]), ("truth.nodes.n000",)),
    ("truth_unknown_node", lambda d: d["truth"]["nodes"].update(zz=[0.1, 0.2, 0.0]), ("truth.nodes.zz",)),
    ("truth_unknown_camera", lambda d: d["truth"]["cameras"].update(camX=d["truth"]["cameras"]["cam0"]),
     ("truth.cameras.camX",)),
    ("truth_planar_node_off_plane", lambda d: d["truth"]["nodes"].update(n000=[0.1, 0.2, 0.3]),
     ("truth.nodes.n000", "z = 0")),
    ("truth_reflection", lambda d: d["truth"]["cameras"]["cam0"].update(rotation=np.diag([1, 1, -1]).tolist()),
     ("truth.cameras.cam0.rotation", "proper rotation")),
    ("truth_huge_position", lambda d: d["truth"]["nodes"].update(n000=[1e300, 0, 0]), ("truth.nodes.n000[0]",)),
    ("sigma_zero", lambda d: d.update(sigma=0), ("sigma",)),
    ("tilt_out_of_range", lambda d: d["observations"][2].update(tilt=2.0), ("observations[2].tilt",)),
    ("camera_id_list", lambda d: d["observations"][2].update(camera=["cam0"]), ("observations[2].camera",)),
]


@pytest.mark.parametrize("name, breaks, fragments", SURVEY_CASES, ids=[c[0] for c in SURVEY_CASES])
def test_bad_survey_refused_by_solve(tmp_path, capsys, solved, name, breaks, fragments) -> None:
    _, _, s_doc, _ = solved
    doc = copy.deepcopy(s_doc)
    breaks(doc)
    bad = _write(tmp_path, "bad.json", doc)
    _one_line_error(["solve", str(bad), "-o", str(tmp_path / "out.json")], capsys, "bad.json", *fragments)
    assert not (tmp_path / "out.json").exists()


def test_deeply_nested_json_is_one_line(tmp_path, capsys) -> None:
    bad = _write(tmp_path, "deep.json", "[" * 50000 + "]" * 50000)
    _one_line_error(["solve", str(bad), "-o", str(tmp_path / "o.json")], capsys, "deep.json", "nested too deeply")
    _one_line_error(["score", str(bad), str(bad)], capsys, "deep.json")
    j = _write(tmp_path, "j.jsonl", "[" * 50000 + "]" * 50000 + "\n")
    with pytest.raises(JournalError, match="nested too deeply"):
        read_journal(j)


def test_writer_reports_a_diverged_node_as_unlocalized(tmp_path, solved) -> None:
    """What the reader refuses is never written as an estimate (fgloc reads what it writes)."""
    _, r_path, _, _ = solved
    result = read_result(r_path)
    nid = next(iter(result.nodes))
    result.nodes[nid] = type(result.nodes[nid])(position=np.array([1e12, 0.0, 0.0]),
                                                covariance=result.nodes[nid].covariance)
    write_result(result, tmp_path / "r.json")
    back = read_result(tmp_path / "r.json")
    assert nid not in back.nodes and "diverged" in back.unlocalized[nid]


# ---- journal: exactly the survey contract -------------------------------------------------


def _journal_lines(tmp_path: Path) -> list[dict]:
    survey = paper_scenario(PaperScenario(n_nodes=6, seed=2))
    survey_to_journal(survey, tmp_path / "good.jsonl")
    return [json.loads(line) for line in (tmp_path / "good.jsonl").read_text().splitlines()]


def _obs_index(lines: list[dict]) -> int:
    return next(i for i, r in enumerate(lines) if r["type"] == "observation")


def _truth_index(lines: list[dict]) -> int:
    return next(i for i, r in enumerate(lines) if r["type"] == "truth")


JOURNAL_CASES = [
    ("header_sigma_zero", lambda ls: ls[0].update(sigma=0.0), "header.sigma"),
    ("header_sigma_negative", lambda ls: ls[0].update(sigma=-1e-3), "header.sigma"),
    ("header_gauge_unknown", lambda ls: ls[0]["gauge"].update(origin="camX"), "header.gauge.origin"),
    ("header_gauge_same", lambda ls: ls[0]["gauge"].update(baseline=ls[0]["gauge"]["origin"]), "gauge.baseline"),
    ("header_duplicate_node", lambda ls: ls[0]["node_ids"].append(ls[0]["node_ids"][0]), "header.node_ids[6]"),
    ("header_meta_nan", lambda ls: ls[0].update(meta={"x": "NAN"}), "header.meta.x"),
    ("tilt_out_of_range", lambda ls: ls[_obs_index(ls)].update(tilt=1.7), "observation.tilt"),
    ("node_id_list", lambda ls: ls[_obs_index(ls)].update(node=["n000"]), "observation.node"),
    ("camera_id_object", lambda ls: ls[_obs_index(ls)].update(camera={"a": 1}), "observation.camera"),
    ("not_found_node_list", lambda ls: ls.append({"type": "not_found", "node": [1], "camera": "cam0",
                                                  "reason": "x"}), "not_found.node"),
    ("done_node_object", lambda ls: ls.append({"type": "node_done", "node": {"a": 1}}), "node_done.node"),
    ("truth_rotation_2x2", lambda ls: ls[_truth_index(ls)]["cameras"]["cam0"].update(rotation=[[1, 0], [0, 1]]),
     "truth.cameras.cam0.rotation"),
    ("truth_rotation_improper",
     lambda ls: ls[_truth_index(ls)]["cameras"]["cam0"].update(rotation=np.diag([1, 1, -1]).tolist()),
     "truth.cameras.cam0.rotation"),
    ("truth_unknown_node", lambda ls: ls[_truth_index(ls)]["nodes"].update(zz=[0, 0, 0]), "truth.nodes.zz"),
]


@pytest.mark.parametrize("name, breaks, field", JOURNAL_CASES, ids=[c[0] for c in JOURNAL_CASES])
def test_journal_refuses_what_survey_json_refuses(tmp_path, name, breaks, field) -> None:
    """A journal record breaking the survey contract is refused at its line, so resume can never
    write a survey.json that `fgloc solve` refuses; the same break in survey.json is refused too."""
    lines = _journal_lines(tmp_path)
    breaks(lines)
    text = "\n".join(json.dumps(r) for r in lines).replace('"NAN"', "NaN") + "\n"
    path = _write(tmp_path, "bad.jsonl", text)
    with pytest.raises(JournalError) as info:
        read_journal(path)
    message = str(info.value)
    assert "\n" not in message and "bad.jsonl: line " in message and field in message, message


def test_journal_to_survey_json_round_trip_is_accepted(tmp_path) -> None:
    """Whatever the journal reader accepts becomes a survey.json `fgloc solve` accepts, unchanged."""
    survey = paper_scenario(PaperScenario(n_nodes=8, repeats=2, seed=5))
    survey_to_journal(survey, tmp_path / "j.jsonl")
    back = journal_to_survey(read_journal(tmp_path / "j.jsonl"))
    write_survey(back, tmp_path / "survey.json")
    again = read_survey(tmp_path / "survey.json")
    assert survey_to_json(again) == survey_to_json(back)
    assert main(["solve", str(tmp_path / "survey.json"), "-o", str(tmp_path / "r.json")]) in (0, 3)
    assert read_result(tmp_path / "r.json").nodes


def test_flag_errors_are_fglocerrors() -> None:
    from fgloc.cli._args import FlagError, finite, integer

    assert issubclass(FlagError, FglocError)
    assert finite("--x", 2.0, above=0.0) == 2.0
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(FlagError, match="--x: expected a finite number > 0"):
            finite("--x", bad, above=0.0)
    with pytest.raises(FlagError, match="--n: expected an integer >= 0, got -1"):
        integer("--n", -1, at_least=0)
