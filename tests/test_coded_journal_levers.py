"""The journal remembers the coded survey's levers (fgloc/survey/coded_levers.py, "Resume rule"),
and the JSON Schemas know them (journal header ``coded``, the ``view`` record's lever fields,
rig.json ``"coded"``).

* A new survey's header records the levers it ran with (the measured fastest by default).
* A resume runs with the recorded levers, even when the defaults or rig.json changed since.
* A journal written before the levers were recorded (no ``coded`` in its header) resumes with
  the old defaults (burst, zoom, blobs, frames, probe off, pairs off): exactly as before.
* A file or flag value that disagrees with the journal is refused in one line, exit 2, and the
  journal is left as it was.
"""

from __future__ import annotations

import copy
import json
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

import fgloc.survey.coded_levers as coded_module
from fgloc.camera.blink_codes import code_book
from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.core.model import Gauge, NodeMode
from fgloc.files.journal import JournalError, JournalHeader, JournalState, read_journal
from fgloc.files.json_io import check
from fgloc.files.rig_config import RigConfigError, parse_rig
from fgloc.survey.coded import CodedSettings
from fgloc.survey.coded_levers import CHOICES, LEGACY, LEGACY_LEVELS, coded_settings, settings_record
from fgloc.survey.session import run_survey
from tests.test_survey_coded import EXAMPLE, clean_cuts, coded_rig, levels_rig, opened, parsed, view_records

NEW_DEFAULTS = {"retry": "continue", "separate": "zoom", "fallback": "round", "video": "frames", "probe": "on",
                "pairs": "groups", "rounds": "short", "round_order": "view", "ladder": "focus", "decode": "fit", "length": "adaptive",
                "explain": "crowds", "looks": "epipolar", "searches": "paired", "covers": "searched",
                "first_window": "kept", "zoom_moves": "together", "retries_at": "wide",
                "tiling": "minimal"}


def lines_of(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def obs(path: Path) -> dict:
    return {k: (o.pan, o.tilt, o.view) for k, o in read_journal(path).observations.items()}


def cut_before_refinement(lines: list[bytes]) -> int:
    """A record index k: a kill just before it (lines[:k]) falls before a refinement view's
    first recording and separates no recording from its continuation, with views still to do."""
    records = [json.loads(x) for x in lines]
    clean = clean_cuts(records)
    starts = [k for k, r in enumerate(records) if r["type"] == "view" and r["view"].startswith("r")
              and r["attempt"] == 0 and k in clean]
    assert starts, "the scene should need refinement"
    return starts[len(starts) // 2]


def resumed_views(path: Path, kept: int) -> list[dict]:
    """The view records a resume appended after the first ``kept`` lines."""
    return [r for r in map(json.loads, lines_of(path)[kept:]) if r["type"] == "view"]


def test_a_new_survey_records_the_measured_fastest_levers(tmp_path):
    rig = parsed(coded_rig(8, width=160))
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    header = read_journal(tmp_path / "journal.jsonl").header
    assert header.coded == NEW_DEFAULTS | {"levels": [2 / 9, 5 / 9, 1.0]}  # 3x, 6x, then 10x
    assert header.coded == settings_record(CodedSettings())
    recs = view_records(tmp_path / "journal.jsonl")
    assert all(r["probe"] == code_book(8).length + 2 for r in recs if r["attempt"] == 0)  # probe on by default


def test_an_old_journal_resumes_with_the_old_defaults(tmp_path, monkeypatch):
    """An old writer's journal (header without ``coded``) of a rig without a ``coded`` block:
    cut before a refinement view and resumed with today's defaults in force, it goes on with
    bursts, no probe, no pairs, the blob fallback and the old zoom ladder, and ends with exactly
    the readings the old survey takes uninterrupted."""
    rig = parsed(coded_rig(12, width=160))
    full = tmp_path / "full"
    with monkeypatch.context() as m:  # the survey as the old defaults ran it, on the old ladder
        m.setattr(coded_module, "CodedSettings", OldLadder)
        run_survey(rig, full, opened=opened(rig)[0], coded_levers=LEGACY)
    lines = lines_of(full / "journal.jsonl")
    header = json.loads(lines[0])
    assert header["coded"]["probe"] == "off"
    del header["coded"]  # the old writer's header: the same record without the levers
    lines[0] = (json.dumps(header, separators=(",", ":")) + "\n").encode()
    uncut = tmp_path / "uncut.jsonl"
    uncut.write_bytes(b"".join(lines))
    assert read_journal(uncut).header.coded is None
    cut = cut_before_refinement(lines)
    d = tmp_path / "cut"
    d.mkdir()
    (d / "journal.jsonl").write_bytes(b"".join(lines[:cut]) + lines[cut][:9])  # killed mid-view
    run_survey(rig, d, resume=True, opened=opened(rig)[0])
    state = read_journal(d / "journal.jsonl")
    assert state.header.coded is None and state.duplicates_ignored == 0
    assert obs(d / "journal.jsonl") == obs(uncut)
    again = resumed_views(d / "journal.jsonl", cut)
    assert again and all("probe" not in r and not r.get("continued") for r in again)
    assert all(r["frames"] == 3 * code_book(12).length + 2 for r in again)  # every recording a full burst
    assert not any("partner" in x for r in again for x in r["readings"])


@dataclass(frozen=True)
class OldLadder(CodedSettings):
    """CodedSettings as before the two-rung ladder became the default."""

    levels: tuple[float, ...] = LEGACY_LEVELS


@dataclass(frozen=True)
class OtherDefaults(CodedSettings):
    """CodedSettings as if a later release had changed every lever's default."""

    retry: str = "burst"
    fallback: str = "blobs"
    probe: str = "off"
    pairs: str = "off"


def test_a_new_journal_resumes_with_its_levers_when_the_defaults_change(tmp_path, monkeypatch):
    rig = parsed(levels_rig(12, width=160))
    full = tmp_path / "full"
    run_survey(rig, full, opened=opened(rig)[0])
    lines = lines_of(full / "journal.jsonl")
    cut = cut_before_refinement(lines)
    d = tmp_path / "cut"
    d.mkdir()
    (d / "journal.jsonl").write_bytes(b"".join(lines[:cut]))
    monkeypatch.setattr(coded_module, "CodedSettings", OtherDefaults)
    assert coded_settings(rig).probe == "off"  # a new survey would now run without the probe
    run_survey(rig, d, resume=True, opened=opened(rig)[0])
    assert obs(d / "journal.jsonl") == obs(full / "journal.jsonl")
    again = resumed_views(d / "journal.jsonl", cut)
    assert again and all("probe" in r for r in again if r["attempt"] == 0)


def test_a_new_journal_resumes_with_its_levers_when_rig_json_drops_them(tmp_path):
    """Started with rig.json's old levers, resumed after the ``coded`` block was removed from
    rig.json (an operational change, journaled): the survey goes on with the recorded levers."""
    data = coded_rig(12, width=160)
    data["coded"] = dict(LEGACY)
    rig = parsed(data)
    full = tmp_path / "full"
    run_survey(rig, full, opened=opened(rig)[0])
    lines = lines_of(full / "journal.jsonl")
    cut = cut_before_refinement(lines)
    d = tmp_path / "cut"
    d.mkdir()
    (d / "journal.jsonl").write_bytes(b"".join(lines[:cut]))
    bare = parsed(coded_rig(12, width=160))
    run_survey(bare, d, resume=True, opened=opened(bare)[0])
    state = read_journal(d / "journal.jsonl")
    assert [c["changed"] for c in state.rig_changes] == [[f"coded.{k}" for k in LEGACY]]
    assert obs(d / "journal.jsonl") == obs(full / "journal.jsonl")
    assert all("probe" not in r for r in resumed_views(d / "journal.jsonl", cut))


@pytest.mark.parametrize(("flag", "file", "named"), [
    (["--coded", "retry=burst"], None, "--coded: retry"),
    (["--coded", "pairs=off"], None, "--coded: pairs"),
    ([], {"probe": "off"}, "rig.json: coded.probe"),
    ([], {"levels": [0.5, 1.0]}, "rig.json: coded.levels"),
])
def test_a_lever_that_disagrees_with_the_journal_is_refused_in_one_line(tmp_path, capsys, flag, file, named):
    data = coded_rig(6, width=160, identification="coded")
    rig_json = tmp_path / "rig.json"
    rig_json.write_text(json.dumps(data))
    args = ["survey", "--rig", str(rig_json), "-o", str(tmp_path / "o"), "--simulate", "--quiet"]
    journal = tmp_path / "o" / "journal.jsonl"
    assert main(args) == 0
    lines = lines_of(journal)
    (tmp_path / "o" / "journal.jsonl").write_bytes(b"".join(lines[:len(lines) // 2]))  # killed half way
    before = journal.read_bytes()
    capsys.readouterr()
    if file is not None:
        rig_json.write_text(json.dumps(data | {"coded": file}))
    assert main(args + ["--resume"] + flag) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    key = named.rsplit(" ", 1)[-1].split(".")[-1]
    was = json.dumps(settings_record(CodedSettings())[key]).replace('"', "'")
    now = flag[1].split("=")[1] if flag else json.dumps(file[key])
    assert named in err[0] and str(journal) in err[0] and was in err[0] and now.strip('"') in err[0], err
    assert journal.read_bytes() == before  # nothing written
    # the same values the journal recorded, given explicitly, are no disagreement
    rig_json.write_text(json.dumps(data | {"coded": {"probe": "on", "levels": [2 / 9, 5 / 9, 1.0]}}))
    assert main(args + ["--resume", "--coded", "retry=continue"]) == 0


def test_an_old_journal_takes_rig_json_and_flag_levers_as_before():
    """Without recorded levers the old rule holds: old defaults, rig.json, then the flags."""
    rig = parsed(coded_rig(4, width=160) | {"coded": {"probe": "on"}})
    old = read_journal_header_only(coded=None)
    s = coded_settings(rig, {"pairs": "on"}, old)
    assert {k: getattr(s, k) for k in CHOICES} == LEGACY | {"probe": "on", "pairs": "on"}
    assert s.levels == LEGACY_LEVELS == (1 / 9, 3 / 9, 1.0) != CodedSettings().levels  # the ladder it climbed
    no_ladder = read_journal_header_only(coded=dict(NEW_DEFAULTS))  # levers recorded, the ladder not
    assert coded_settings(parsed(coded_rig(4, width=160)), None, no_ladder).levels == LEGACY_LEVELS
    recorded = read_journal_header_only(coded=NEW_DEFAULTS | {"levels": [0.5, 1.0]})
    s = coded_settings(parsed(coded_rig(4, width=160)), None, recorded)
    assert {k: getattr(s, k) for k in CHOICES} == NEW_DEFAULTS and s.levels == (0.5, 1.0)
    with pytest.raises(FglocError, match=r"--coded: video: j\.jsonl was started with video 'frames', got 'fields'"):
        coded_settings(parsed(coded_rig(4, width=160)), {"video": "fields"}, recorded, "j.jsonl")


def read_journal_header_only(coded: dict | None):
    """A journal state whose header records ``coded`` (None: an old writer's header)."""
    return JournalState(JournalHeader(NodeMode.PLANAR, Gauge("cam0", "cam1"), 0.001, ["cam0", "cam1"], ["n0"],
                                      coded=coded))


# ----- schemas
@pytest.fixture(scope="module")
def every_lever_journal(tmp_path_factory) -> list[dict]:
    """The records of a real coded survey whose journal holds every lever field: default levers
    plus radio separation (16 motes: continuations, probes, pair readings, short rounds)."""
    out = tmp_path_factory.mktemp("levers")
    data = coded_rig(16, width=160, seed=2)  # a scene with a continued recording (seed 1 needs none since pair decoding reads neighbours)
    # the level decoder's misses give it its retries; the greedy wide views, a continued recording
    data["coded"] = {"separate": "radio", "decode": "levels", "tiling": "greedy"}
    rig = parsed(data)
    run_survey(rig, out, opened=opened(rig)[0])
    return [json.loads(x) for x in lines_of(out / "journal.jsonl")]


def test_a_real_coded_journal_with_every_lever_field_validates(every_lever_journal, tmp_path):
    records = every_lever_journal
    views = [r for r in records if r["type"] == "view"]
    present = {k for r in views for k in ("continued", "probe", "round", "lit", "candidates") if k in r}
    present |= {"partner" for r in views for x in r["readings"] if "partner" in x}
    assert present == {"continued", "probe", "round", "lit", "candidates", "partner"}
    assert set(records[0]["coded"]) == {*CHOICES, "levels"} and records[0]["coded"]["separate"] == "radio"
    for r in records:
        kind = r["type"]
        if kind in ("header", "view", "observation", "truth", "field_time"):
            check(r, "journal", "journal", JournalError, definition=kind, root=kind)


@pytest.mark.parametrize(("where", "value", "problem"), [
    (("header", "coded", "retry"), "again", "header.coded.retry: expected one of burst, continue, got 'again'"),
    (("header", "coded", "pairs"), True, "header.coded.pairs: expected one of off, on, groups"),
    (("header", "coded", "levels"), [0.0, 1.0], "header.coded.levels[0]: expected a zoom in (0, 1], got 0.0"),
    (("header", "coded", "video"), None, "header.coded.video: missing required field"),
    (("view", "continued"), False, "view.continued: expected true, got false"),
    (("view", "probe"), "yes", "view.probe: expected an integer >= 1"),
    (("view", "round"), -1, "view.round: expected an integer >= 0"),
    (("view", "lit"), [""], "view.lit[0]: expected a non-empty string id"),
    (("view", "readings", "partner"), 1.5, "partner: expected an integer >= 0"),
])
def test_a_bad_lever_value_fails_validation(every_lever_journal, tmp_path, where, value, problem):
    records = copy.deepcopy(every_lever_journal)
    kind, *path = where
    if kind == "header":
        target = records[0]
    else:
        key = "partner" if "partner" in path else path[0]
        target = next(r for r in records if r["type"] == "view" and (
            key in r or any(key in x for x in r["readings"])))
        if path[0] == "readings":
            target = next(x for x in target["readings"] if "partner" in x)
            path = path[1:]
    for k in path[:-1]:
        target = target[k]
    if value is None:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    journal = tmp_path / "journal.jsonl"
    journal.write_text("".join(json.dumps(r) + "\n" for r in records))
    with pytest.raises(JournalError) as info:
        read_journal(journal)
    message = str(info.value)
    assert "\n" not in message and problem in message, message


def test_rig_json_with_every_lever_validates_and_a_bad_value_fails():
    data = json.loads(EXAMPLE.read_text())
    data["coded"] = {"retry": "burst", "separate": "radio", "fallback": "blobs", "video": "fields", "probe": "off",
                     "pairs": "off", "rounds": "full", "round_order": "class", "ladder": "climb",
                     "levels": [0.25, 0.5, 1.0]}
    check(data, "rig", "rig.json", RigConfigError)
    parse_rig(data, str(EXAMPLE), EXAMPLE.parent)
    for key, bad, problem in (("retry", "again", "coded.retry: expected one of burst, continue, got 'again'"),
                              ("probe", "yes", "coded.probe: expected one of off, on, got 'yes'"),
                              ("levels", [0.5, 1.5], "coded.levels[1]: expected a zoom in (0, 1], got 1.5"),
                              ("levels", [], "coded.levels: expected ascending zooms")):
        wrong = data | {"coded": data["coded"] | {key: bad}}
        with pytest.raises(RigConfigError, match=re.escape(problem)):
            check(wrong, "rig", "rig.json", RigConfigError)
