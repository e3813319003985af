"""The survey's repeat phase (fgloc.survey.repeats) against the in-process simulated rig."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.evaluate.crlb import cramer_rao_bound
from fgloc.files.journal import read_journal
from fgloc.files.rig_config import parse_rig, rig_meaning, rig_operational
from fgloc.plan.repeat import plan_repeats
from fgloc.solve.joint import solve_survey
from fgloc.survey.repeats import base_survey
from fgloc.survey.session import journal_survey, run_survey
from tests.test_rig_config import EXAMPLE
from tests.test_survey_runner import obs_by_key, opened, resume_from_cuts

BUDGET = 8


def repeat_rig(n_nodes: int = 12, budget: int = BUDGET, repeats: int = 1, **top):
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": 3, "heights": [0.1, 0.12], "occlusion": 0.1, "dead_nodes": ["n003"]}
    data["retry"] = {"backoff_s": 0.0}
    data["repeats"] = repeats
    data["repeat_budget"] = budget
    data.update(top)
    return parse_rig(data, str(EXAMPLE), EXAMPLE.parent)


def crb_trace(survey) -> float:
    return float(sum(np.trace(c) for c in cramer_rao_bound(survey).values()))


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """One uninterrupted survey with a repeat budget, and its journal."""
    rig = repeat_rig()
    d = tmp_path_factory.mktemp("full")
    run_survey(rig, d, opened=opened(rig)[0])
    return rig, d


@pytest.mark.parametrize("repeats", [1, 2])
def test_budget_is_spent_exactly_on_the_planners_choices(tmp_path, repeats):
    rig = repeat_rig(repeats=repeats)
    run_survey(rig, tmp_path, opened=opened(rig)[0])
    state = read_journal(tmp_path / "journal.jsonl")
    extra = [o for o in state.observations.values() if o.index >= repeats]
    assert len(extra) == BUDGET
    base = base_survey(state, repeats)
    assert len(base.observations) == len(state.observations) - BUDGET
    plan = plan_repeats(base, solve_survey(base), BUDGET, "mean")
    assert Counter((o.camera, o.node) for o in extra) == Counter((r.camera, r.node) for r in plan.readings)
    # The k-th repeat of a pair has index repeats + k: no gaps, no collisions with the node loop.
    for (c, n), k in Counter((o.camera, o.node) for o in extra).items():
        assert sorted(o.index for o in state.observations_of(n, c)) == list(range(repeats + k))
    # A repeat is an ordinary reading of its pair: the same LED measured by the same camera.
    for o in extra:
        first = state.observations[(o.node, o.camera, 0)]
        assert abs(o.pan - first.pan) < 1e-3 and abs(o.tilt - first.tilt) < 1e-3


def test_repeats_shrink_the_cramer_rao_trace_more_than_unplanned_ones(full_run):
    rig, d = full_run
    state = read_journal(d / "journal.jsonl")
    base, final = base_survey(state, rig.repeats), journal_survey(d)
    t_base, t_final = crb_trace(base), crb_trace(final)
    assert t_final < t_base
    # Unplanned: the same number of repeats spread over the first pairs in canonical order.
    naive = replace(base, observations=base.observations + base.observations[:BUDGET])
    assert t_base - t_final > t_base - crb_trace(naive)


def test_kill_and_resume_during_the_repeat_phase_gives_the_same_readings(full_run, tmp_path):
    rig, full = full_run
    data = (full / "journal.jsonl").read_bytes()
    ends = [i + 1 for i, b in enumerate(data) if b == ord("\n")]
    lines = data.splitlines()
    last_done = max(k for k, line in enumerate(lines) if b'"node_done"' in line)
    repeat_ends = ends[last_done:]  # cut after the last node_done and after every repeat record
    assert len(repeat_ends) >= BUDGET + 1
    resume_from_cuts(rig, data, repeat_ends, tmp_path)  # clean cuts and torn last lines


def test_repeat_budget_is_operational_and_a_larger_budget_extends_the_plan(tmp_path):
    small, large = repeat_rig(budget=3), repeat_rig(budget=BUDGET)
    assert "repeat_budget" in rig_operational(large) and "repeat_budget" not in rig_meaning(large)
    ref = tmp_path / "ref"
    run_survey(large, ref, opened=opened(large)[0])
    d = tmp_path / "grown"
    run_survey(small, d, opened=opened(small)[0])
    assert sum(1 for o in read_journal(d / "journal.jsonl").observations.values() if o.index >= 1) == 3
    run_survey(large, d, resume=True, opened=opened(large)[0])  # accepted, journaled as rig_changed
    state = read_journal(d / "journal.jsonl")
    assert [c["changed"] for c in state.rig_changes] == [["repeat_budget"]]
    assert obs_by_key(d / "journal.jsonl") == obs_by_key(ref / "journal.jsonl")


def test_repeat_budget_is_checked():
    with pytest.raises(FglocError, match=r"repeat_budget: .*planar"):
        repeat_rig(nodes="3d")
    with pytest.raises(FglocError, match=r"repeat_budget"):
        repeat_rig(budget=-1)
    assert repeat_rig(budget=0).repeat_budget == 0


def test_a_repeat_phase_killed_after_a_nodes_last_repeat_leaves_no_led_lit(full_run, tmp_path):
    """Killed after the last repeat reading of a node, before its LED went off: the resume has
    nothing left to take of that node, and switches its LED off before the next one (the rig's
    LED state survives the kill here, as a real mote's does)."""
    rig, full = full_run
    lines = (full / "journal.jsonl").read_text().splitlines()
    repeats = [(k, json.loads(line)["node"]) for k, line in enumerate(lines)
               if '"observation"' in line and json.loads(line)["index"] >= rig.repeats]
    # the first repeat node that another repeat node follows: cut after its last reading
    k, node = next((k, n) for (k, n), (_k2, n2) in zip(repeats, repeats[1:], strict=False) if n2 != n)
    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "journal.jsonl").write_text("\n".join(lines[:k + 1]) + "\n")
    rig_opened, sim = opened(rig)
    sim.leds.set_led(node, True)  # what the killed process left on
    run_survey(rig, tmp_path / "cut", opened=rig_opened, resume=True)
    assert not sim.scene.lit
    assert obs_by_key(tmp_path / "cut" / "journal.jsonl") == obs_by_key(full / "journal.jsonl")
