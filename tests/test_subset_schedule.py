"""Subset schedules, the re-measuring simulator and the ``subset`` observation field."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.errors import FileFormatError
from fgloc.core.subsets import draw_subsets, subsets_for_coverage
from fgloc.files.survey_result import read_survey, write_survey
from fgloc.sim.scenes import PaperScenario, paper_scenario


def test_draw_subsets_distinct_and_even() -> None:
    """Subsets hold k distinct nodes and cover nodes evenly (T k = 4 N: each node 4 times)."""
    subsets = draw_subsets(100, 10, 40, np.random.default_rng(0))
    assert all(len(set(s.tolist())) == 10 for s in subsets)
    counts = Counter(int(j) for s in subsets for j in s)
    assert set(counts.values()) == {4} and len(counts) == 100
    assert subsets_for_coverage(100, 5, 5) == 100


def test_simulator_remeasures_each_subset() -> None:
    """Each subset's nodes are read afresh by both cameras (repeats times), tagged with
    the subset; a node in two subsets gets independent readings in each."""
    sv = paper_scenario(PaperScenario(n_nodes=30, seed=1, repeats=2, subset_schedule=(6, 10)))
    tags = Counter(o.subset for o in sv.observations)
    assert set(tags) == set(range(10)) and set(tags.values()) == {6 * 2 * 2}
    by_subset: dict[int, set[str]] = {}
    for o in sv.observations:
        by_subset.setdefault(o.subset, set()).add(o.node)
    assert all(len(v) == 6 for v in by_subset.values())
    node = sorted(by_subset[0])[0]
    readings = [(o.pan, o.tilt) for o in sv.observations if o.node == node and o.camera == "cam0"]
    assert len(set(readings)) == len(readings)  # fresh noise every time


def test_subset_field_roundtrip_and_validation(tmp_path) -> None:
    """``subset`` is written and read back; untagged files read as None; a bad value
    is one clear error naming file and field."""
    sv = paper_scenario(PaperScenario(n_nodes=5, seed=2, subset_schedule=(3, 2)))
    path = tmp_path / "s.json"
    write_survey(sv, path)
    back = read_survey(path)
    assert [o.subset for o in back.observations] == [o.subset for o in sv.observations]
    data = json.loads(path.read_text())
    for o in data["observations"]:
        o.pop("subset")
    path.write_text(json.dumps(data))
    assert all(o.subset is None for o in read_survey(path).observations)
    data["observations"][1]["subset"] = -2
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match=r"observations\[1\]\.subset: expected a non-negative integer"):
        read_survey(path)


def test_cli_simulate_schedule_and_solve_baseline(tmp_path, capsys) -> None:
    """``fgloc simulate --subset-schedule`` then ``fgloc solve --method subset-newton``."""
    s, r = tmp_path / "s.json", tmp_path / "r.json"
    assert main(["simulate", "-o", str(s), "--nodes", "20", "--subset-schedule", "10", "6", "--seed", "3"]) == 0
    assert main(["solve", str(s), "-o", str(r), "--method", "subset-newton"]) == 0
    out = json.loads(r.read_text())
    assert out["solver"]["method"] == "subset-newton"
    assert len(out["nodes"]) + len(out["unlocalized"]) == 20
    assert main(["simulate", "-o", str(s), "--nodes", "20", "--subset-schedule", "30", "2"]) == 2
    assert "--subset-schedule" in capsys.readouterr().err
