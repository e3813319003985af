"""View planner: every target covered, with fewer views than a plain grid."""

from __future__ import annotations

import math

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.view_planner import box_targets, coverage, neighbour_px, plan_refinement, plan_views


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
