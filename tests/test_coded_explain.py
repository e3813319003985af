"""The ``explain`` lever (fgloc/survey/coded_ladder.py ``resolved_elsewhere``; docs/blink-codes.md
"Blobs another view resolved").

* A blob is resolved by another recording of the same camera, from another head or zoom, at
  its zoom or closer, with the blob's whole neighbourhood (6 px of the blob's own recording)
  inside its image, a reading in it and no refused blob of any kind in it; by nothing else.
* On a seeded 320 x 240 scene ``"views"`` records fewer refinement frames than
  ``"readings"`` and still reads every visible pair once, none mislabelled.
* ``"crowds"`` also resolves a wide-pass blob, only where the other recording read two motes or
  more in its clean neighbourhood; on a seeded scene it records fewer 3x frames than ``"views"``,
  every visible pair read, none mislabelled.
* A journal whose header predates the lever resumes with ``"readings"``; the lever is
  schema-checked.
"""

from __future__ import annotations

import numpy as np

from fgloc.camera.pixel_angles import pan_tilt_to_pixel, pixel_to_pan_tilt
from fgloc.survey.coded_ladder import CROWD_READINGS, SEPARATION_PX, resolved_elsewhere
from tests.test_coded_ladder import intrinsics_at
from tests.test_survey_coded import (
    check_lever_in_schema,
    coded_rig,
    cut_and_resume,
    parsed,
    resumed_and_new,
    view_records,
)
from tests.test_survey_coded_levers import survey_reads_every_visible_pair

HEAD = (0.3, -0.2)
TILE = 2 / 9


def blob_and_direction(k, zoom: float = TILE):
    """A blob at the image centre of a recording at ``HEAD`` and ``zoom``, and its (pan, tilt)."""
    intr = k(zoom)
    uv = (intr.cx, intr.cy)
    p, t = pixel_to_pan_tilt(intr, np.array(uv), *HEAD)
    return (uv, HEAD, zoom), (float(p), float(t))


def recording(k, direction, head, zoom, reading_px=None, refused_px=None, refused_kind="ambiguous"):
    """A journaled view record at ``head`` and ``zoom`` with a reading ``reading_px`` pixels
    right of where ``direction`` falls, and a refused blob ``refused_px`` pixels left of it."""
    intr = k(zoom)
    (u, v), _front = pan_tilt_to_pixel(intr, *direction, *head)
    rec = {"head": list(head), "zoom": zoom, "readings": [], "refused": []}
    if reading_px is not None:
        rec["readings"].append({"node": "n1", "u": float(u) + reading_px, "v": float(v)})
    if refused_px is not None:
        rec["refused"].append({"kind": refused_kind, "u": float(u) - refused_px, "v": float(v), "reason": "x"})
    return rec


def resolved(k, blob, views, rung: int = 1) -> bool:
    (out,) = resolved_elsewhere([blob], views, "cam0", rung, k, 0.0)
    return out


def test_a_blob_is_resolved_only_by_a_clean_neighbourhood_in_another_recording():
    k = intrinsics_at()
    blob, d = blob_and_direction(k)
    beside = (HEAD[0] + 0.03, HEAD[1] + 0.01)  # the tile beside: the blob lies well inside it
    near = SEPARATION_PX - 1.5
    assert resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, beside, TILE, near)})
    # no reading there: the light is not explained
    assert not resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, beside, TILE)})
    assert not resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, beside, TILE, SEPARATION_PX + 1.0)})
    # a refused blob in the neighbourhood, of any kind (a border cut too): a mote may hide there
    for kind in ("ambiguous", "rejected", "duplicate"):
        assert not resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, beside, TILE, near, near, kind)})
    assert resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, beside, TILE, near, SEPARATION_PX + 1.0)})
    # the blob's own view (the same head and zoom: its second recording too) resolves nothing
    assert not resolved(k, blob, {("cam0", "r1-000", 1): recording(k, d, HEAD, TILE, near)})
    # a coarser recording cannot separate what the blob's could not
    assert not resolved(k, blob, {("cam0", "w001", 0): recording(k, d, beside, 0.0, 0.5)})
    # a closer one can, its neighbourhood scaled to the same angle
    scale = k(1.0).fx / k(TILE).fx
    close = (HEAD[0] + 0.002, HEAD[1])
    assert resolved(k, blob, {("cam0", "r2-000", 0): recording(k, d, close, 1.0, near * scale)}, rung=2)
    assert not resolved(k, blob, {("cam0", "r2-000", 0): recording(k, d, close, 1.0, near * scale,
                                                                      (SEPARATION_PX - 0.5) * scale)}, rung=2)
    # views after the rung is planned, and the other camera's, are not looked at
    assert not resolved(k, blob, {("cam0", "r2-000", 0): recording(k, d, close, 1.0, near * scale)}, rung=1)
    assert not resolved(k, blob, {("cam1", "r1-001", 0): recording(k, d, beside, TILE, near)})


def test_a_crowd_rule_asks_for_two_readings_in_the_clean_neighbourhood():
    """``explain "crowds"`` on the wide pass's blobs: one reading in the other recording's clean
    neighbourhood is not enough (an isolated mote beside it may be the blob), two read apart are."""
    k = intrinsics_at()
    blob, d = blob_and_direction(k, zoom=0.0)
    beside = (HEAD[0] + 0.1, HEAD[1] + 0.03)  # the wide view beside: the blob lies well inside it
    near = SEPARATION_PX - 1.5
    one = recording(k, d, beside, 0.0, near)
    two = recording(k, d, beside, 0.0, near)
    two["readings"].append(dict(two["readings"][0], node="n2", u=two["readings"][0]["u"] - 2 * near))
    for rec, expected in ((one, (True, False)), (two, (True, True))):
        views = {("cam0", "w001", 0): rec}
        got = tuple(resolved_elsewhere([blob], views, "cam0", 0, k, 0.0, min_readings=m)[0] for m in (1, CROWD_READINGS))
        assert got == expected
    # a refused blob in the neighbourhood still resolves nothing, however many readings
    spoilt = dict(two, refused=[{"kind": "rejected", "u": two["readings"][0]["u"] - near, "v": two["readings"][0]["v"],
                                 "reason": "x"}])
    assert resolved_elsewhere([blob], {("cam0", "w001", 0): spoilt}, "cam0", 0, k, 0.0, min_readings=2) == [False]
    # the blob's own wide view resolves nothing
    assert resolved_elsewhere([blob], {("cam0", "w000", 0): dict(two, head=list(HEAD))}, "cam0", 0, k, 0.0,
                              min_readings=2) == [False]


def test_a_neighbourhood_cut_by_the_image_border_resolves_nothing():
    k = intrinsics_at()
    blob, d = blob_and_direction(k)
    intr = k(TILE)
    # a head that puts the blob 3 px inside the right-hand border: half its neighbourhood is outside
    for inside_px, expected in ((3.0, False), (SEPARATION_PX + 3.0, True)):
        u = intr.width - inside_px
        p, t = pixel_to_pan_tilt(intr, np.array([u, intr.cy]), *HEAD)
        head = (HEAD[0] - (float(p) - HEAD[0]), HEAD[1] - (float(t) - HEAD[1]))
        (bu, _bv), _ = pan_tilt_to_pixel(intr, *d, *head)
        assert abs(bu - u) < 1.0
        assert resolved(k, blob, {("cam0", "r1-001", 0): recording(k, d, head, TILE, -1.0)}) is expected


def rung_frames(tmp_path, explains: tuple[str, ...], rung: str) -> dict[str, int]:
    """The 320 x 240 rig (60 motes, seed 3) surveyed with each of ``explains``: every visible pair
    read once, none mislabelled; the frames each recorded in tiles of ``rung`` (``"r1"``, ...)."""
    frames = {}
    for explain in explains:
        data = coded_rig(60, 320, seed=3)
        # tiling "greedy": on this scene's fewest views "views" drops every 6x tile (0 frames) and
        # "crowds" no 3x tile, so neither test would compare anything
        data["coded"] = {"explain": explain, "tiling": "greedy"}
        out = tmp_path / explain
        survey_reads_every_visible_pair(parsed(data), out)
        frames[explain] = sum(r["frames"] for r in view_records(out / "journal.jsonl") if r["view"].startswith(rung))
    return frames


def test_views_records_fewer_refinement_frames_and_reads_every_visible_pair(tmp_path):
    """The second rung's tiles (6x) are not planned over blobs the tile beside resolved at 3x;
    every visible pair is still read once, none mislabelled."""
    frames = rung_frames(tmp_path, ("readings", "views"), "r2")
    assert 0 < frames["views"] < frames["readings"], frames


def test_crowds_records_fewer_first_rung_frames_and_reads_every_visible_pair(tmp_path):
    """3x tiles are not planned over wide-pass blobs where another wide view read a crowd apart
    cleanly; every visible pair is still read once, none mislabelled."""
    frames = rung_frames(tmp_path, ("views", "crowds"), "r1")
    assert 0 < frames["crowds"] < frames["views"], frames


def test_a_survey_explaining_by_views_resumes_to_the_uncut_readings(tmp_path):
    """Killed at the first refinement tile, in the middle of them (clean and torn) and after the last:
    the rule decides from journaled views only, so each resume records every view once."""
    cut_and_resume(parsed(coded_rig(100, 320, seed=1)), tmp_path, "r")


def test_a_header_without_the_explain_lever_resumes_with_readings():
    assert resumed_and_new("explain", ladder="focus", levels=[2 / 9, 1.0]) == ("readings", "crowds")  # old, new


def test_the_explain_lever_is_schema_checked():
    check_lever_in_schema("explain", "readings", "guess")
