"""The coded survey's zoom back after refinement: on the camera's lane only where it fits before the
longest lane ends; else owed, the head zooming back to the survey zoom just before its next
operation (a fallback search, priced in that node's field time) or after the survey's last
reading (not priced)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.drivers.inprocess_rig import SceneHead
from fgloc.files.journal import read_journal
from fgloc.survey.clock import Zoom, price
from fgloc.survey.coded import CodedSurvey
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_labels, coded_rig, levels_rig, opened, parsed, view_records


@pytest.fixture
def head_log(monkeypatch):
    """Every set_zoom and move_to of the in-process heads, in order: (camera index, what, value)."""
    log: list[tuple[int, str, object]] = []
    set_zoom, move_to = SceneHead.set_zoom, SceneHead.move_to

    def zooming(self, zoom):  # noqa: ANN001, ANN202
        log.append((self.index, "zoom", float(zoom)))
        return set_zoom(self, zoom)

    def moving(self, pan, tilt):  # noqa: ANN001, ANN202
        log.append((self.index, "move", (float(pan), float(tilt))))
        return move_to(self, pan, tilt)

    monkeypatch.setattr(SceneHead, "set_zoom", zooming)
    monkeypatch.setattr(SceneHead, "move_to", moving)
    return log


def _lanes_at_the_end(monkeypatch) -> dict[str, list]:
    """The camera lanes as the survey prices them, captured when it settles its heads."""
    lanes: dict[str, list] = {}
    settle = CodedSurvey.settle_heads

    def settling(self, runner):  # noqa: ANN001, ANN202
        lanes.update({c: list(ops) for c, ops in self.lanes.items()})
        return settle(self, runner)

    monkeypatch.setattr(CodedSurvey, "settle_heads", settling)
    return lanes


def test_a_refined_camera_zooms_back_on_its_lane_only_in_the_longest_lane_s_slack_and_every_head_ends_wide(
        tmp_path, monkeypatch, head_log):
    data = levels_rig(12, width=160)
    data["coded"]["zoom_moves"] = "apart"  # each zoom its own operation on the lane (together: the next test)
    data["coded"]["tiling"] = "greedy"  # with the fewest tiles no zoom back fits in the slack
    rig = parsed(data)
    lanes = _lanes_at_the_end(monkeypatch)
    rig_opened, sim = opened(rig)
    run_survey(rig, tmp_path, opened=rig_opened)
    records = view_records(tmp_path / "journal.jsonl")
    refined = {r["camera"] for r in records if float(r["zoom"]) > 0}
    assert refined, "the scene should need refinement"
    timing = CodedSurvey(rig, rig_opened.open_head, rig_opened.leds, sim).lane_timing
    ends = {c: price([op for op in ops if not (isinstance(op, Zoom) and op.dzoom < 0)], timing[c]).total
            for c, ops in lanes.items()}
    longest = max(ends.values())
    decided = set()
    for c in refined:
        zooms = [op.dzoom for op in lanes[c] if isinstance(op, Zoom)]
        assert zooms and zooms[0] > 0  # zoomed in rung by rung
        last = max(float(r["zoom"]) for r in records if r["camera"] == c)  # the ladder ascends
        back = price([Zoom(rig.cameras[rig.camera_ids.index(c)].zoom - last)], timing[c]).total
        fits = ends[c] + back <= longest + 1e-9
        # back on the lane exactly when it fits before the longest lane ends, as its last operation
        assert (zooms[-1] < 0) == fits and sum(z < 0 for z in zooms) == int(fits)
        assert not fits or isinstance(lanes[c][-1], Zoom)
        decided.add(fits)
    assert decided == {True, False}  # this scene: cam0 zooms back in cam1's slack, cam1 (the longest) owes it
    for i, cam in enumerate(rig.cameras):  # every head ends at its survey zoom all the same
        assert sim.heads[cam.id]._zoom == cam.zoom
        zooms = [v for k, what, v in head_log if k == i and what == "zoom"]
        if cam.id in refined:
            assert max(zooms) > cam.zoom and zooms[-1] == cam.zoom


def test_a_head_that_zooms_while_moving_zooms_on_its_way_to_each_rung(tmp_path, monkeypatch) -> None:
    """Lever ``zoom_moves``: with ``together`` the in-process head (an EVI-D100, which zooms while
    moving) is driven through ``move_and_zoom``, and each rung's zoom travel rides on the Slew to
    the rung's first tile (``dzoom``), which is priced max(axes, zoom) instead of their sum; with
    ``apart`` each rung's zoom is its own Zoom before that Slew. Either way every reading lies on
    its mote. (The two runs record at other clock times, so their noise, retries and views may differ.)"""
    from fgloc.survey.clock import Slew, op_time

    move_and_zoom = SceneHead.move_and_zoom
    for mode in ("apart", "together"):
        data = levels_rig(12, width=160)
        data["coded"]["zoom_moves"] = mode
        rig = parsed(data)
        lanes = _lanes_at_the_end(monkeypatch)
        calls: list[str] = []

        def counting(self, pan, tilt, zoom, calls=calls):  # noqa: ANN001, ANN202
            calls.append(self.scene.camera_ids[self.index])
            return move_and_zoom(self, pan, tilt, zoom)

        monkeypatch.setattr(SceneHead, "move_and_zoom", counting)
        rig_opened, sim = opened(rig)
        out = tmp_path / mode
        run_survey(rig, out, opened=rig_opened)
        timing = CodedSurvey(rig, rig_opened.open_head, rig_opened.leds, sim).lane_timing
        records = view_records(out / "journal.jsonl")
        check_labels(rig, sim.scene, read_journal(out / "journal.jsonl"), max_error_deg=0.2)
        refined = {r["camera"] for r in records if float(r["zoom"]) > 0}
        assert refined
        assert bool(calls) == (mode == "together") and set(calls) <= set(rig.camera_ids)
        for camera in refined:
            rungs = sorted({float(r["zoom"]) for r in records if r["camera"] == camera})
            steps = list(np.diff(rungs))  # the ladder ascends from the survey zoom, one zoom travel per rung
            ins_zoom = [op.dzoom for op in lanes[camera] if isinstance(op, Zoom) and op.dzoom > 0]
            moves = [op for op in lanes[camera] if isinstance(op, Slew) and op.dzoom > 0]
            assert (ins_zoom, [op.dzoom for op in moves]) == ((steps, []) if mode == "apart" else ([], steps))
            if mode == "together":
                head, lane = timing[camera].head, lanes[camera]
                apart = [x for op in lane for x in ((Zoom(op.dzoom), Slew(op.dpan, op.dtilt))
                                                    if isinstance(op, Slew) and op.dzoom else (op,))]
                saved = sum(min(head.zoom_time(op.dzoom), op_time(Slew(op.dpan, op.dtilt), timing[camera])
                                - head.command_s) for op in moves)
                assert saved > 0
                assert price(apart, timing[camera]).total - price(lane, timing[camera]).total == pytest.approx(saved)


def test_a_zoomed_camera_zooms_back_before_its_first_fallback_search_priced_there(tmp_path, monkeypatch, head_log):
    """A mote whose code the survey does not know (its blob unassigned, chased up the ladder and
    handed to the fallback) is measured the sequential way: each camera that refined zooms back
    before its first move of that search, the zoom is priced in the node's field time, and the
    readings lie on the mote."""
    rig = parsed(coded_rig(12, width=160))
    hidden = "n005"
    init = CodedSurvey.__init__

    def forgetting(self, *args, **kw):  # noqa: ANN001, ANN202
        init(self, *args, **kw)
        self.node_of_code = {k: n for k, n in self.node_of_code.items() if n != hidden}

    monkeypatch.setattr(CodedSurvey, "__init__", forgetting)
    rig_opened, sim = opened(rig)
    run_survey(rig, tmp_path, opened=rig_opened)
    state = read_journal(tmp_path / "journal.jsonl")
    check_labels(rig, sim.scene, state, max_error_deg=0.2)
    obs = [o for (n, _c, _k), o in state.observations.items() if n == hidden]
    seen_by = {c for c, n in sim.scene.visible_pairs() if n == hidden}
    assert {o.camera for o in obs} == seen_by and seen_by
    for o in obs:
        assert o.view is None  # the sequential way
        i = rig.camera_ids.index(o.camera)
        p, t = sim.scene.apparent[i, rig.node_ids.index(hidden)]
        assert math.degrees(math.hypot(math.remainder(o.pan - p, 2 * math.pi) * math.cos(t), o.tilt - t)) < 0.2
    records = view_records(tmp_path / "journal.jsonl")
    last_zoom = {r["camera"]: float(r["zoom"]) for r in records}  # each camera's last recording's zoom
    zoomed = {c for c, z in last_zoom.items() if z > 0 and c in {o.camera for o in obs}}
    assert zoomed, "a camera that ended zoomed in should search for the mote"
    for c in zoomed:
        i = rig.camera_ids.index(c)
        cam = rig.cameras[i]
        events = [(what, v) for k, what, v in head_log if k == i]
        last_rec = max(k for k, (what, v) in enumerate(events) if what == "zoom" and v == last_zoom[c])
        after = events[last_rec + 2:]  # past the last tile's own move
        moves = [k for k, (what, _v) in enumerate(after) if what == "move"]
        assert moves and after[:moves[0]] == [("zoom", cam.zoom)]  # back to the survey zoom, then the search
    node_time = [r for r in state.field_times if r.get("scope") == "fallback_node" and r.get("node") == hidden]
    assert len(node_time) == 1
    timing = CodedSurvey(rig, rig_opened.open_head, rig_opened.leds, sim).timing
    owed = max(price([Zoom(cam.zoom - last_zoom[cam.id])], timing[cam.id]).total
               for cam in rig.cameras if cam.id in zoomed)
    assert node_time[0]["phases"].get("zoom", 0.0) == pytest.approx(owed) and owed > 0


def test_a_survey_resumed_after_the_ladder_still_prices_the_owed_zoom_back(tmp_path) -> None:
    """A resumed survey opens its heads anew; the zoom back the ladder left owed is still priced
    before the head's next operation (a reopened head used to drop it): the zoom its fallback
    searches price equals the uncut survey's. Scene: 60 motes, 40 % of the pairs occluded
    (tests/test_coded_fallback_order.py), whose fallback searches with a camera that ended zoomed in."""
    data = coded_rig(60, 320, occlusion=0.4, seed=2)
    # tiling "greedy": with the fewest tiles no fallback search pays a zoom back the ladder left owed
    data["coded"] = {"fallback": "predicted", "decode": "levels", "length": "fixed", "ladder": "climb", "tiling": "greedy",
                     "levels": [2 / 9, 1.0]}
    rig = parsed(data)
    full, cut = tmp_path / "full", tmp_path / "cut"
    run_survey(rig, full, opened=opened(rig)[0])
    lines = (full / "journal.jsonl").read_text().splitlines()
    stop = next(k for k, line in enumerate(lines) if '"type":"codes"' in line and '"stop"' in line)
    cut.mkdir()
    (cut / "journal.jsonl").write_text("\n".join(lines[:stop]) + "\n")  # killed after the ladder's last view
    run_survey(rig, cut, opened=opened(rig)[0], resume=True)

    def fallback_zoom(path) -> float:
        return sum(float(r["phases"].get("zoom", 0.0)) for r in read_journal(path / "journal.jsonl").field_times
                   if r.get("scope") in ("fallback_node", "fallback_group", "fallback_pair"))  # the first search pays it

    owed = fallback_zoom(full)
    assert owed > 0, "the scene should leave a zoom back owed to a fallback search"
    assert fallback_zoom(cut) == pytest.approx(owed)
