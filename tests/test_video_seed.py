"""rig.json ``simulation.video_seed``: another recording of the same simulated scene (the motes'
start phases and clocks and the frame noise drawn anew), for measuring a coded survey's field
time over recordings (``scripts/coded_survey.py --video-seeds``)."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.files.journal import read_journal
from fgloc.files.rig_config import RigConfigError, rig_meaning
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_labels, coded_rig, opened, parsed, view_records


def _survey(tmp_path, name: str, video_seed: int | None):  # noqa: ANN001, ANN202
    data = coded_rig(12, width=160)
    if video_seed is not None:
        data["simulation"]["video_seed"] = video_seed
    rig = parsed(data)
    rig_opened, sim = opened(rig)
    run_survey(rig, tmp_path / name, opened=rig_opened)
    state = read_journal(tmp_path / name / "journal.jsonl")
    check_labels(rig, sim.scene, state, max_error_deg=0.2)  # every reading lies on its own mote
    pixels = {(r["camera"], r["view"], r["attempt"], rd["node"]): (rd["u"], rd["v"])
              for r in view_records(tmp_path / name / "journal.jsonl") for rd in r["readings"]}
    return rig, sim, pixels


def test_a_video_seed_records_the_same_scene_anew_and_the_same_seed_again_alike(tmp_path) -> None:
    rig0, sim0, scene_seed = _survey(tmp_path, "scene", None)
    rig1, sim1, seven = _survey(tmp_path, "seven", 7)
    _, _, again = _survey(tmp_path, "seven-again", 7)
    # the same scene: truth and apparent bearings
    nodes0, nodes1 = sim0.scene.truth.nodes, sim1.scene.truth.nodes
    assert nodes0.keys() == nodes1.keys() and all(np.array_equal(nodes0[n], nodes1[n]) for n in nodes0)
    assert np.array_equal(sim0.scene.apparent, sim1.scene.apparent)
    # another draw of the video: the readings of the views both recorded moved by noise, not to other motes
    both = sorted(set(scene_seed) & set(seven))
    assert len(both) >= 10
    moved = [np.hypot(scene_seed[k][0] - seven[k][0], scene_seed[k][1] - seven[k][1]) for k in both]
    assert max(moved) > 1e-3 and max(moved) < 2.0
    assert again == seven  # seeded: the same video seed records the same
    # a resume must not mix recordings: the seed is part of what the readings mean
    assert rig_meaning(rig1, simulated=True)["simulation.video_seed"] == 7
    assert "simulation.video_seed" not in rig_meaning(rig0, simulated=True)


@pytest.mark.parametrize("bad", [-1, "7", 1.5])
def test_a_bad_video_seed_is_one_line_naming_the_field(bad) -> None:  # noqa: ANN001
    data = coded_rig(12, width=160)
    data["simulation"]["video_seed"] = bad
    with pytest.raises(RigConfigError) as err:
        parsed(data)
    assert "simulation.video_seed" in str(err.value) and "\n" not in str(err.value)
