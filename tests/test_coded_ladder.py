"""The zoom refinement's ``ladder`` lever (fgloc/survey/coded_ladder.py; docs/blink-codes.md
"Where the ladder's time went").

* :func:`unread` drops a refused blob at a reading of the camera (pixels of the blob's own
  zoom), :func:`focused` keeps a rung's blob only near what the rung chased and hands a lamp
  that stays lit after a zoom step to the fallback, :func:`read_before` takes exactly the
  views done before a rung is planned (or before a view), :func:`retry_helps` records a view
  again only for a blob no reading explains.
* On seeded scenes ``"focus"`` records fewer refinement frames than ``"climb"`` (the survey
  before the lever) and still reads every visible pair once, none mislabelled.
* A focused survey killed before, in the middle of (torn) and after its refinement resumes to
  the uncut run's readings, each view recorded once; a journal whose header predates the lever
  resumes climbing; a flag that disagrees with the journal is refused in one line, exit 2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import Gauge, NodeMode
from fgloc.files.journal import JournalHeader, JournalState
from fgloc.survey.coded_ladder import (
    EXPLAINED_PX,
    FOCUS_PX,
    SEPARATION_PX,
    codes_read_before,
    focused,
    light_before,
    never_dark,
    read_before,
    retry_helps,
    unread,
    unseen,
    view_order,
)
from fgloc.survey.coded_levers import LEGACY, coded_settings
from tests.test_survey_coded import (
    check_lever_in_schema,
    check_lever_refused_on_resume,
    coded_rig,
    cut_and_resume,
    parsed,
    view_records,
)
from tests.test_survey_coded_levers import survey_reads_every_visible_pair

HEAD = (0.3, -0.2)


def intrinsics_at():
    rig = parsed(coded_rig(4, width=320))
    base = rig.cameras[0].intrinsics
    return lambda z: base if z == 0.0 else base.at_zoom(z)


def blob_at(k, head, zoom, du: float = 0.0):
    """A blob ``du`` pixels right of the image centre at ``zoom``."""
    intr = k(zoom)
    return (intr.cx + du, intr.cy), head, zoom


def reading(k, blob, du: float):
    """The bearing of a reading ``du`` pixels (of the blob's zoom) right of ``blob``."""
    (u, v), head, zoom = blob
    p, t = pixel_to_pan_tilt(k(zoom), np.array([u + du, v]), *head)
    return pan_tilt_bearing(float(p), float(t))


# ----- the rules, on their own
def test_a_blob_at_a_reading_is_read_in_pixels_of_its_own_zoom():
    k = intrinsics_at()
    wide, tile = blob_at(k, HEAD, 0.0), blob_at(k, HEAD, 1.0)  # 10x: a pixel is a tenth of a wide one
    near, far = EXPLAINED_PX - 0.3, EXPLAINED_PX + 0.5
    assert unread([wide], np.array([reading(k, wide, near)]), k) == []
    assert unread([wide], np.array([reading(k, wide, far)]), k) == [0]
    assert unread([tile], np.array([reading(k, tile, near)]), k) == []
    # the same angle is 10 tile pixels: that reading is another mote, the tile's blob stays unread
    assert unread([tile], np.array([reading(k, wide, near)]), k) == [0]
    assert unread([wide, tile], np.zeros((0, 3)), k) == [0, 1]
    # a blob refused as merged LEDs hides a second mote beside the read one: never explained
    assert unread([wide, tile], np.array([reading(k, wide, near), reading(k, tile, near)]), k, [True, False]) == [0]


def test_a_rung_carries_on_only_what_lies_where_it_looked():
    k = intrinsics_at()
    chased = blob_at(k, HEAD, 0.0)  # chased from the wide view; the rung's tiles at 2x
    level = 1 / 9
    intr = k(level)
    centre = (intr.cx, intr.cy)  # the same head: the chased blob (on the axis) stays at the centre
    scale = intr.fx / k(0.0).fx  # tile pixels per wide pixel

    def found(wide_px: float):
        return (float(centre[0]) + wide_px * scale, float(centre[1])), HEAD, level

    inside, outside = found(FOCUS_PX - 2.0), found(FOCUS_PX + 4.0)
    carried, handed = focused([chased], [False], [inside, outside], [False, False], k)
    assert carried == [inside] and handed == []
    # a blob that stays lit where the chased blob never went dark either: a lamp, to the fallback
    carried, handed = focused([chased], [True], [inside, outside], [True, True], k)
    assert carried == [] and handed == [inside]
    # ... but one that stays lit where an ambiguous blob was chased is chased on
    carried, handed = focused([chased], [False], [inside], [True], k)
    assert carried == [inside] and handed == []
    assert focused([], [], [inside], [False], k) == ([], [])


def test_light_no_coarser_recording_showed_is_unseen():
    """A rung's blob away from every chased one is dropped by :func:`focused` (a coarser view
    decided that direction); :func:`unseen` names those no coarser recording showed light at
    (no reading within EXPLAINED_PX of its pixels, no refused blob within SEPARATION_PX), which
    the survey hands to the fallback: a faint mote the wide zoom did not detect."""
    k = intrinsics_at()
    chased, level = blob_at(k, HEAD, 0.0), 1 / 9
    intr = k(level)
    scale = intr.fx / k(0.0).fx
    away = (float(intr.cx) + (FOCUS_PX + 20.0) * scale, float(intr.cy)), HEAD, level  # 32 wide px off
    wide_u = k(0.0).cx + FOCUS_PX + 20.0

    def views(kind: str, du: float) -> dict:  # the wide view's one item, du wide pixels from the found blob
        item = {"u": wide_u + du, "v": k(0.0).cy}
        rec = {"head": list(HEAD), "zoom": 0.0, "readings": [], "refused": []}
        rec[kind].append(item)
        return {("cam0", "w000", 0): rec, ("cam0", "r1-000", 0): {"head": list(HEAD), "zoom": level,
                                                                  "readings": [{"u": 0.0, "v": 0.0}], "refused": []}}

    def new_light(v: dict) -> bool:
        return unseen([away], light_before(v, "cam0", 1, k, 0.0), k) == [away]

    assert focused([chased], [False], [away], [False], k) == ([], [])
    assert new_light({})  # nothing before
    assert not new_light(views("readings", EXPLAINED_PX - 0.5))  # that reading's mote, read
    assert new_light(views("readings", EXPLAINED_PX + 1.5))  # a neighbour read beside it
    assert not new_light(views("refused", SEPARATION_PX - 1.0))  # inside a coarser blob: decided there
    assert new_light(views("refused", SEPARATION_PX + 1.0))
    assert len(light_before(views("refused", 0.0), "cam0", 2, k, 0.0)[0]) == 2  # rung 1's tiles count for rung 2


def test_never_dark_is_the_decoders_steady_light_refusal():
    assert never_dark({"kind": "rejected", "reason": "never dark (off level 305 of amplitude 8)"})
    assert not never_dark({"kind": "ambiguous", "reason": "never dark"})
    assert not never_dark({"kind": "rejected", "reason": "3 of 16 bits never read cleanly"})


def test_read_before_takes_the_views_done_before_the_rung():
    def rec(pan: float) -> dict:
        return {"readings": [{"pan": pan, "tilt": 0.0}]}

    views = {("cam0", "w000", 0): rec(0.1), ("cam0", "w000", 1): rec(0.2), ("cam0", "s1-000", 0): rec(0.3),
             ("cam0", "r1-000", 0): rec(0.4), ("cam0", "r2-001", 1): rec(0.5), ("cam1", "w000", 0): rec(0.6)}

    def pans(rung: int) -> list[float]:
        b = read_before(views, "cam0", rung)
        return sorted(round(math.atan2(y, x), 6) for x, y, _ in b)

    assert pans(0) == [0.1, 0.2, 0.3]
    assert pans(1) == [0.1, 0.2, 0.3, 0.4]
    assert pans(3) == [0.1, 0.2, 0.3, 0.4, 0.5]


def test_a_view_is_recorded_again_only_for_a_blob_no_reading_explains():
    k = intrinsics_at()
    (u, v), head, _ = blob_at(k, HEAD, 0.0)
    record = {"head": list(head), "zoom": 0.0, "refused": [
        {"kind": "rejected", "u": u, "v": v, "reason": "3 of 16 bits never read cleanly"},
        {"kind": "rejected", "u": u + 40.0, "v": v, "reason": "too close to the image border"}]}
    at_blob = np.array([reading(k, blob_at(k, HEAD, 0.0), 0.5)])
    assert not retry_helps(record, at_blob, k, 0.0)  # the refused mote was read; the border blob never counts
    assert retry_helps(record, np.zeros((0, 3)), k, 0.0)
    ambiguous = record | {"refused": record["refused"] + [{"kind": "ambiguous", "u": u - 30.0, "v": v, "reason": "x"}]}
    assert retry_helps(ambiguous, at_blob, k, 0.0)  # an unread merged blob: a longer recording may cure it
    assert retry_helps(record | {"refused": [{"kind": "duplicate", "reason": "code 5 decoded from 2 blobs"}]},
                       at_blob, k, 0.0)  # no pixel: cannot tell


def test_view_order_and_the_readings_before_a_view():
    assert sorted(["r2-000", "w010", "r1-003", "s1-v000", "w002", "r1-000"], key=view_order) == [
        "w002", "w010", "s1-v000", "r1-000", "r1-003", "r2-000"]

    def rec(pan: float) -> dict:
        return {"readings": [{"pan": pan, "tilt": 0.0}]}

    views = {("cam0", "w000", 0): rec(0.1), ("cam0", "w001", 0): rec(0.2), ("cam0", "w001", 1): rec(0.3),
             ("cam0", "w002", 0): rec(0.4), ("cam0", "r1-000", 0): rec(0.5), ("cam1", "w000", 0): rec(0.6)}
    b = read_before(views, "cam0", 0, "w001", 0)
    assert sorted(round(math.atan2(y, x), 6) for x, y, _ in b) == [0.1, 0.2]
    b = read_before(views, "cam0", 0, "r1-000", 0)
    assert sorted(round(math.atan2(y, x), 6) for x, y, _ in b) == [0.1, 0.2, 0.3, 0.4, 0.5]


def test_codes_read_before_a_recording_are_the_camera_s_earlier_readings_by_code():
    def rec(code: int, pan: float) -> dict:
        return {"readings": [{"pan": pan, "tilt": 0.0, "code": code}, {"pan": 9.0, "tilt": 0.0}]}  # 2nd: no code

    views = {("cam0", "w000", 0): rec(7, 0.1), ("cam0", "w001", 0): rec(8, 0.2), ("cam0", "w001", 1): rec(9, 0.3),
             ("cam0", "w002", 0): rec(10, 0.4), ("cam1", "w000", 0): rec(11, 0.6)}

    def pans(view: str, attempt: int) -> dict[int, float]:
        got = codes_read_before(views, "cam0", view, attempt)
        return {c: round(math.atan2(b[1], b[0]), 6) for c, b in got.items()}

    assert pans("w000", 0) == {}
    assert pans("w001", 0) == {7: 0.1}  # not the view's own first recording: it is the one being decoded
    assert pans("w001", 1) == {7: 0.1, 8: 0.2}
    assert pans("r1-000", 0) == {7: 0.1, 8: 0.2, 9: 0.3, 10: 0.4}  # never another camera's


# ----- the survey
def ladder_rig(n: int, width: int, ladder: str, seed: int = 1) -> dict:
    data = coded_rig(n, width, seed=seed)
    # the level decoder's misses make these scenes climb; explain "views": with "crowds" the 160 px
    # scene's one 3x tile of cam1 falls where it reads nothing (docs/blink-codes.md, "Crowds another
    # wide view read apart"), and this compares the ladders, not the explain rules; tiling
    # "greedy": with the fewest tiles the 160 px scene's ladders record the same frames
    data["coded"] = {"ladder": ladder, "decode": "levels", "explain": "views", "tiling": "greedy"}
    return data


@pytest.mark.parametrize(("n", "width", "seed"), [(30, 320, 3), (12, 160, 1)])
def test_focus_records_fewer_refinement_frames_and_reads_every_visible_pair(tmp_path, n, width, seed):
    frames = {}
    for ladder in ("climb", "focus"):
        rig = parsed(ladder_rig(n, width, ladder, seed))
        out = tmp_path / ladder
        _, _, state = survey_reads_every_visible_pair(rig, out)  # every visible pair once, none mislabelled
        recs = view_records(out / "journal.jsonl")
        frames[ladder] = sum(r["frames"] for r in recs if r["view"].startswith("r"))
        assert all(float(r["zoom"]) > 0 for r in recs if r["view"].startswith("r"))
    assert 0 < frames["focus"] < frames["climb"], frames


def test_a_mote_merged_with_one_read_at_a_higher_zoom_is_still_read(tmp_path):
    """The 640 x 480 rig of scripts/coded_survey.py, seed 4: cam0's wide views merge n021 with
    n028 2.6 px away (refused as ambiguous, its centroid 1.3 px from n028); a 2x tile reads n028.
    The merged blob must not count as n028: n021 is read too (by the fallback)."""
    from tests.conftest import load_script

    rig = load_script("coded_survey").rig_for(4, 100, 640, "coded", 502, 0.0, {}, True)
    survey_reads_every_visible_pair(rig, tmp_path / "s4")


def test_no_pair_reading_is_taken_from_an_leds_cut_off_edge(tmp_path):
    """The 320 x 240 rig of scripts/coded_survey.py, seed 5: a 2x tile of cam1 pair-decoded
    n078 with n067 5.3 px from the aperture's centre (r = 5), its light cut off at the edge
    beside a flickering lamp: the reading lay 0.42 deg from n067, nearer n033. Such an LED is
    refused (``PairConfig.edge_px``); every reading lies within 0.2 deg of its own mote."""
    from tests.conftest import load_script

    rig = load_script("coded_survey").rig_for(5, 100, 320, "coded", None, 0.0, {}, False)
    survey_reads_every_visible_pair(rig, tmp_path / "s5", 0.2)


def test_a_focused_survey_resumes_to_the_uncut_readings(tmp_path):
    """Killed at the first refinement view, in the middle of them (clean and torn) and after
    the last: each resume records every view once (the ladder decides from earlier views only)."""
    cut_and_resume(parsed(ladder_rig(12, 160, "focus")), tmp_path, "r")


def test_a_header_without_the_ladder_lever_resumes_climbing():
    recorded = {k: v for k, v in LEGACY.items() if k != "ladder"} | {"levels": [1 / 9, 3 / 9, 1.0]}
    state = JournalState(JournalHeader(NodeMode.PLANAR, Gauge("cam0", "cam1"), 0.001, ["cam0", "cam1"], ["n0"],
                                       coded=recorded))
    rig = parsed(coded_rig(4, width=160))
    assert coded_settings(rig, None, state).ladder == "climb"
    assert coded_settings(rig).ladder == "focus"  # a new survey
    with pytest.raises(FglocError, match=r"--coded: ladder: j\.jsonl was started with ladder 'climb', got 'focus'"):
        coded_settings(rig, {"ladder": "focus"}, state, "j.jsonl")
    with pytest.raises(FglocError, match=r"coded\.ladder: expected one of climb, focus, got 'up'"):
        coded_settings(parsed(coded_rig(4, width=160) | {"coded": {"ladder": "up"}}))


def test_a_ladder_flag_that_disagrees_with_the_journal_is_refused_in_one_line(tmp_path, capsys):
    check_lever_refused_on_resume(coded_rig(6, width=160), tmp_path, capsys, "ladder=climb", "ladder", "ladder=focus")


def test_the_ladder_lever_is_schema_checked():
    check_lever_in_schema("ladder", "climb", "jump")
