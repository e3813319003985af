"""The coded fallback's LEDs: motes no camera placed are searched together, all lit at once,
one look per camera (``fgloc.survey.coded_fallback.search_unplaced_together`` on
``SurveyRunner.look_with_all_lit``); a search killed with its LED lit leaves none lit after
the resume."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import fgloc.survey.coded_fallback as coded_fallback
from fgloc.files.journal import read_journal
from fgloc.survey.runner import SurveyRunner
from fgloc.survey.session import run_survey
from tests.test_survey_coded import coded_rig, opened, parsed
from tests.test_survey_runner import resume_from_cuts, small_rig

GROUP_REASON = "lit at once"


def lamp_rig():
    """40 motes, 30 % of the (camera, mote) pairs occluded, rendered frames with static lights and
    on-off detection: three live motes (n001, n023, n026) are hidden from both cameras, and the
    lamps leave each camera blobs it cannot explain, so the fallback would search them there."""
    data = coded_rig(40, occlusion=0.3, seed=1, frames="rendered")
    data["search"] = dict(data.get("search", {}), detection="on-off")
    return parsed(data)


def hidden_from_both(rig, sim) -> set[str]:
    return {n for j, n in enumerate(rig.node_ids) if not sim.scene.visible[:, j].any()} - set(rig.simulation.dead_nodes)


def field_times(path, scope: str) -> list[dict]:
    return [r for r in map(json.loads, path.read_text().splitlines())
            if r["type"] == "field_time" and r.get("scope") == scope]


def test_motes_hidden_from_every_camera_are_searched_once_all_lit(tmp_path, monkeypatch) -> None:
    rig = lamp_rig()
    rig_opened, sim = opened(rig)
    hidden = hidden_from_both(rig, sim)
    assert len(hidden) == 3
    run_survey(rig, tmp_path / "group", opened=rig_opened)
    state = read_journal(tmp_path / "group" / "journal.jsonl")
    grouped = {key for key, reason in state.not_found.items() if GROUP_REASON in reason}
    assert grouped == {(n, c) for n in hidden for c in rig.camera_ids}
    assert not sim.scene.lit  # every LED the group lit is off again
    searched = {r["node"] for r in field_times(tmp_path / "group" / "journal.jsonl", "fallback_node")}
    assert not searched & hidden
    (group,) = field_times(tmp_path / "group" / "journal.jsonl", "fallback_group")

    # the same survey with each of them searched on its own: the same readings, the same misses,
    # and the three searches cost more than the one look of the group
    monkeypatch.setattr(coded_fallback, "search_unplaced_together", lambda coded, runner, pool, searches, silent: searches)
    run_survey(rig, tmp_path / "alone", opened=opened(rig)[0])
    alone = read_journal(tmp_path / "alone" / "journal.jsonl")
    assert alone.observations == state.observations
    assert set(alone.not_found) == set(state.not_found)
    one_by_one = [r for r in field_times(tmp_path / "alone" / "journal.jsonl", "fallback_node") if r["node"] in hidden]
    assert len(one_by_one) == 3
    assert group["total_s"] < sum(r["total_s"] for r in one_by_one)


def test_a_group_survey_killed_anywhere_around_the_group_resumes_to_the_same_journal(tmp_path) -> None:
    rig = lamp_rig()
    run_survey(rig, tmp_path / "full", opened=opened(rig)[0])
    data = (tmp_path / "full" / "journal.jsonl").read_bytes()
    lines = data.splitlines()
    ends = [0, *np.cumsum([len(line) + 1 for line in lines]).tolist()]
    grouped = [k for k, line in enumerate(lines) if GROUP_REASON.encode() in line]
    group_time = next(k for k, line in enumerate(lines) if b'"fallback_group"' in line)
    # before the group's first miss, between its misses, and after its price
    cuts = [grouped[0], grouped[len(grouped) // 2], group_time + 1]
    states = resume_from_cuts(rig, data, [int(ends[k]) for k in cuts], tmp_path)
    reference = read_journal(tmp_path / "full" / "journal.jsonl")
    for state in states:
        assert set(state.not_found) == set(reference.not_found)
        assert state.done == reference.done


@pytest.mark.parametrize("which", ["visible", "hidden"])
def test_look_with_all_lit_reports_the_cameras_that_saw_light(tmp_path, which: str) -> None:
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.survey.session import start_journal

    rig = small_rig(12, occlusion=0.4)
    sim = InProcessRig(rig)
    visible = sim.scene.visible
    cam0 = rig.camera_ids[0]
    if which == "visible":  # two motes in view of cam0
        nodes = [n for j, n in enumerate(rig.node_ids) if visible[0, j] and n != "n003"][:2]
    else:
        nodes = [n for j, n in enumerate(rig.node_ids) if not visible[0, j] and n != "n003"][:2]
    assert len(nodes) == 2
    journal, state = start_journal(rig, tmp_path, resume=False, simulated=sim)
    runner = SurveyRunner(rig, sim.open_head, sim.leds, journal, state)
    with ThreadPoolExecutor(max_workers=2) as pool:
        lit, seen = runner.look_with_all_lit(nodes, pool, {cam0: None})
    assert lit == nodes
    assert seen == ({cam0} if which == "visible" else set())
    assert not sim.scene.lit
    assert not read_journal(tmp_path / "journal.jsonl").not_found  # it journals nothing


def test_a_fallback_search_killed_after_its_last_reading_leaves_no_led_lit(tmp_path, monkeypatch) -> None:
    """Killed after a fallback search's last reading, before the LED went off: the resume finds
    the node read by every camera and switches its LED off before closing it (a field mote
    would otherwise stay lit through every later search). The rig's LED state survives the kill
    here, as a real mote's does."""
    from fgloc.survey.coded import CodedSurvey

    rig = parsed(coded_rig(12, width=160))
    hidden = "n005"  # its code forgotten: the fallback reads it the sequential way
    init = CodedSurvey.__init__

    def forgetting(self, *args, **kw):  # noqa: ANN001, ANN202
        init(self, *args, **kw)
        self.node_of_code = {k: n for k, n in self.node_of_code.items() if n != hidden}

    monkeypatch.setattr(CodedSurvey, "__init__", forgetting)
    run_survey(rig, tmp_path / "full", opened=opened(rig)[0])
    lines = (tmp_path / "full" / "journal.jsonl").read_text().splitlines()
    start = next(k for k, line in enumerate(lines) if '"node_started"' in line and f'"{hidden}"' in line)
    last = max(k for k, line in enumerate(lines) if '"observation"' in line and f'"{hidden}"' in line)
    assert last > start and '"node_done"' in lines[last + 1]
    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "journal.jsonl").write_text("\n".join(lines[:last + 1]) + "\n")

    rig_opened, sim = opened(rig)
    sim.leds.set_led(hidden, True)  # what the killed process left on
    assert hidden in sim.scene.lit
    run_survey(rig, tmp_path / "cut", opened=rig_opened, resume=True)
    assert not sim.scene.lit
    resumed, full = (read_journal(tmp_path / d / "journal.jsonl") for d in ("cut", "full"))
    assert resumed.observations == full.observations and hidden in resumed.done
