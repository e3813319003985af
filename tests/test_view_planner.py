"""View planner: every target covered, with fewer views than a plain grid."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.view_planner import (
    box_targets,
    coverage,
    fewest_views,
    needed_from,
    neighbour_px,
    plan_refinement,
    plan_views,
    whole_groups,
)


def test_box_is_covered_by_few_views() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    targets = box_targets(math.radians(-60), math.radians(60), math.radians(-40), math.radians(10), math.radians(2))
    views = plan_views(intr, targets, margin_px=12.0)
    cov = coverage(intr, targets, np.array(views), 12.0)
    assert cov.any(axis=0).all()
    # a 120 x 50 deg box: 2 x 2 fields of view of 65 x 51 deg is the area bound; grid search uses 3 x 2
    assert 3 <= len(views) <= 8


def test_views_ordered_nearest_first_and_near_nadir_wide() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    # a ring of pan around a steep tilt: a view at the nadir side covers a wide pan range
    targets = box_targets(math.radians(-40), math.radians(40), math.radians(-80), math.radians(-70), math.radians(1))
    views = plan_views(intr, targets)
    assert coverage(intr, targets, np.array(views), 12.0).any(axis=0).all()
    assert len(views) == 1


def test_fewest_views_beats_greedy_where_greedy_takes_the_biggest_view_first() -> None:
    # the classic trap: row 0 covers the most, but rows 1 and 2 alone cover everything
    cov = np.array([[1, 1, 1, 1, 0, 0],
                    [1, 1, 0, 0, 1, 0],
                    [0, 0, 1, 1, 0, 1]], dtype=bool)
    assert sorted(fewest_views(cov) or []) == [1, 2]


@pytest.mark.parametrize("seed", range(12))
def test_fewest_views_is_a_minimum_cover_by_brute_force(seed: int) -> None:
    import itertools

    rng = np.random.default_rng(seed)
    cov = rng.random((9, 24)) < 0.25
    need = cov.any(axis=0)
    chosen = fewest_views(cov)
    assert chosen is not None
    assert cov[chosen].any(axis=0)[need].all()
    smallest = next(k for k in range(1, 10) for rows in itertools.combinations(range(9), k)
                    if cov[list(rows)].any(axis=0)[need].all())
    assert len(chosen) == smallest


def _steep_box() -> tuple[CameraIntrinsics, np.ndarray, tuple[float, float]]:
    """A search box like a benchmark camera's (scripts/coded_survey.py, 100 motes, seed 3, cam0):
    95 deg of pan, tilt from -60 deg to 2 deg, a 640 x 480 image at fx 502 px; (intrinsics,
    targets, tilt limits)."""
    intr = CameraIntrinsics(fx=502.0, fy=502.0, cx=320.0, cy=240.0, width=640, height=480)
    lo, hi = math.radians(-60.0), math.radians(2.0)
    return intr, box_targets(math.radians(-225.0), math.radians(-130.0), lo, hi, 0.7 * 16.0 / 502.0), (lo, hi)


def test_minimal_tiling_covers_a_steep_box_in_fewer_views() -> None:
    intr, targets, (lo, hi) = _steep_box()
    greedy = plan_views(intr, targets, 16.0, tilt_limits=(lo, hi))
    fewest = plan_views(intr, targets, 16.0, tilt_limits=(lo, hi), minimal=True)
    for views in (greedy, fewest):
        assert coverage(intr, targets, np.array(views), 16.0).any(axis=0).all()
    assert len(fewest) < len(greedy), (len(fewest), len(greedy))
    assert plan_views(intr, targets, 16.0, tilt_limits=(lo, hi), minimal=True) == fewest  # the same plan again


def test_a_greedy_cover_larger_than_the_limit_is_kept(monkeypatch) -> None:
    # the steep box's greedy cover (5 views) above a limit of 4: kept as it is, no integer program
    import fgloc.survey.view_planner as vp

    intr, targets, (lo, hi) = _steep_box()
    greedy = plan_views(intr, targets, 16.0, tilt_limits=(lo, hi))
    solved: list[int] = []
    monkeypatch.setattr(vp, "fewest_views", lambda cov: solved.append(len(cov)) or None)
    monkeypatch.setattr(vp, "FEWEST_MAX_VIEWS", len(greedy) - 1)
    assert plan_views(intr, targets, 16.0, tilt_limits=(lo, hi), minimal=True) == greedy and solved == []
    monkeypatch.setattr(vp, "FEWEST_MAX_VIEWS", len(greedy))
    plan_views(intr, targets, 16.0, tilt_limits=(lo, hi), minimal=True)
    assert len(solved) == 1  # at the limit the program runs


def test_whole_groups_counts_a_view_only_for_groups_it_covers_whole() -> None:
    cov = np.array([[1, 1, 0, 0, 1],
                    [0, 1, 1, 0, 0]], dtype=bool)
    groups = np.array([0, 0, 1, 1, 2])
    # group 0: view 0 whole; group 1: no view whole (targets 2, 3 stay columns); group 2: view 0
    expected = np.array([[1, 1, 0, 0],
                         [0, 0, 1, 0]], dtype=bool)
    np.testing.assert_array_equal(whole_groups(cov, groups), expected)


def test_grouped_minimal_tiles_never_split_a_blob_between_two_tiles() -> None:
    # blobs as the zoom ladder chases them: each blob's 3 x 3 directions a few pixels apart;
    # the fewest tiles over the directions alone split some blob between two tiles' borders
    intr = CameraIntrinsics.from_fov(640, 480, 20.0)
    rng = np.random.default_rng(3)  # a draw whose fewest loose tiles split a blob (most do not)
    centres = np.column_stack([rng.uniform(-0.6, 0.6, 20), rng.uniform(-0.35, 0.0, 20)])
    offsets = np.array([(dp, dt) for dp in (-0.004, 0.0, 0.004) for dt in (-0.004, 0.0, 0.004)])
    targets = (centres[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
    groups = np.repeat(np.arange(len(centres)), len(offsets))

    def split(views: list[tuple[float, float]]) -> int:
        cov = coverage(intr, targets, np.array(views), 16.0)
        return sum(not cov[:, groups == g].all(axis=1).any() for g in range(len(centres)))

    loose = plan_views(intr, targets, 16.0, minimal=True)
    whole = plan_views(intr, targets, 16.0, minimal=True, groups=groups)
    assert coverage(intr, targets, np.array(whole), 16.0).any(axis=0).all()
    assert split(loose) > 0  # the trap the groups avoid
    assert split(whole) == 0
    assert len(whole) == len(loose)  # here at no extra tile


def test_nothing_to_cover() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    assert plan_views(intr, np.zeros((0, 2))) == []


def test_neighbour_px_matches_projection() -> None:
    # two targets near the image centre: tangent-plane distance = pixel distance in a view on them
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    from fgloc.camera.pixel_angles import pan_tilt_to_pixel

    pt = np.array([[0.3, -0.4], [0.3 + 0.004, -0.4 + 0.003], [1.5, 0.2]])
    d = neighbour_px(pt, intr)
    uv, _ = pan_tilt_to_pixel(intr, pt[:2, 0], pt[:2, 1], 0.302, -0.3985)
    assert d[0] == d[1]
    assert abs(d[0] - float(np.hypot(*(uv[0] - uv[1])))) < 0.02 * d[0]
    # one video field has every second row: vertical distances halve
    vert = np.array([[0.0, -0.2], [0.0, -0.2 + 0.01]])
    assert abs(neighbour_px(vert, intr, field_rows=True)[0] - 0.5 * neighbour_px(vert, intr)[0]) < 1e-9


def test_refinement_zooms_only_as_far_as_needed() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    pa = 1.0 / intr.fx  # rad per pixel at the wide end
    pairs = {3.0: (0.0, -0.3), 1.5: (0.6, -0.3), 0.6: (-0.6, -0.3), 0.2: (0.3, -0.8)}  # separation px -> place
    pts = [(-0.5, 0.2)]  # a lone target: never refined
    for sep, (p, t) in pairs.items():
        pts += [(p, t), (p + sep * pa / math.cos(t), t)]
    passes, lost = plan_refinement(intr, np.array(pts), 4.0, levels=(1 / 9, 3 / 9, 1.0))
    # 3 px needs 1.33x -> 2x level; 1.5 px needs 2.7x -> 4x; 0.6 px needs 6.7x -> 10x; 0.2 px: 20x, none
    assert [(round(rp.zoom, 3), rp.targets) for rp in passes] == [(0.111, 2), (0.333, 2), (1.0, 2)]
    assert lost == 2
    for rp in passes:  # each pass's views cover its targets at its zoom
        assert len(rp.views) == 1
    tele = intr.at_zoom(1.0)
    sep = pairs[0.6]
    cov = coverage(tele, np.array(pts[5:7]), np.array(passes[2].views), 12.0)
    assert cov.all() and sep[0] == -0.6


def _crowded_scene(seed: int, n: int) -> np.ndarray:
    """(pan, tilt) of motes on the unit square seen from a camera 0.1 above a corner."""
    from fgloc.core.geometry import bearing_pan_tilt, rot_z, world_to_base

    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(0, 1, (n, 2)), np.zeros(n)])
    d = world_to_base(rot_z(math.pi / 4), np.array([0.0, 0.0, 0.1]), pts)
    return np.column_stack(bearing_pan_tilt(d))


@pytest.mark.parametrize("seed", range(3))
def test_shared_tiles_cover_every_target_at_a_zoom_that_separates_it(seed: int) -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    pt = _crowded_scene(seed, 600)
    levels = (1 / 9, 3 / 9, 1.0)
    alone, lost_a = plan_refinement(intr, pt, 4.0, levels, field_rows=True)
    shared, lost_s = plan_refinement(intr, pt, 4.0, levels, field_rows=True, share_tiles=True)
    assert lost_a == lost_s
    assert sum(len(rp.views) for rp in shared) <= sum(len(rp.views) for rp in alone)
    assert [rp.zoom for rp in shared] == sorted(rp.zoom for rp in shared)  # recorded in ascending zoom
    need = 4.0 / np.maximum(neighbour_px(pt, intr, field_rows=True), 1e-12)
    served = np.zeros(len(pt), bool)
    for rp in shared:
        zi = intr.at_zoom(rp.zoom)
        cov = coverage(zi, pt, np.array(rp.views), 12.0).any(axis=0)
        served |= cov & (need <= zi.fx / intr.fx)  # in a tile whose zoom separates it
    crowded = need > 1.0
    reachable = need <= intr.at_zoom(1.0).fx / intr.fx
    assert served[crowded & reachable].all()
    assert lost_s == int((crowded & ~reachable).sum())


def test_needed_from_two_and_four_cameras() -> None:
    resolved = {"a": np.array([True, False, False, True]), "b": np.array([False, False, True, True])}
    need = needed_from(resolved)
    assert all(need[c].all() for c in resolved)  # two cameras: every target from both
    four = {"a": np.array([False, False, True]), "b": np.array([True, True, True]),
            "c": np.array([True, False, True]), "d": np.array([False, True, False])}
    need4 = needed_from(four)
    assert need4["a"].tolist() == [False, False, False]  # target 0: b, c; 1: b, d resolve it
    assert need4["d"].tolist() == [False, True, False]  # target 2: a, b, c resolve it
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    pt = _crowded_scene(0, 300)
    crowded = neighbour_px(pt, intr) < 4.0
    passes, lost = plan_refinement(intr, pt, 4.0, needed=~crowded)  # none needed: nothing refined or lost
    assert passes == [] and lost == 0


def _scene(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.3, 0.05, n)])


def test_colouring_separates_every_conflicting_pair() -> None:
    from fgloc.survey.view_planner import colour_conflicts, conflict_pairs

    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    for seed in range(40):  # random crowded scenes, frames and fields, plus random extra edges
        pt = _scene(seed, 60 + 10 * seed)
        pairs = conflict_pairs(pt, intr, 8.0, field_rows=seed % 2 == 1)
        d = neighbour_px(pt, intr, field_rows=seed % 2 == 1)
        in_pair = np.zeros(len(pt), bool)
        in_pair[pairs.ravel()] = True
        assert np.array_equal(in_pair, d < 8.0)  # the pairs are exactly the crowded targets' conflicts
        rng = np.random.default_rng(seed)
        extra = rng.integers(0, len(pt), (seed, 2))
        allp = np.vstack([pairs, extra[extra[:, 0] != extra[:, 1]]])
        colour = colour_conflicts(len(pt), allp)
        assert np.all(colour[allp[:, 0]] != colour[allp[:, 1]])
        assert np.all(colour[allp.ravel()] >= 0)
        lonely = np.setdiff1d(np.arange(len(pt)), allp.ravel())
        assert np.all(colour[lonely] == -1)


def test_bipartite_conflicts_get_two_colours() -> None:
    from fgloc.survey.view_planner import colour_conflicts

    rng = np.random.default_rng(3)
    for _ in range(30):
        n = int(rng.integers(4, 60))
        side = rng.integers(0, 2, n)
        a, b = np.flatnonzero(side == 0), np.flatnonzero(side == 1)
        if not len(a) or not len(b):
            continue
        pairs = np.column_stack([rng.choice(a, 3 * n), rng.choice(b, 3 * n)])
        colour = colour_conflicts(n, pairs)
        assert colour.max() == 1 and np.all(colour[pairs[:, 0]] != colour[pairs[:, 1]])
    odd = np.array([[0, 1], [1, 2], [2, 0]])  # a triangle needs three
    assert sorted(colour_conflicts(3, odd).tolist()) == [0, 1, 2]


def test_radio_rounds_cover_each_class_and_pause_separates() -> None:
    from fgloc.survey.field_plans import radio_separation
    from fgloc.survey.view_planner import conflict_pairs

    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        base = _scene(seed, 150)
        pts = {"a": base, "b": base[:, ::-1] * np.array([1.0, 0.4]) + rng.normal(0, 0.01, base.shape)}
        views = {c: plan_views(intr, p) for c, p in pts.items()}
        sep = radio_separation(intr, pts, views, 6.0, ("a", "b"))
        for c, p in pts.items():
            pairs = conflict_pairs(p, intr, 6.0)
            # lit together in no round: the two motes of a pair never share a class
            assert np.all(sep.colour[pairs[:, 0]] != sep.colour[pairs[:, 1]])
            assert not sep.leftover[c].any()
            rounds = sep.rounds[c]
            assert len(rounds) == sep.classes
            for rr in rounds:
                want = np.zeros(len(p), bool)
                want[pairs.ravel()] = True
                want &= sep.colour == rr.colour
                if rr.views:
                    seen = coverage(intr, p, np.array(rr.views), 12.0).any(axis=0)
                    assert np.all(seen[want]), "every conflicting mote of the class is re-recorded"
                else:
                    assert not want.any()
                assert len(rr.view_targets) == len(rr.views) and all(k > 0 for k in rr.view_targets)


def test_mote_beside_a_lamp_goes_to_zoom() -> None:
    from fgloc.survey.field_plans import radio_separation

    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    px = 1.0 / intr.fx  # about one pixel of pan at tilt 0
    pt = np.array([[0.0, 0.0], [2 * px, 0.0], [0.3, 0.0], [0.3 + 2 * px, 0.0], [-0.3, 0.0]])
    lamp = np.array([[-0.3 + 2 * px, 0.0]])
    views = [(0.0, 0.0)]
    sep = radio_separation(intr, {"a": pt}, {"a": views}, 4.0, ("a",), lamps={"a": lamp})
    assert sep.colour[0] != sep.colour[1] and sep.colour[2] != sep.colour[3] and sep.colour[4] == -1
    assert sep.leftover["a"].tolist() == [False, False, False, False, False]  # no mote crowds mote 4
    # a lamp beside a crowded pair: both motes of the pair go to zoom, not to a colour class
    pt2 = np.vstack([pt, [[-0.3 + 4 * px, 0.0]]])
    sep2 = radio_separation(intr, {"a": pt2}, {"a": views}, 4.0, ("a",), lamps={"a": lamp})
    assert sep2.leftover["a"].tolist() == [False, False, False, False, True, True]
    assert sep2.colour[4] == -1 and sep2.colour[5] == -1
    zoomed = radio_separation(intr, {"a": pt}, {"a": views}, 4.0, ())
    assert zoomed.leftover["a"].tolist() == [True, True, True, True, False] and not zoomed.rounds
