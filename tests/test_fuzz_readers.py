"""Property-based fuzzing of every reader and the CLI entry points (hypothesis).

Properties: any byte string, and any mutation of a valid file, ends either in a parse
or in one FglocError line (CLI: exit status 2), never in another exception; what fgloc
writes, fgloc reads back identically; each fast predicate in the readers accepts only
items the JSON Schema accepts. Profiles (tests/conftest.py): ``ci`` (default, 60
examples per test, derandomized) and ``HYPOTHESIS_PROFILE=long``.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fgloc.camera.intrinsics import CameraIntrinsics  # noqa: E402
from fgloc.cli import main  # noqa: E402
from fgloc.core.errors import FglocError  # noqa: E402
from fgloc.core.model import Gauge, NodeMode, Observation, Survey, Truth  # noqa: E402
from fgloc.files import journal as journal_mod  # noqa: E402
from fgloc.files import survey_result  # noqa: E402
from fgloc.files.camera_file import intrinsics_to_json, read_intrinsics, write_intrinsics  # noqa: E402
from fgloc.files.journal import read_journal, survey_to_journal  # noqa: E402
from fgloc.files.json_io import _validator, is_vector3, parse_json  # noqa: E402
from fgloc.files.rig_config import load_rig  # noqa: E402
from fgloc.files.survey_result import (  # noqa: E402
    read_result,
    read_survey,
    result_to_json,
    survey_to_json,
    write_result,
    write_survey,
)
from fgloc.sim.scenes import PaperScenario, paper_scenario  # noqa: E402
from fgloc.solve.joint import solve_survey  # noqa: E402

_SURVEY = paper_scenario(PaperScenario(n_nodes=6, seed=11))
_SURVEY_DOC = survey_to_json(_SURVEY)
_RESULT_DOC = result_to_json(solve_survey(_SURVEY))
_CAMERA_DOC = intrinsics_to_json(CameraIntrinsics(fx=800.0, fy=801.0, cx=319.5, cy=239.5, width=640, height=480))
_RIG_DOC: dict[str, Any] = {
    "cameras": [{"id": "c0", "driver": "simulated", "intrinsics": {"fx": 800, "fy": 800, "cx": 320, "cy": 240,
                                                                     "width": 640, "height": 480}},
                {"id": "c1", "driver": "simulated", "intrinsics": {"fx": 800, "fy": 800, "cx": 320, "cy": 240,
                                                                     "width": 640, "height": 480}}],
    "motes": {"driver": "simulated"},
    "node_ids": ["1", "2", "3"],
}

# Values a mutation puts in: every JSON type, the non-finite and huge tokens, deep nesting.
_SPECIAL_TOKENS = ["NaN", "Infinity", "-Infinity", "1e400", "9" * 400, "-0", "1e308", "[[[[[[[[]]]]]]]]",
                   '{"a": {"b": []}}', '""', "null", "true", "0", "-1", "1.5707963277948966", "3.2"]
_json_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=8), st.sampled_from([["cam0"], {"id": 1}, [], {}, [[1, 0], [0, 1]], [1, 2, 3]]),
)
_MARK = "__FUZZ_TOKEN__"


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path into a document (keys and indexes), the root included."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:4]):  # the first few items of big arrays suffice
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw: st.DrawFn, doc: Any) -> str:
    """``doc`` as JSON text with one to three places replaced, deleted or turned into raw tokens."""
    doc = copy.deepcopy(doc)
    tokens = []
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "token", "delete"]))
        if not path:
            if action == "replace":
                doc = draw(_json_leaf)
            continue
        parent = doc
        try:
            for key in path[:-1]:
                parent = parent[key]
        except (KeyError, IndexError, TypeError):
            continue
        if action == "delete" and isinstance(parent, dict):
            parent.pop(path[-1], None)
        elif action == "token":
            tokens.append(draw(st.sampled_from(_SPECIAL_TOKENS)))
            parent[path[-1]] = f"{_MARK}{len(tokens) - 1}"
        else:
            parent[path[-1]] = draw(_json_leaf)
    text = json.dumps(doc)
    for i, tok in enumerate(tokens):
        text = text.replace(f'"{_MARK}{i}"', tok)
    return text


def _reads_or_fglocerror(reader, path: Path) -> None:
    try:
        reader(path)
    except FglocError as exc:
        assert "\n" not in str(exc) and str(exc)


_READERS = {"survey": (read_survey, _SURVEY_DOC), "result": (read_result, _RESULT_DOC),
            "camera": (read_intrinsics, _CAMERA_DOC), "rig": (load_rig, _RIG_DOC)}


@pytest.mark.parametrize("name", sorted(_READERS))
@given(data=st.binary(max_size=300))
def test_any_bytes_parse_or_one_line_error(tmp_path_factory, name, data) -> None:
    path = tmp_path_factory.mktemp("b") / f"{name}.json"
    path.write_bytes(data)
    _reads_or_fglocerror(_READERS[name][0], path)


@pytest.mark.parametrize("name", sorted(_READERS))
@given(data=st.data())
def test_mutated_files_parse_or_one_line_error(tmp_path_factory, name, data) -> None:
    reader, doc = _READERS[name]
    path = tmp_path_factory.mktemp("m") / f"{name}.json"
    path.write_text(data.draw(mutated(doc)))
    _reads_or_fglocerror(reader, path)


def _journal_lines() -> list[str]:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        survey_to_journal(_SURVEY, Path(d) / "j.jsonl")
        return (Path(d) / "j.jsonl").read_text().splitlines()


_JOURNAL = _journal_lines()


@given(data=st.data())
def test_mutated_journals_parse_or_one_line_error(tmp_path_factory, data) -> None:
    lines = list(_JOURNAL)
    for _ in range(data.draw(st.integers(1, 2))):
        i = data.draw(st.integers(0, len(lines) - 1))
        lines[i] = data.draw(mutated(json.loads(lines[i]))).replace("\n", " ")
    if data.draw(st.booleans()):
        lines.append(data.draw(st.text(max_size=40)).replace("\n", " "))
    path = tmp_path_factory.mktemp("j") / "j.jsonl"
    path.write_text("\n".join(lines) + "\n")
    try:
        state = read_journal(path)
    except FglocError as exc:
        assert "\n" not in str(exc)
        return
    # Accepted: the survey it records is one fgloc solve accepts (the journal applies the survey contract).
    out = path.with_name("survey.json")
    write_survey(journal_mod.journal_to_survey(state), out)
    read_survey(out)


@given(data=st.binary(max_size=200))
def test_any_bytes_journal(tmp_path_factory, data) -> None:
    path = tmp_path_factory.mktemp("jb") / "j.jsonl"
    path.write_bytes(data)
    _reads_or_fglocerror(read_journal, path)


# ---- what fgloc writes it reads back identically -----------------------------------------

_angle = st.floats(-math.pi, math.pi, allow_nan=False)
_tilt = st.floats(-math.pi / 2, math.pi / 2, allow_nan=False)
_sigma = st.floats(1e-9, 1.0, allow_nan=False, exclude_min=False)
_coord = st.floats(-1e9, 1e9, allow_nan=False)
_ids = st.lists(st.text(min_size=1, max_size=6), min_size=2, max_size=5, unique=True)


@st.composite
def surveys(draw: st.DrawFn) -> Survey:
    cams = draw(_ids)
    nodes = draw(_ids)
    mode = draw(st.sampled_from(list(NodeMode)))
    obs = [Observation(camera=draw(st.sampled_from(cams)), node=draw(st.sampled_from(nodes)), pan=draw(_angle),
                       tilt=draw(_tilt), sigma=draw(st.none() | _sigma), subset=draw(st.none() | st.integers(0, 9)))
           for _ in range(draw(st.integers(0, 8)))]
    truth = None
    if draw(st.booleans()):
        truth = Truth(cameras={}, nodes={n: np.array([draw(_coord), draw(_coord),
                                                      0.0 if mode is NodeMode.PLANAR else draw(_coord)])
                                         for n in nodes})
    return Survey(mode=mode, gauge=Gauge(cams[0], cams[1]), sigma=draw(_sigma), camera_ids=cams, node_ids=nodes,
                  observations=obs, truth=truth)


@given(survey=surveys())
def test_written_surveys_read_back_identically(tmp_path_factory, survey) -> None:
    path = tmp_path_factory.mktemp("rt") / "s.json"
    write_survey(survey, path)
    assert survey_to_json(read_survey(path)) == survey_to_json(survey)


@given(survey=surveys())
def test_journal_written_surveys_read_back(tmp_path_factory, survey) -> None:
    """survey -> journal -> survey.json -> read_survey: accepted, same readings (canonical order)."""
    d = tmp_path_factory.mktemp("jr")
    survey_to_journal(survey, d / "j.jsonl")
    back = journal_mod.journal_to_survey(read_journal(d / "j.jsonl"))
    write_survey(back, d / "s.json")
    again = read_survey(d / "s.json")
    key = lambda o: (o.camera, o.node, o.pan, o.tilt, o.sigma)  # noqa: E731 (subset is not journaled)
    assert sorted(map(key, again.observations)) == sorted(map(key, survey.observations))


@given(fx=st.floats(1.0, 1e5), fy=st.floats(1.0, 1e5), w=st.integers(1, 10000), h=st.integers(1, 10000),
       k1=st.floats(-10, 10), zoom=st.floats(0, 1), data=st.data())
def test_written_intrinsics_read_back_identically(tmp_path_factory, fx, fy, w, h, k1, zoom, data) -> None:
    cx = data.draw(st.floats(-0.5, w - 0.5))
    cy = data.draw(st.floats(-0.5, h - 0.5))
    intr = CameraIntrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h, k1=k1, zoom=zoom)
    path = tmp_path_factory.mktemp("c") / "c.json"
    write_intrinsics(intr, path)
    assert intrinsics_to_json(read_intrinsics(path)) == intrinsics_to_json(intr)


@given(scale=st.floats(1e-12, 1e3), shear=st.floats(-0.99, 0.99), pos=st.lists(_coord, min_size=2, max_size=2))
def test_written_results_read_back_identically(tmp_path_factory, scale, shear, pos) -> None:
    doc = copy.deepcopy(_RESULT_DOC)
    n = next(iter(doc["nodes"]))
    doc["nodes"][n] = {"position": [*pos, 0.0], "covariance": [[scale, shear * scale], [shear * scale, scale]]}
    path = tmp_path_factory.mktemp("r") / "r.json"
    path.write_text(json.dumps(doc))
    result = read_result(path)
    write_result(result, path)
    assert result_to_json(read_result(path)) == result_to_json(result)


# ---- fast predicates never accept what the schema rejects -------------------------------

_bad_number_tokens = st.sampled_from(["NaN", "1e400", "9" * 400, "-1.6", "1.58", "-0.0", "0", "true", '"1"', "null"])
_field_value = st.one_of(_bad_number_tokens.map(lambda t: ("RAW", t)), st.floats(-2.0, 2.0), _json_leaf)


def _render(value: Any) -> str:
    """JSON text of ``value`` where ``("RAW", token)`` pairs become raw tokens (NaN, 1e400, ...)."""
    if isinstance(value, tuple):
        return value[1]
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k)}: {_render(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_render(v) for v in value) + "]"
    return json.dumps(value)


def _near(base: dict, keys: list[str]) -> st.SearchStrategy[Any]:
    """Items like ``base`` with a few fields replaced, removed or turned into odd tokens."""
    def change(edits: list[tuple[str, Any, bool]]) -> dict:
        item: dict[str, Any] = dict(base)
        for key, value, drop in edits:
            if drop:
                item.pop(key, None)
            else:
                item[key] = value
        return item
    return st.lists(st.tuples(st.sampled_from(keys), _field_value, st.booleans()), min_size=1, max_size=3).map(change)


_PREDICATES = {
    "survey observation": (survey_result._plain_observation, ("survey", "observation"),
                           _near({"camera": "c", "node": "n", "pan": 0.1, "tilt": -0.2},
                                 ["camera", "node", "pan", "tilt", "sigma", "subset"])),
    "journal observation": (journal_mod._plain_observation, ("journal", "observation"),
                            _near({"camera": "c", "node": "n", "index": 0, "pan": 0.1, "tilt": -0.2},
                                  ["camera", "node", "index", "pan", "tilt", "sigma"])),
    "result node": (survey_result._plain_node, ("result", "node"),
                    _near({"position": [0.1, 0.2, 0.0], "covariance": [[1e-6, 0.0], [0.0, 1e-6]]},
                          ["position", "covariance"])
                    | st.builds(lambda p, c: {"position": p, "covariance": c},
                                st.lists(_field_value, min_size=2, max_size=4),
                                st.lists(st.lists(_field_value, min_size=1, max_size=4), min_size=1, max_size=4))),
    "vector3": (is_vector3, ("survey", "vector3"), st.lists(_field_value | _coord, min_size=2, max_size=4)),
}


@pytest.mark.parametrize("name", sorted(_PREDICATES))
@settings(max_examples=10 * settings.default.max_examples)  # cheap: 10x the profile's count
@given(data=st.data())
def test_fast_predicates_are_no_laxer_than_the_schemas(name, data) -> None:
    """Whatever a reader's fast predicate pre-accepts, the schema accepts too."""
    predicate, (schema, definition), items = _PREDICATES[name]
    item = parse_json(_render(data.draw(items)))  # the item as the reader sees it
    if predicate(item):
        assert _validator(schema, definition).is_valid(item), item


def test_the_predicate_check_can_fail(monkeypatch) -> None:
    """A predicate that forgets the tilt range is caught by the property above."""
    lax = lambda o: type(o) is dict and set(o) >= {"camera", "node", "pan", "tilt"}  # noqa: E731
    item = parse_json('{"camera": "c", "node": "n", "pan": 0.1, "tilt": 1.58}')
    assert lax(item) and not _validator("survey", "observation").is_valid(item)


# ---- the CLI entry points ------------------------------------------------------------------

@given(data=st.data())
def test_cli_solve_and_score_end_in_a_result_or_one_line(tmp_path_factory, capsys, data) -> None:
    d = tmp_path_factory.mktemp("cli")
    s_path, r_path = d / "s.json", d / "r.json"
    s_path.write_text(data.draw(mutated(_SURVEY_DOC)))
    r_path.write_text(data.draw(mutated(_RESULT_DOC)))
    command = data.draw(st.sampled_from(["solve", "score", "view"]))
    argv = {"solve": ["solve", str(s_path), "-o", str(d / "out.json")],
            "score": ["score", str(s_path), str(r_path),
                      f"--baseline-m={data.draw(st.sampled_from(['100', '0', '-1', 'nan', 'inf', '1e308']))}"],
            "view": ["view", str(r_path), "--survey", str(s_path), "--save", str(d / "v.rrd")]}[command]
    status = main(argv)
    err = capsys.readouterr().err
    assert status in (0, 2, 3), err
    if status == 2:
        assert err.count("\n") == 1 and err.startswith("fgloc: error: "), err


@given(flag=st.sampled_from(["--nodes", "--sigma-deg", "--roll-pitch-deg", "--repeats", "--seed"]),
       value=st.sampled_from(["-1", "0", "nan", "inf", "-inf", "1e308", "3", "-0.5", "91"]))
def test_cli_simulate_flags(tmp_path_factory, capsys, flag, value) -> None:
    out = tmp_path_factory.mktemp("sim") / "s.json"
    try:
        status = main(["simulate", "-o", str(out), "--nodes", "5", flag, value])
    except SystemExit as exc:  # argparse: an int flag given a float is a usage error (exit 2)
        status = int(exc.code or 0)
    err = capsys.readouterr().err
    assert status in (0, 2), err
    if status == 0:
        read_survey(out)
