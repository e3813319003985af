"""GTSAM factors for pan-tilt localization: bearing factors and gauge priors."""

from fgloc.factors.baseline_prior import BaselinePrior, baseline_length_factor, ground_point_factor
from fgloc.factors.pan_tilt_factor import pan_tilt_error, pan_tilt_factor, planar_pan_tilt_factor

__all__ = [
    "BaselinePrior",
    "baseline_length_factor",
    "ground_point_factor",
    "pan_tilt_error",
    "pan_tilt_factor",
    "planar_pan_tilt_factor",
]
