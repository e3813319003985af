"""The ``looks`` lever (fgloc/survey/coded_epipolar.py; docs/blink-codes.md "Looks near the
epipolar plane").

* A point anywhere on the reading camera's ray lies in the band's plane seen from the other
  camera; a direction tilted off the plane by an angle is that angle away; the gain is the
  ratio of the two ranges.
* The scale is the largest offset the survey's own twice-read motes show (divided by
  ``max(gain, 1)``), widened by ``SAFETY``; too few such motes measure none.
* The fallback then looks only at blobs inside the band; on a seeded scene with many
  occluded pairs it searches fewer nodes than ``"disk"`` and reads the same pairs.
* A journal whose header predates the lever resumes with ``"disk"``; the lever is schema-checked.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing
from fgloc.core.model import CameraPose
from fgloc.files.journal import read_journal
from fgloc.survey.coded import CodedSurvey
from fgloc.survey.coded_epipolar import (
    MIN_PAIRS,
    SAFETY,
    EpipolarBand,
    across_angles,
    across_scale,
    band,
    within_band,
)
from fgloc.survey.coded_levers import LEGACY, blobs_near
from fgloc.survey.session import run_survey
from tests.test_survey_coded import check_lever_in_schema, coded_rig, opened, parsed, resumed_and_new


def rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


A = CameraPose(np.array([0.0, 0.0, 0.1]), rotation_z(0.3))
B = CameraPose(np.array([1.0, 0.0, 0.12]), rotation_z(2.0))


def seen_from(pose: CameraPose, point: np.ndarray) -> tuple[float, float]:
    """(pan, tilt) of a world point in a camera's base frame."""
    pan, tilt = bearing_pan_tilt(pose.rotation.T @ (np.asarray(point, float) - pose.position))
    return float(pan), float(tilt)


def tilted_off(band_: EpipolarBand, direction: tuple[float, float], angle: float) -> tuple[float, float]:
    """``direction`` (in the band's plane) turned ``angle`` out of it, towards the normal."""
    d = pan_tilt_bearing(*direction)
    return tuple(float(x) for x in bearing_pan_tilt(math.cos(angle) * d + math.sin(angle) * band_.normal))


def test_the_readers_whole_ray_lies_in_the_plane_and_a_tilt_off_it_is_that_far() -> None:
    p = np.array([0.4, 0.7, 0.0])
    got = band(A.position, B.position, B.rotation, p)
    assert got is not None
    assert got.gain == pytest.approx(np.linalg.norm(p - A.position) / np.linalg.norm(p - B.position))
    assert abs(float(np.linalg.norm(got.normal)) - 1.0) < 1e-12
    # the range along A's ray is what the ground-plane placement gets wrong: none of it moves the plane
    along = [A.position + s * (p - A.position) for s in (0.3, 0.8, 1.0, 1.7, 4.0)]
    assert np.all(across_angles(np.array([seen_from(B, q) for q in along]), got) < 1e-9)
    for angle in (0.001, 0.01, 0.05):
        off = tilted_off(got, seen_from(B, p), angle)
        assert across_angles(np.array([off]), got)[0] == pytest.approx(angle, abs=1e-9)
    assert band(A.position, B.position, B.rotation, A.position + 2 * (B.position - A.position)) is None  # the baseline


def test_the_band_widens_with_the_gain_and_by_the_offset() -> None:
    flat = EpipolarBand(np.array([0.0, 0.0, 1.0]), 0.5)  # the plane z = 0 of the base frame: across = |tilt|
    steep = EpipolarBand(flat.normal, 3.0)
    tilts = np.array([[0.0, 0.009], [0.0, 0.011], [0.0, 0.029], [0.0, 0.031]])
    assert within_band(tilts, flat, 0.01, 0.0).tolist() == [True, False, False, False]  # gain below 1 counts as 1
    assert within_band(tilts, steep, 0.01, 0.0).tolist() == [True, True, True, False]
    assert within_band(tilts, flat, 0.01, 0.002).tolist() == [True, True, False, False]


def _twice_read(n: int, offsets: np.ndarray) -> tuple[dict, dict]:
    """``n`` motes read by both cameras; A reads each exactly, B each ``offsets[k]`` off the plane."""
    rng = np.random.default_rng(3)
    points = {f"n{k:02d}": np.array([rng.uniform(-0.5, 1.5), rng.uniform(0.3, 2.0), 0.0]) for k in range(n)}
    readings: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for k, (node, p) in enumerate(points.items()):
        b = band(A.position, B.position, B.rotation, p)
        assert b is not None
        readings[(node, "cam0")] = [seen_from(A, p)]
        readings[(node, "cam1")] = [tilted_off(b, seen_from(B, p), float(offsets[k]))]
    return readings, points


def test_the_scale_is_the_largest_twice_read_offset_over_its_gain_widened() -> None:
    poses = {"cam0": A, "cam1": B}
    offsets = np.linspace(0.0005, 0.004, MIN_PAIRS)
    readings, points = _twice_read(MIN_PAIRS, offsets)
    # seen from B, B's reading lies offsets[k] off A's plane; seen from A, A's reading lies off B's
    # plane by what B's tilt makes there, so the largest ratio over both orders is checked directly
    expected = 0.0
    for k, (node, p) in enumerate(points.items()):
        gain_b = np.linalg.norm(p - A.position) / np.linalg.norm(p - B.position)
        expected = max(expected, offsets[k] / max(gain_b, 1.0))
        ray_b = B.position + B.rotation @ pan_tilt_bearing(*readings[(node, "cam1")][0])
        plane_b = band(B.position, A.position, A.rotation, ray_b)
        assert plane_b is not None
        a_off = across_angles(np.array(readings[(node, "cam0")]), plane_b)[0]
        expected = max(expected, a_off / max(1.0 / gain_b, 1.0))
    assert across_scale(poses, readings, points) == pytest.approx(SAFETY * expected, rel=1e-9)
    fewer, fewer_points = _twice_read(MIN_PAIRS - 1, offsets)
    assert across_scale(poses, fewer, fewer_points) is None


def test_the_fallback_looks_only_at_blobs_inside_a_motes_band(tmp_path: Path) -> None:
    rig = parsed(coded_rig(30, 320))
    _opened, sim = opened(rig)
    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    at = (0.2, 0.0)
    off = (0.2, 0.045)  # 2.6 deg from the prediction, inside the 3 deg disk, 2.6 deg off the plane
    on = (0.23, 0.0)  # 1.7 deg along the plane
    coded.final_blobs["cam1"] = np.array([off, on])
    coded.bands = {"cam1": {"n1": EpipolarBand(np.array([0.0, 0.0, 1.0]), 0.8)}}  # the plane tilt = 0
    coded.across_scale = 0.01  # the band: 0.01 rad + 3 px of 160 px = 0.029 rad
    assert blobs_near(coded, "cam1", at, "n1") == [on]
    assert blobs_near(coded, "cam1", at, "n2") == [off]  # no band (two cameras read n2): the disk, thinned
    coded.final_blobs["cam1"] = np.array([off])
    assert blobs_near(coded, "cam1", at, "n1") == []  # nothing in the band: not found without a search
    coded.across_scale = None  # too few motes read twice to measure the band
    assert blobs_near(coded, "cam1", at, "n1") == [off]
    coded.across_scale = 0.01
    coded.settings = replace(coded.settings, looks="disk")
    assert blobs_near(coded, "cam1", at, "n1") == [off]


def test_with_fields_the_band_allows_half_the_separation_in_field_rows() -> None:
    """A field row spans twice a column's angle: a mote merged into a blob lies up to 3 field
    rows (3 px of 80, not of 160) off its centroid across a horizontal plane. Seed 5's recording
    3 at 1000 motes lost n661 so: its merged blob lay 1.04 deg off the plane, the band was 0.82."""
    data = coded_rig(30, 320)
    data["coded"] = {"video": "fields"}
    rig = parsed(data)
    _opened, sim = opened(rig)
    coded = CodedSurvey(rig, sim.open_head, sim.leds, sim)
    k = coded.intrinsics_at("cam1", coded.survey_zoom["cam1"])
    assert (k.fx, k.fy) == (160.0, 80.0)
    at = (0.2, 0.0)
    rows = (0.2, 0.01 + 2.5 / 80)  # 2.5 field rows beyond the scale: inside 3 rows, outside 3 columns
    beyond = (0.2, 0.01 + 3.5 / 80)
    coded.bands = {"cam1": {"n1": EpipolarBand(np.array([0.0, 0.0, 1.0]), 0.8)}}  # the plane tilt = 0
    coded.across_scale = 0.01
    coded.final_blobs["cam1"] = np.array([rows])
    assert blobs_near(coded, "cam1", at, "n1") == [rows]
    coded.final_blobs["cam1"] = np.array([beyond])
    assert blobs_near(coded, "cam1", at, "n1") == []


def _occluded_scene(looks: str, tmp_path: Path) -> tuple[int, float, set, set, int]:
    """100 motes with half the pairs occluded (seed 2), the predicted fallback after the level
    decoder at the fixed length with every unexplained blob climbing the ladder: the fallback
    searches 7 nodes with ``looks: disk``. Returns (nodes the fallback searched, their priced
    seconds, the (camera, node) pairs read, those journaled not found, how many of those say the
    band held no blob)."""
    data = coded_rig(100, 320, occlusion=0.5, seed=2)
    data["coded"] = {"fallback": "predicted", "decode": "levels", "length": "fixed", "ladder": "climb",
                     "looks": looks, "searches": "one", "levels": [2 / 9, 1.0]}
    rig = parsed(data)
    rig_opened, sim = opened(rig)
    out = tmp_path / looks
    run_survey(rig, out, opened=rig_opened)
    st = read_journal(out / "journal.jsonl")
    nodes = [r for r in st.field_times if r.get("scope") == "fallback_node"]
    read = {(c, n) for (n, c, _) in st.observations}
    assert not sim.scene.visible_pairs() - read, "every visible pair is read"
    in_band = sum("epipolar plane" in reason for reason in st.not_found.values())
    return len(nodes), sum(float(r["total_s"]) for r in nodes), read, set(st.not_found), in_band


def test_the_fallback_searches_fewer_nodes_inside_the_bands_and_reads_the_same_pairs(tmp_path: Path) -> None:
    disk = _occluded_scene("disk", tmp_path)
    epipolar = _occluded_scene("epipolar", tmp_path)
    assert epipolar[2] == disk[2]
    assert epipolar[3] == disk[3]
    assert epipolar[0] < disk[0]
    assert epipolar[1] < disk[1]
    assert epipolar[4] >= disk[0] - epipolar[0] and disk[4] == 0  # the nodes no longer searched say why


def test_an_old_header_resumes_with_the_disk_and_the_lever_is_schema_checked() -> None:

    assert LEGACY["looks"] == "disk"
    assert resumed_and_new("looks", fallback="round", levels=[2 / 9, 1.0]) == ("disk", "epipolar")
    check_lever_in_schema("looks", "disk", "ring")
