"""Lever ``first_window``: a view's first recording that goes on from 2L + 2 to 3L + 2 frames
keeps the readings of its first 2L + 2 frames that the whole decode lacks
(:func:`fgloc.camera.blink_decoder.supplement_decode` in
:func:`fgloc.survey.coded_recording.record_adaptive`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fgloc.camera.blink_codes import code_book
from fgloc.survey.coded_views import reading_centroid
from fgloc.survey.session import run_survey
from tests import test_survey_coded as sc
from tests.test_survey_coded_levers import survey_reads_every_visible_pair

L = code_book(60).length  # the 60-mote scene's book


def _rig(first_window: str) -> dict:
    data = sc.coded_rig(60, 320)
    # tiling "greedy": with the fewest views cam0 reads n022 at a wide view's edge 4.2 px from n028, whose
    # light pulls the centroid 1 px (0.38 deg, past the 0.2 deg this fixture checks; docs/blink-codes.md,
    # "The fewest views")
    data["coded"] = {"length": "adaptive", "first_window": first_window, "tiling": "greedy"}
    return data


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The 60-mote scene surveyed with each value: its view records in journal order."""
    out = {}
    for value in ("dropped", "kept"):
        path = tmp_path_factory.mktemp(value)
        if value == "kept":  # every visible pair read once, each reading at its mote
            survey_reads_every_visible_pair(sc.parsed(_rig(value)), path)
        else:
            rig = sc.parsed(_rig(value))
            run_survey(rig, path, opened=sc.opened(rig)[0])
        out[value] = sc.view_records(path / "journal.jsonl")
    return out


def test_a_view_that_goes_on_keeps_what_its_first_frames_read(both):
    """Camera by camera, up to its first view whose readings differ, both surveys recorded the same
    views from the same frames. That view went on to 3L + 2 frames; with ``kept`` it has every
    reading of ``dropped`` (the same values) and more."""
    first_differing = []
    for camera in ("cam0", "cam1"):
        dropped, kept = ([r for r in both[v] if r["camera"] == camera] for v in ("dropped", "kept"))
        for a, b in zip(dropped, kept):
            assert (a["view"], a["attempt"], a["target"]) == (b["view"], b["attempt"], b["target"])
            if a["readings"] != b["readings"]:
                first_differing.append((a, b))
                break
    if not first_differing:
        pytest.fail("the first window should read a mote in this scene")
    for a, b in first_differing:
        check_kept(a, b)


def check_kept(a: dict, b: dict) -> None:
    """``b``, the view ``a`` recorded with the first window kept, reads all ``a`` read and more."""
    assert a["frames"] == b["frames"] == 3 * L + 2 and a["attempt"] == 0 and not a.get("stopped")
    whole = {r["node"]: r for r in a["readings"]}
    got = {r["node"]: r for r in b["readings"]}
    assert all(got[n] == r for n, r in whole.items())
    assert len(got) > len(whole)


def test_the_journal_records_the_lever_and_an_old_header_drops_the_first_window(tmp_path):
    from fgloc.survey.coded_levers import LEGACY
    from tests.test_survey_coded import check_lever_in_schema, resumed_and_new

    rig = sc.parsed(sc.coded_rig(12, 160))
    run_survey(rig, tmp_path, opened=sc.opened(rig)[0])
    header = json.loads((tmp_path / "journal.jsonl").read_text().splitlines()[0])
    assert header["coded"]["first_window"] == "kept"
    assert LEGACY["first_window"] == "dropped"
    assert resumed_and_new("first_window") == ("dropped", "kept")
    check_lever_in_schema("first_window", "kept", "whole")


def _spot(u: float, v: float, size: int = 15, sigma: float = 1.2) -> np.ndarray:
    ys, xs = np.mgrid[0:size, 0:size]
    return 200.0 * np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * sigma**2))


def test_a_reading_the_first_window_added_takes_its_centroid_from_those_frames():
    """A mote at (7.0, 7.0) blinks from the start; from frame 34 (2L + 2 of L = 16) a neighbour
    2 px to its right lights with it. Over all 50 frames the centroid is pulled towards the
    neighbour; over the first 34 it is the mote's. A pair-decoded LED keeps its decoder's."""
    lit = np.arange(50) % 3 != 0
    stack = np.full((50, 15, 15), 10.0)
    stack[lit] += _spot(7.0, 7.0)
    stack[lit & (np.arange(50) >= 34)] += _spot(9.0, 7.0)
    whole = reading_centroid(stack, 7.2, 7.1, None)
    first = reading_centroid(stack, 7.2, 7.1, None, first_frames=34)
    assert whole[0] > 7.25  # the late light pulls it
    assert first == pytest.approx((7.0, 7.0), abs=0.02)
    assert reading_centroid(stack, 7.2, 7.1, partner=12, first_frames=34) == (7.2, 7.1)
