"""The ``tiling`` lever (fgloc/survey/view_planner.py ``fewest_views``; docs/blink-codes.md
"The fewest views").

* On the 640 x 480 rig of scripts/coded_survey.py (100 motes, seed 3, fields) the greedy cover
  records six wide views per camera; ``"minimal"`` records four, covers each camera's search box
  all the same, and still reads every visible pair once, none mislabelled.
* A journal whose header predates the lever resumes with ``"greedy"`` (the views it planned);
  the lever is schema-checked.
"""

from __future__ import annotations

import numpy as np

from tests.test_survey_coded import check_lever_in_schema, resumed_and_new, view_records
from tests.test_survey_coded_levers import survey_reads_every_visible_pair


def test_minimal_tiling_records_fewer_wide_views_and_reads_every_visible_pair(tmp_path):
    from fgloc.survey.coded_settings import CodedSettings
    from fgloc.survey.view_planner import box_targets, coverage
    from tests.conftest import load_script

    rig_for = load_script("coded_survey").rig_for
    wide: dict[str, dict[str, list[tuple[float, float]]]] = {}
    for tiling in ("greedy", "minimal"):
        rig = rig_for(3, 100, 640, "coded", 502, 0.0, {"video": "fields", "tiling": tiling}, True)
        survey_reads_every_visible_pair(rig, tmp_path / tiling)
        recs = view_records(tmp_path / tiling / "journal.jsonl")
        wide[tiling] = {c: [tuple(r["target"]) for r in recs if r["camera"] == c and r["view"][0] == "w"
                            and r["attempt"] == 0] for c in rig.camera_ids}
    for c in rig.camera_ids:
        assert len(wide["minimal"][c]) < len(wide["greedy"][c]), (c, wide)
        s, intr = rig.search_for(c), rig.cameras[rig.camera_ids.index(c)].intrinsics
        knobs = CodedSettings()
        targets = box_targets(s.pan_min, s.pan_max, s.tilt_min, s.tilt_max,
                              knobs.target_step * knobs.margin_px / max(intr.fx, intr.fy))
        assert coverage(intr, targets, np.array(wide["minimal"][c]), knobs.margin_px - 1.0).any(axis=0).all()


def test_a_header_without_the_tiling_lever_resumes_with_greedy() -> None:
    assert resumed_and_new("tiling") == ("greedy", "minimal")  # old, new
    assert resumed_and_new("tiling", tiling="minimal")[0] == "minimal"  # a journal that recorded it


def test_the_tiling_lever_is_schema_checked() -> None:
    check_lever_in_schema("tiling", "minimal", "optimal")
