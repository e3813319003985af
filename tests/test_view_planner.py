"""View planner: every target covered, with fewer views than a plain grid."""

from __future__ import annotations

import math

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.view_planner import box_targets, coverage, plan_views


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
