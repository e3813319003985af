"""The ``retries_at`` lever (fgloc/survey/coded_ladder.py ``may_record_again``; docs/blink-codes.md
"Second recordings only up to the first rung").

* ``"first_rung"`` lets the wide pass, the radio rounds and the first refinement rung's tiles be
  recorded a second time, not a higher rung's tiles nor the fallback round's views; ``"all"``
  every view; ``"wide"`` the wide pass and the radio rounds only.
* On the 640 x 480 rig of scripts/coded_survey.py (200 motes, seed 2, fields) ``"all"`` records a
  6x tile twice; ``"first_rung"`` does not, records fewer frames above the first rung, and still
  reads every visible pair once, none mislabelled; ``"wide"`` (the default) records no refinement
  tile or round view twice and reads every visible pair once.
* A journal whose header predates the lever resumes with ``"all"``; the lever is schema-checked.
"""

from __future__ import annotations

import pytest

from fgloc.survey.coded_ladder import may_record_again
from tests.test_survey_coded import check_lever_in_schema, resumed_and_new, view_records
from tests.test_survey_coded_levers import survey_reads_every_visible_pair


@pytest.mark.parametrize(("view", "first_rung"), [
    ("w000", True), ("w017", True),  # the wide pass
    ("s0-000", True), ("s1-v002", True),  # radio rounds, class- and view-major
    ("r1-000", True), ("r1-014", True),  # the first refinement rung
    ("r2-000", False), ("r3-004", False),  # higher rungs
    ("f000", False), ("f003", False),  # the fallback round
])
def test_only_views_up_to_the_first_rung_are_recorded_again(view: str, first_rung: bool) -> None:
    assert may_record_again(view, "first_rung") is first_rung
    assert may_record_again(view, "wide") is (view[0] in "ws")
    assert may_record_again(view, "all")


def _above_first_rung(view: str) -> bool:
    return view.startswith("f") or (view.startswith("r") and not view.startswith("r1-"))


def test_first_rung_records_no_higher_view_twice_and_reads_every_visible_pair(tmp_path):
    from tests.conftest import load_script

    rig_for = load_script("coded_survey").rig_for
    again, frames = {}, {}
    for retries_at in ("all", "first_rung", "wide"):
        # tiling "greedy": with the fewest tiles no view above the first rung is recorded twice here
        rig = rig_for(2, 200, 640, "coded", 502, 0.0, {"video": "fields", "retries_at": retries_at, "tiling": "greedy"},
                      True)
        survey_reads_every_visible_pair(rig, tmp_path / retries_at)
        recs = view_records(tmp_path / retries_at / "journal.jsonl")
        again[retries_at] = [r["view"] for r in recs if r["attempt"] == 1 and _above_first_rung(r["view"])]
        frames[retries_at] = sum(r["frames"] for r in recs if _above_first_rung(r["view"]))
    assert again["all"], "the scene should record a view above the first rung twice"
    assert again["first_rung"] == []
    assert frames["first_rung"] < frames["all"], frames
    # the default: no refinement tile nor round view recorded twice
    recs = view_records(tmp_path / "wide" / "journal.jsonl")
    assert not [r["view"] for r in recs if r["attempt"] == 1 and r["view"][0] in "rf"]


def test_a_header_without_the_retries_at_lever_resumes_with_all() -> None:
    assert resumed_and_new("retries_at") == ("all", "wide")  # old, new


def test_the_retries_at_lever_is_schema_checked() -> None:
    check_lever_in_schema("retries_at", "all", "everywhere")
