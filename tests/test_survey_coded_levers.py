"""The planner's levers in the integrated coded survey (issue 16 follow-up): a retry that goes
on recording (sliding windows), radio separation of crowded motes by pause-by-bitmap, their
rig.json switches, and crash safety in each mode (resume never duplicates a reading)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.errors import FglocError
from fgloc.files.journal import read_journal
from fgloc.survey.clock import CameraTiming
from fgloc.survey.coded_levers import LEGACY, LEGACY_LEVELS, coded_settings
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_labels, coded_rig, levels_rig, opened, parsed, view_records

PERIOD = CameraTiming().frame_period_s


def lever_rig(n_nodes: int = 30, width: int = 320, **coded):
    """A coded rig with the old defaults (:data:`LEGACY`: burst, zoom, blobs, frames, probe and
    pairs off; the old ladder :data:`LEGACY_LEVELS`) written out, each lever test turning on its
    own lever against that baseline."""
    data = coded_rig(n_nodes, width)
    data["coded"] = LEGACY | {"levels": list(LEGACY_LEVELS)} | coded
    return data


def survey_reads_every_visible_pair(rig, out, max_error_deg: float = 0.2):
    """Run the coded survey into ``out``: every visible (camera, mote) pair read once, none
    twice, each reading within ``max_error_deg`` of its mote. Returns (runner, simulation, journal state)."""
    rig_opened, sim = opened(rig)
    _, runner = run_survey(rig, out, opened=rig_opened)
    state = read_journal(out / "journal.jsonl")
    assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
    assert state.duplicates_ignored == 0
    check_labels(rig, sim.scene, state, max_error_deg=max_error_deg)
    return runner, sim, state


@pytest.fixture(scope="module")
def defaults30(tmp_path_factory):
    """The 30-mote coded survey with every lever at its default (burst retries, frames, no
    probe, blob fallback): (field time, journaled views), the baseline of the lever tests."""
    out = tmp_path_factory.mktemp("defaults30")
    rig = parsed(lever_rig(30))
    _, runner = run_survey(rig, out, opened=opened(rig)[0])
    return runner.field_time, read_journal(out / "journal.jsonl").views


def test_continued_retry_goes_on_recording_and_reads_what_the_burst_missed(tmp_path, defaults30):
    """retry "continue": a view with curable refusals records L more frames from where its
    recording ended (the survey clock continues, no new burst) and decodes the whole recording
    in sliding windows; what it reads is new (no mote twice) and correctly labelled."""
    rig = parsed(lever_rig(30, retry="continue"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path, 0.2)
    recs = view_records(tmp_path / "journal.jsonl")
    first = {(r["camera"], r["view"]): r for r in recs if r["attempt"] == 0}
    again = [r for r in recs if r["attempt"] > 0]
    assert again and all(r.get("continued") for r in again)
    book_length = runner_book_length(rig)
    for r in again:
        prev = first[(r["camera"], r["view"])]
        assert r["frames"] == book_length and r["head"] == prev["head"]  # no re-slew, L more frames
        # the recording continues: its first frame period follows the previous recording's last
        assert r["clock_s"] == pytest.approx(prev["clock_s"] + prev["frames"] * PERIOD, abs=1e-9)
    # the continued windows read motes the first recording of those views had missed
    assert sum(len(r["readings"]) for r in again) > 0
    # priced as a continuation: cheaper on the clock than the same survey retrying in bursts
    assert runner.field_time.phases["frames"] < defaults30[0].phases["frames"]


def runner_book_length(rig) -> int:
    from fgloc.camera.blink_codes import code_book

    return code_book(len(rig.node_ids)).length


def test_continued_retry_resumes_without_duplicates(tmp_path):
    """A kill between a view's first recording and its continuation: the video is gone, so the
    resumed survey records that retry as a new burst (not continued); nothing is read twice,
    every view is recorded once, every visible pair is read, and what was journaled stays.
    Under the default levers (continue, predicted, probe, pairs)."""
    rig = parsed(levels_rig(12, width=160))
    full = tmp_path / "full"
    run_survey(rig, full, opened=opened(rig)[0])
    data = (full / "journal.jsonl").read_bytes()
    lines = data.splitlines(keepends=True)
    recs = [json.loads(x) for x in lines]
    again = [k for k, r in enumerate(recs) if r["type"] == "view" and r["attempt"] > 0]
    assert again, "the scene should retry a view"
    n_views = sum(r["type"] == "view" for r in recs)
    for k, cut in enumerate([again[0], again[-1]]):
        d = tmp_path / f"cut{k}"
        d.mkdir()
        (d / "journal.jsonl").write_bytes(b"".join(lines[:cut]) + lines[cut][:9])  # torn continuation
        kept = read_journal(d / "journal.jsonl").observations
        rig_opened, sim = opened(rig)
        run_survey(rig, d, resume=True, opened=rig_opened)
        state = read_journal(d / "journal.jsonl")
        assert state.duplicates_ignored == 0
        assert all(state.observations[key] == o for key, o in kept.items())
        assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
        check_labels(rig, sim.scene, state, max_error_deg=0.4)
        resumed = view_records(d / "journal.jsonl")
        keys = [(r["camera"], r["view"], r["attempt"]) for r in resumed]
        assert len(keys) == len(set(keys))
        redo = next(r for r in resumed if (r["camera"], r["view"], r["attempt"]) ==
                    (recs[cut]["camera"], recs[cut]["view"], recs[cut]["attempt"]))
        assert not redo.get("continued") and redo["frames"] == recs[cut]["frames"] * 3 + 2
        assert len(resumed) >= n_views - 2  # later retries may differ; every planned view is there


@pytest.mark.parametrize(("coded", "problem"), [({"retry": "again"}, "coded.retry"), ({"separate": 3}, "coded.separate"),
                                                ("radio", "coded: expected an object"),
                                                ({"levels": [1.0, 0.5]}, "coded.levels"),
                                                ({"fallback": "everywhere"}, "coded.fallback"),
                                                ({"retyr": "continue"}, "coded.retyr: unknown lever")])
def test_bad_coded_settings_are_one_line_and_exit_2(tmp_path, capsys, coded, problem):
    data = coded_rig(4, width=160)
    data["coded"] = coded
    with pytest.raises(FglocError, match=problem):
        coded_settings(parsed(data))
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o"), "--simulate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and problem in err[0], err
    assert not (tmp_path / "o" / "journal.jsonl").exists()


def test_coded_settings_defaults_and_rig_values():
    s = coded_settings(parsed(coded_rig(4, width=160)))  # a new survey: the measured fastest levers
    assert (s.retry, s.separate, s.fallback, s.video, s.probe, s.pairs) == (
        "continue", "zoom", "round", "frames", "on", "groups")
    s = coded_settings(parsed(lever_rig(4, width=160, retry="continue", separate="radio")))
    assert (s.retry, s.separate) == ("continue", "radio")
    assert coded_settings(parsed(lever_rig(4, width=160, retry="continue")), {"retry": "burst"}).retry == "burst"
    with pytest.raises(FglocError, match="--coded: retry: expected one of burst, continue, got 'x'"):
        coded_settings(parsed(coded_rig(4, width=160)), {"retry": "x"})
    with pytest.raises(FglocError, match="--coded: speed: unknown lever"):
        coded_settings(parsed(coded_rig(4, width=160)), {"speed": "max"})
    assert np.isfinite(PERIOD)


def test_paused_motes_stay_dark_in_the_rendered_views():
    """The in-process rig renders what the motes' side says: a mote paused by bitmap is not
    drawn (code kept running), a resume draws it again."""
    from fgloc.camera.blink_codes import code_book
    from fgloc.drivers.inprocess_rig import InProcessRig
    from fgloc.drivers.tinyos.blink import BlinkBroadcast, pause_packets

    rig = parsed(coded_rig(8, width=160))
    sim = InProcessRig(rig)
    sim.leds.broadcast_codes(BlinkBroadcast(code_book(8).length, 1, 8, PERIOD))
    sim.open_head("cam0")
    sim.record_blinks("cam0", 1, 0.0, "x")
    blinks = sim._blinks
    before = {m.node for m in blinks.motes("cam0")}  # type: ignore[attr-defined]
    assert len(before) >= 4
    paused = {sim.leds.addresses[n] for n in sorted(before)[:3]}
    for p in pause_packets(paused, range(1, 9)):
        sim.leds.broadcast_codes(p, set(), 0.0)
    after = {m.node for m in blinks.motes("cam0")}  # type: ignore[attr-defined]
    assert after == before - set(sorted(before)[:3])
    for p in pause_packets(set(), range(1, 9)):
        sim.leds.broadcast_codes(p, set(), 0.0)
    assert {m.node for m in blinks.motes("cam0")} == before  # type: ignore[attr-defined]
    assert sim.leds.blink.running.keys() >= paused  # paused motes kept running their code


def test_radio_separation_reads_crowded_motes_at_the_wide_zoom(tmp_path):
    """separate "radio": after the wide pass the crowded motes are placed from the other camera's
    readings, coloured, and each class blinks alone (the others paused by bitmap) while the
    cameras record the views holding them again at the wide zoom; the rounds read motes the wide
    pass could not, only motes of the lit class, none mislabelled; then every mote is resumed."""
    from fgloc.drivers.tinyos.blink import BlinkPause, parse_blink_command

    rig = parsed(lever_rig(30, separate="radio"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path, 0.2)
    recs = view_records(tmp_path / "journal.jsonl")
    rounds = [r for r in recs if r["view"].startswith("s")]
    assert rounds and all(r["zoom"] == 0.0 and r["view"].startswith(f"s{r['round']}-") for r in rounds)
    read_in_rounds = [(r["camera"], rd["node"]) for r in rounds for rd in r["readings"]]
    assert read_in_rounds and all(rd["node"] in r["lit"] for r in rounds for rd in r["readings"])
    wide = {(r["camera"], rd["node"]) for r in recs if r["view"].startswith("w") for rd in r["readings"]}
    assert not wide & set(read_in_rounds)  # new readings, not repeats
    classes = [set(r["lit"]) for r in {r["round"]: r for r in rounds}.values()]
    assert all(not a & b for a in classes for b in classes if a is not b)  # one class per round
    # the rounds' pauses went to the motes as pause-by-bitmap broadcasts; the last resumed every mote
    pauses = [c for c in map(parse_blink_command, sim.leds.received) if isinstance(c, BlinkPause)]
    assert len(pauses) == 3 * (len(classes) + 1) and not pauses[-1].paused
    assert not sim.leds.blink.paused
    # priced: the rounds wait for each other (barriers) and the pauses are radio time
    assert runner.field_time.phases["radio"] > 0


def test_radio_separation_resumes_to_the_uncut_readings(tmp_path):
    """Cut before a round's view, inside it (torn) and after the last round: each resume
    re-plans the same rounds from the journaled wide views, re-sends the pauses and ends with
    exactly the uncut run's readings, each view recorded once."""
    from tests.test_survey_runner import resume_from_cuts

    rig = parsed(lever_rig(30, separate="radio"))
    full = tmp_path / "full"
    run_survey(rig, full, opened=opened(rig)[0])
    data = (full / "journal.jsonl").read_bytes()
    records = [json.loads(line) for line in data.splitlines()]
    ends = list(np.cumsum([len(line) + 1 for line in data.splitlines()]))
    rounds = [k for k, r in enumerate(records) if r["type"] == "view" and r["view"].startswith("s")]
    n_views = sum(r["type"] == "view" for r in records)
    assert len(rounds) >= 2
    states = resume_from_cuts(rig, data, [int(ends[rounds[0] - 1]), int(ends[rounds[-1]])], tmp_path)
    for k in range(len(states)):
        keys = [(r["camera"], r["view"], r["attempt"]) for r in view_records(tmp_path / f"cut{k}" / "journal.jsonl")]
        assert len(keys) == len(set(keys)) == n_views, k


def test_radio_separation_over_the_visca_and_tinyos_twins(tmp_path):
    """The pause-by-bitmap broadcasts go through the real TinyOS driver to the base-station twin,
    whose motes go dark: the rounds read only motes of the lit class, every visible pair is
    read and none mislabelled."""
    from fgloc.drivers.inprocess_rig import build_scene

    data = lever_rig(20, width=320, separate="radio")
    data["simulation"]["twin"] = "visca"
    for cam in data["cameras"]:
        cam["model"], cam["mounting"] = "EVI-D70", "ceiling"
    data["search"] = {"pan_min_deg": -170, "pan_max_deg": 170, "tilt_min_deg": -88, "tilt_max_deg": 25}
    rig = parsed(data)
    run_survey(rig, tmp_path, simulate=True)
    state = read_journal(tmp_path / "journal.jsonl")
    scene = build_scene(rig)
    assert {(c, n) for (n, c, _) in state.observations} == scene.visible_pairs()
    check_labels(rig, scene, state, max_error_deg=0.4)
    rounds = [r for r in view_records(tmp_path / "journal.jsonl") if r["view"].startswith("s")]
    assert rounds and any(r["readings"] for r in rounds)
    assert all(rd["node"] in r["lit"] for r in rounds for rd in r["readings"])


def test_predicted_fallback_skips_the_search_where_no_blob_can_hide_the_mote(tmp_path):
    """fallback "predicted": a mote a camera did not decode is placed from the other camera's
    readings; with no unexplained blob near that direction the pair is not found without a
    search (occluded pairs here), so the fallback costs less; every visible pair is still read.
    (A ladder that stops at 2x leaves blobs unexplained, as 100 motes do at 10x.)"""
    rig = parsed(lever_rig(30, fallback="predicted", levels=[1 / 9]))
    rig_opened, sim = opened(rig)
    _, runner = run_survey(rig, tmp_path / "p", opened=rig_opened)
    state = read_journal(tmp_path / "p" / "journal.jsonl")
    assert {(c, n) for (n, c, _) in state.observations} == sim.scene.visible_pairs()
    occluded = {(n, c) for i, c in enumerate(rig.camera_ids) for j, n in enumerate(rig.node_ids)
                if not sim.scene.visible[i, j] and n != "n003"}
    assert occluded and occluded <= set(state.not_found)
    placed = [k for k, why in state.not_found.items() if "place the mote" in why]
    assert placed and set(placed) <= occluded
    blobs = parsed(lever_rig(30, fallback="blobs", levels=[1 / 9]))
    _, blob_runner = run_survey(blobs, tmp_path / "b", opened=opened(blobs)[0])
    assert runner.field_time.phases["fallback"] < blob_runner.field_time.phases["fallback"]


def test_fields_decode_interlaced_video_at_twice_the_rate(tmp_path, defaults30):
    """video "fields": the motes blink one bit per field (the start broadcast says 16.68 ms),
    the in-process rig renders fields (every second row, 59.94 Hz, half the light) and the
    survey decodes them with the field's intrinsics: every visible pair read, none mislabelled,
    each recording 3L + 2 fields priced at the field rate (less video time than frames)."""
    from fgloc.drivers.tinyos.blink import BlinkBroadcast, parse_blink_command

    rig = parsed(lever_rig(30, video="fields"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path / "f", 0.3)
    starts = [c for c in map(parse_blink_command, sim.leds.received) if isinstance(c, BlinkBroadcast)]
    assert starts and all(c.bit_period_s == pytest.approx(PERIOD / 2, abs=1e-5) for c in starts)
    frames = sim.record_blinks("cam0", 5, 1.0, "probe", fields=True)
    assert frames[0][1].shape == (120, 320)
    assert np.diff([t for t, _ in frames]).min() == pytest.approx(PERIOD / 2, abs=2e-3)
    per_recording = runner.field_time.phases["frames"] / len(state.views)
    assert per_recording < 0.7 * defaults30[0].phases["frames"] / len(defaults30[1])


def test_fields_need_a_rig_that_records_them(tmp_path, capsys):
    data = lever_rig(6, width=160, video="fields")
    data["simulation"]["twin"] = "visca"
    for cam in data["cameras"]:
        cam["model"], cam["mounting"] = "EVI-D70", "ceiling"
    data["search"] = {"pan_min_deg": -170, "pan_max_deg": 170, "tilt_min_deg": -88, "tilt_max_deg": 25}
    (tmp_path / "rig.json").write_text(json.dumps(data))
    assert main(["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o"), "--simulate"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "coded.video" in err[0] and "fields" in err[0], err


def test_the_coded_flag_overrides_the_file(tmp_path, capsys):
    (tmp_path / "rig.json").write_text(json.dumps(lever_rig(12, width=160, retry="burst")))
    args = ["survey", "--rig", str(tmp_path / "rig.json"), "-o", str(tmp_path / "o"), "--simulate", "--quiet",
            "--identify", "coded"]
    assert main(args + ["--coded", "retry=continue", "--coded", "fallback=predicted"]) == 0
    again = [r for r in view_records(tmp_path / "o" / "journal.jsonl") if r["attempt"] > 0]
    assert again and all(r.get("continued") for r in again)
    capsys.readouterr()
    for bad, problem in (("retry", "--coded: expected KEY=VALUE"), ("video=tv", "--coded: video")):
        assert main(args[:4] + [str(tmp_path / f"o-{bad}")] + args[5:] + ["--coded", bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and problem in err[0], err
        assert not (tmp_path / f"o-{bad}" / "journal.jsonl").exists()


def test_probe_stops_the_recording_of_empty_views_only(tmp_path, defaults30):
    """probe "on": each recording starts with L + 2 frames; a view they show no blob in stops
    there (priced as L + 2 frames), any other goes on to 3L + 2 as one recording. Every
    visible pair is still read; each probed-empty view really holds no visible mote."""
    from fgloc.camera.pixel_angles import pan_tilt_to_pixel

    rig = parsed(lever_rig(30, probe="on"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path / "p", 0.2)
    recs = [r for r in view_records(tmp_path / "p" / "journal.jsonl") if r["attempt"] == 0]
    length = runner_book_length(rig)
    empty = [r for r in recs if r["frames"] == length + 2]
    full = [r for r in recs if r["frames"] == 3 * length + 2]
    assert empty and full and len(empty) + len(full) == len(recs)
    assert all(r["probe"] == length + 2 for r in recs)
    assert all(not r["readings"] and not r["refused"] for r in empty)
    for r in empty:  # no visible mote lies in the image of an empty view
        i = rig.camera_ids.index(r["camera"])
        intr = rig.cameras[i].intrinsics if r["zoom"] == 0 else rig.cameras[i].intrinsics.at_zoom(r["zoom"])
        live = [j for j, n in enumerate(rig.node_ids) if sim.scene.visible[i, j] and n not in sim.scene.dead]
        uv, front = pan_tilt_to_pixel(intr, sim.scene.apparent[i, live, 0], sim.scene.apparent[i, live, 1], *r["head"])
        inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
        assert not inside.any(), r["view"]
    assert runner.field_time.phases["frames"] < defaults30[0].phases["frames"]


def test_group_decoding_in_the_survey_reads_crowds_the_pair_decoder_leaves(tmp_path):
    """pairs "groups": a refused pair is also tried as three LEDs. On the 30-mote rig every
    visible pair is still read once with its own label, and crowds of three read in the wide
    view save refinement tiles against pairs "on" (3 against 5 here)."""
    tiles = {}
    for mode in ("on", "groups"):
        out = tmp_path / mode
        _, _, state = survey_reads_every_visible_pair(parsed(lever_rig(30, pairs=mode)), out, 0.2)
        assert (read_journal(out / "journal.jsonl").header.coded or {}).get("pairs") == mode
        tiles[mode] = sum(1 for r in view_records(out / "journal.jsonl")
                          if r["view"].startswith("r") and r["attempt"] == 0)
    assert tiles["groups"] < tiles["on"]


def test_pair_decoding_labels_blobs_of_two_motes_in_the_survey(tmp_path, defaults30):
    """pairs "on": blobs the single decoder refuses are tried as two LEDs; a pair read in a view
    gives two readings naming each other (``partner``), both correctly labelled and close to
    their motes' bearings; every visible pair is read, and fewer refinement tiles are needed."""
    rig = parsed(lever_rig(30, pairs="on"))
    runner, sim, state = survey_reads_every_visible_pair(rig, tmp_path, 0.2)
    recs = view_records(tmp_path / "journal.jsonl")
    paired = [(r, rd) for r in recs for rd in r["readings"] if "partner" in rd]
    assert paired
    for r, rd in paired:  # the partner, when this view took its reading too, names it back, a few px away
        mate = [x for x in r["readings"] if x.get("code") == rd["partner"]]
        assert not mate or (mate[0]["partner"] == rd["code"] and math.hypot(mate[0]["u"] - rd["u"],
                                                                            mate[0]["v"] - rd["v"]) < 8.0)
    tiles = sum(1 for r in recs if r["view"].startswith("r") and r["attempt"] == 0)
    assert tiles < sum(1 for (c, v, a) in defaults30[1] if v.startswith("r") and a == 0)
