"""Pair and group decoding in the field plan: only crowded groups of exactly two (three), at the measured rate."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.field_plans import group_decoding, pair_decoding, pair_rate_table
from fgloc.survey.view_planner import neighbour_px, plan_refinement

INTR = CameraIntrinsics.from_fov(640, 480, 65.0)


def _at_px(offsets_px: list[tuple[float, float]], tilt: float = -0.3) -> np.ndarray:
    """(N, 2) pan-tilt of targets at pixel offsets (dx, dy) near (0, tilt), tangent plane."""
    d = np.asarray(offsets_px, float)
    return np.column_stack([d[:, 0] / (INTR.fx * math.cos(tilt)), tilt + d[:, 1] / INTR.fy])


SCENE = _at_px([(0.0, 0.0), (3.0, 0.0),  # a pair, a third mote 9 px away (index 8)
                (100.0, 0.0), (102.0, 1.0), (104.0, 2.0),  # a chain of three: no pair
                (200.0, 0.0),  # alone
                (300.0, 0.0), (300.0, 2.5),  # a pair, nothing near
                (12.0, 0.0)])


def test_only_groups_of_exactly_two_and_their_third_mote() -> None:
    pd = pair_decoding(INTR, SCENE, 4.0, 1.0, np.random.default_rng(0))
    assert sorted(map(tuple, pd.pairs.tolist())) == [(0, 1), (6, 7)]
    assert pd.resolved.tolist() == [True, True, False, False, False, False, True, True, False]
    third = dict(zip(map(tuple, pd.pairs.tolist()), pd.third_px.tolist()))
    assert third[(0, 1)] == pytest.approx(9.0, abs=0.05) and third[(6, 7)] == math.inf
    none = pair_decoding(INTR, SCENE, 4.0, 0.0, np.random.default_rng(0))
    assert not none.resolved.any() and none.resolved_pairs == 0


def test_field_rows_halve_vertical_distances() -> None:
    pt = _at_px([(0.0, 0.0), (0.0, 6.0), (50.0, 0.0)])  # 6 px apart in frames, 3 in fields
    assert len(pair_decoding(INTR, pt, 4.0, 1.0, np.random.default_rng(0)).pairs) == 0
    assert len(pair_decoding(INTR, pt, 4.0, 1.0, np.random.default_rng(0), field_rows=True).pairs) == 1


def test_rate_is_the_share_resolved() -> None:
    grid = np.array([(-1.5 + 0.15 * i, -1.0 + 0.05 * j) for i in range(20) for j in range(20)])
    partner = grid + np.column_stack([2.0 / (INTR.fx * np.cos(grid[:, 1])), np.zeros(len(grid))])
    pt = np.vstack([grid, partner])  # 400 pairs 2 px apart, 25 px and more from each other
    pd = pair_decoding(INTR, pt, 4.0, 0.7, np.random.default_rng(5))
    assert len(pd.pairs) == 400
    assert abs(pd.resolved_pairs / 400 - 0.7) < 3.5 * math.sqrt(0.7 * 0.3 / 400)  # binomial, 3.5 sigma


def test_resolved_pairs_leave_the_refinement() -> None:
    pd = pair_decoding(INTR, SCENE, 4.0, 1.0, np.random.default_rng(0))
    crowded = neighbour_px(SCENE, INTR) < 4.0
    assert crowded.sum() == 7
    before = plan_refinement(INTR, SCENE, 4.0, share_tiles=True)[0]
    after = plan_refinement(INTR, SCENE, 4.0, needed=~pd.resolved, share_tiles=True)[0]
    assert sum(rp.targets for rp in after) == sum(rp.targets for rp in before) - 4 == 3


def test_rate_by_third_mote_distance() -> None:
    near = np.vstack([SCENE, _at_px([(306.0, 0.0)])])  # a third mote 6 px from the pair (6, 7)
    pd = pair_decoding(INTR, near, 4.0, ((8.0, 0.0), (math.inf, 1.0)), np.random.default_rng(0))
    third = dict(zip(map(tuple, pd.pairs.tolist()), pd.third_px.tolist()))
    assert third[(6, 7)] == pytest.approx(6.0, abs=0.05)
    assert pd.resolved[[0, 1]].all() and not pd.resolved[[6, 7]].any()  # 9 px: rate 1; 6 px: rate 0
    alone = pair_decoding(INTR, SCENE, 4.0, ((8.0, 0.0), (math.inf, 1.0)), np.random.default_rng(0))
    assert alone.resolved[[6, 7]].all()  # no third mote at all (inf): the last bin


def test_rate_table_parsing() -> None:
    assert pair_rate_table("0.8") == ((math.inf, 0.8),)
    assert pair_rate_table("6:0.1,8:0.4,inf:0.9") == ((6.0, 0.1), (8.0, 0.4), (math.inf, 0.9))
    for bad in ("1.2", "8:0.4,6:0.1,inf:0.9", "6:0.1", ""):
        with pytest.raises(ValueError):
            pair_rate_table(bad)


def test_group_decoding_only_groups_of_exactly_three() -> None:
    """The chain (2, 3, 4) is the one group of three; pairs and singles are no group; at rate
    1 its motes are resolved, at 0 none; the fourth mote's distance picks the table's rate."""
    gd = group_decoding(INTR, SCENE, 4.0, 1.0, np.random.default_rng(0))
    assert gd.groups.tolist() == [[2, 3, 4]] and gd.fourth_px.tolist() == [math.inf]
    assert np.flatnonzero(gd.resolved).tolist() == [2, 3, 4] and gd.resolved_groups == 1
    assert not group_decoding(INTR, SCENE, 4.0, 0.0, np.random.default_rng(0)).resolved.any()
    near = np.vstack([SCENE, _at_px([(110.0, 2.0)])])  # a fourth mote 6 px from (104, 2)
    gn = group_decoding(INTR, near, 4.0, ((8.0, 0.0), (math.inf, 1.0)), np.random.default_rng(0))
    assert gn.fourth_px[0] == pytest.approx(6.0, abs=0.05) and not gn.resolved.any()
    four = np.vstack([SCENE, _at_px([(106.0, 3.0)])])  # the chain grows to four: no group of three
    assert len(group_decoding(INTR, four, 4.0, 1.0, np.random.default_rng(0)).groups) == 0


def test_group_rate_is_the_share_resolved() -> None:
    grid = np.array([(-1.5 + 0.15 * i, -1.0 + 0.05 * j) for i in range(20) for j in range(20)])
    cos = np.cos(grid[:, 1])
    pt = np.vstack([grid, grid + np.column_stack([2.0 / (INTR.fx * cos), np.zeros(len(grid))]),
                    grid + np.column_stack([1.0 / (INTR.fx * cos), np.full(len(grid), 2.0 / INTR.fy)])])
    gd = group_decoding(INTR, pt, 4.0, 0.4, np.random.default_rng(5))
    assert len(gd.groups) == 400
    assert abs(gd.resolved_groups / 400 - 0.4) < 3.5 * math.sqrt(0.4 * 0.6 / 400)  # binomial, 3.5 sigma


def test_group_lever_in_the_coded_readings() -> None:
    """With ``group_rate`` 1 the readings model reads every crowded group of exactly three in
    the wide views (its motes leave the refinement) and exactly (zero noise)."""
    from fgloc.core.model import CameraPose
    from fgloc.survey.coded_readings import CodedNoise, coded_observations

    rng = np.random.default_rng(4)  # 6 crowded groups of three over the two cameras
    cams = [CameraPose(np.array([0.0, 0.0, 0.1]), np.eye(3)), CameraPose(np.array([1.0, 0.0, 0.1]), np.eye(3))]
    nodes = np.column_stack([rng.uniform(0, 1, (150, 2)), np.zeros(150)])
    g = np.linspace(0, 1, 41)
    area = np.column_stack([np.repeat(g, 41), np.tile(g, 41), np.zeros(41 * 41)])
    ids = [f"n{j}" for j in range(150)]
    exact = CodedNoise(head_sigma=0.0, decoder_sigma_pan=0.0, decoder_sigma_tilt=0.0)
    off = coded_observations(["a", "b"], cams, ids, nodes, area, INTR, exact, np.random.default_rng(1))
    on = coded_observations(["a", "b"], cams, ids, nodes, area, INTR, replace(exact, group_rate=1.0),
                            np.random.default_rng(1))
    from fgloc.core.geometry import bearing_pan_tilt, world_to_base

    n_group = 0
    for cid, cam in zip(["a", "b"], cams):
        d = world_to_base(cam.rotation, cam.position, nodes)
        pt = np.column_stack(bearing_pan_tilt(d / np.linalg.norm(d, axis=1, keepdims=True)))
        n_group += int(group_decoding(INTR, pt, 4.0, 1.0, np.random.default_rng(0)).resolved.sum())
    assert n_group == 18
    # each group mote leaves the refinement (or the unresolved: no zoom separated it)
    assert (sum(on.refined.values()) + sum(on.unresolved.values())
            == sum(off.refined.values()) + sum(off.unresolved.values()) - n_group)
    truth = {}
    for cid, cam in zip(["a", "b"], cams):
        d = world_to_base(cam.rotation, cam.position, nodes)
        p, t = bearing_pan_tilt(d / np.linalg.norm(d, axis=1, keepdims=True))
        truth.update({(cid, ids[j]): (p[j], t[j]) for j in range(150)})
    for o in on.observations:
        tp, tt = truth[(o.camera, o.node)]
        assert abs(math.remainder(o.pan - tp, 2 * math.pi)) < 1e-9 and abs(o.tilt - tt) < 1e-9
