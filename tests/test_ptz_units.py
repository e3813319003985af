"""Counts <-> spec radians: signs, ranges, mounting, round trips (drivers/ptz_units.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.drivers.ptz_units import (
    CEILING,
    DESK,
    EVI_D30,
    EVI_D70,
    EVI_D100,
    Mounting,
    PanTiltUnits,
    PositionOutOfRangeError,
    camera_model,
    mounting,
)


def test_d100_limits_are_plus_minus_100_and_25_degrees() -> None:
    """protocols.md 1.8: FA60 (-1440) = -100 deg ... 05A0 = +100; FE98 (-360) = -25 ... 0168 = +25."""
    u = PanTiltUnits(EVI_D100, DESK)
    pan, tilt = u.to_spec(1440, 360)
    # device +pan = right = clockwise from above = spec negative; tilt up = up
    assert math.degrees(pan) == pytest.approx(-100.0)
    assert math.degrees(tilt) == pytest.approx(25.0)
    assert u.to_counts(math.radians(100.0), math.radians(-25.0)) == (-1440, -360)


def test_out_of_range_raises_with_degrees_in_the_message() -> None:
    u = PanTiltUnits(EVI_D100, DESK)
    with pytest.raises(PositionOutOfRangeError, match=r"pan 101.00 deg .*-100.0..100.0"):
        u.to_counts(math.radians(101.0), 0.0)
    with pytest.raises(PositionOutOfRangeError, match="tilt"):
        u.to_counts(0.0, math.radians(25.1))
    with pytest.raises(PositionOutOfRangeError):
        u.to_counts(float("nan"), 0.0)


@pytest.mark.parametrize("model", [EVI_D100, EVI_D30, EVI_D70])
@pytest.mark.parametrize("mount", [DESK, CEILING, Mounting("custom", -1, 1, pan_zero_deg=30.0, tilt_zero_deg=-5.0)])
def test_round_trip_over_the_whole_range_is_exact_in_counts(model, mount) -> None:
    """Every count pair on a grid (incl. the limits) survives counts -> spec -> counts unchanged."""
    u = PanTiltUnits(model, mount)
    for p in np.linspace(model.pan_min, model.pan_max, 37).round().astype(int):
        for t in (model.tilt_min, -1, 0, 1, model.tilt_max):
            assert u.to_counts(*u.to_spec(int(p), int(t))) == (int(p), int(t))


def test_ceiling_mount_sees_the_same_world_direction() -> None:
    """Physical check: a ceiling head is the desk head turned 180 deg about its forward (x) axis.

    The same device counts point the optical axis at the mirror image (y, z) -> (-y, -z)
    in a frame whose z is up; the spec bearing from the ceiling units must equal that
    rotated bearing.
    """
    desk, ceiling = PanTiltUnits(EVI_D100, DESK), PanTiltUnits(EVI_D100, CEILING)
    flip = np.diag([1.0, -1.0, -1.0])
    for counts in [(300, 100), (-1000, -200), (1440, 360), (0, -50)]:
        b_desk = pan_tilt_bearing(*desk.to_spec(*counts))  # in the head's own (upright) frame
        b_ceiling = pan_tilt_bearing(*ceiling.to_spec(*counts))
        np.testing.assert_allclose(b_ceiling, flip @ b_desk, atol=1e-12)


def test_zero_offset_and_wrap() -> None:
    u = PanTiltUnits(EVI_D70, Mounting("rotated", -1, 1, pan_zero_deg=170.0))
    pan, _ = u.to_spec(-2267, 0)  # device -170 -> spec +170 + 170 = 340 -> -20 deg
    assert math.degrees(pan) == pytest.approx(-20.0, abs=0.05)
    assert u.to_counts(pan, 0.0) == (-2267, 0)


def test_zoom_fraction() -> None:
    u = PanTiltUnits(EVI_D100)
    assert u.zoom_to_counts(1.0) == 0x4000 and u.zoom_to_counts(0.0) == 0
    assert u.zoom_from_counts(0x2000) == 0.5
    with pytest.raises(PositionOutOfRangeError):
        u.zoom_to_counts(1.5)


def test_lookup_names() -> None:
    assert camera_model("evi-d100") is EVI_D100 and camera_model("EVI-D31") is EVI_D30
    assert mounting("Ceiling") is CEILING
    with pytest.raises(FglocError, match="unknown model"):
        camera_model("EVI-X")
    with pytest.raises(FglocError, match="unknown mounting"):
        mounting("wall")
