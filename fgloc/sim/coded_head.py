"""Coded-survey-like off-centre readings through imperfect heads, straight from the head model.

A coded survey reads the head once per view and takes every decoded LED off-centre: its
pixel composed with the view's encoder readings by the ideal pixel -> pan-tilt composition.
:func:`off_centre_survey` gives a survey with truth such readings without rendering video:
each camera's views lie on a grid of encoder angles (spacing twice ``half_width``, a random
grid origin per camera, the pan wrapped to (-pi, pi]); a (camera, node) pair is read in the
view nearest the encoder readings that would centre it (:func:`fgloc.core.head_model.head_pan_tilt`),
so it sits up to ``half_width`` off the view's centre (default +-26 degrees in pan, +-17 in
tilt: the 90 x 74 degree wide views of the test rig less a margin); the reading is
:func:`fgloc.core.head_model.head_view_pan_tilt` at that view plus independent N(0, sigma)
noise per axis (the decoder's centroid error; the head's repeatability, shared by a view, is
left out). Each reading carries its view's angles (``Observation.view_angles``).

Radians; survey (baseline) length units.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgloc.core.geometry import FloatArray, wrap_angle
from fgloc.core.head_model import head_pan_tilt, head_view_pan_tilt
from fgloc.core.model import Observation, Survey
from fgloc.sim.head_errors import reading_heads

#: Half the spacing of the views' grid (pan, tilt), radians: the largest off-centre offset.
HALF_WIDTH: tuple[float, float] = (math.radians(26.0), math.radians(17.0))


def off_centre_survey(
    survey: Survey, heads: dict[str, FloatArray], rng: np.random.Generator, sigma: float,
    half_width: tuple[float, float] = HALF_WIDTH,
) -> Survey:
    """``survey``'s (camera, node) pairs read off-centre by heads ``heads`` (camera id -> (7,)):
    the readings a coded survey takes (module docstring), ``sigma`` radians of independent noise
    per axis (also the survey's ``sigma``). ``survey`` must have truth; its readings only name
    the pairs."""
    truth = survey.truth
    if truth is None:
        raise ValueError("off-centre readings need a survey with truth")
    obs = survey.observations
    params = reading_heads(survey, heads)
    R = np.array([truth.cameras[o.camera].rotation for o in obs]).reshape(-1, 3, 3)
    c = np.array([truth.cameras[o.camera].position for o in obs]).reshape(-1, 3)
    x = np.array([truth.nodes[o.node] for o in obs], dtype=float).reshape(-1, 3)
    q = np.einsum("nji,nj->ni", R, x - c)  # base frame
    centred_pan, centred_tilt, _, _ = head_pan_tilt(q, params, jacobians=False)
    step = 2.0 * np.asarray(half_width, dtype=float)
    origin = {cid: rng.uniform(0.0, 1.0, 2) * step for cid in survey.camera_ids}
    o0 = np.array([origin[o.camera] for o in obs]).reshape(-1, 2)
    view_pan = wrap_angle(o0[:, 0] + step[0] * np.round((wrap_angle(centred_pan - o0[:, 0])) / step[0]))
    view_tilt = np.clip(o0[:, 1] + step[1] * np.round((centred_tilt - o0[:, 1]) / step[1]), -0.5 * math.pi,
                        0.5 * math.pi)
    pan, tilt, _, _ = head_view_pan_tilt(q, params, view_pan, view_tilt, jacobians=False)
    pan = wrap_angle(pan + rng.normal(0.0, sigma, len(obs)))
    tilt = np.clip(tilt + rng.normal(0.0, sigma, len(obs)), -0.5 * math.pi, 0.5 * math.pi)
    out = [Observation(o.camera, o.node, float(pan[k]), float(tilt[k]), zoom=o.zoom, view_pan=float(view_pan[k]),
                       view_tilt=float(view_tilt[k])) for k, o in enumerate(obs)]
    return replace(survey, observations=out, sigma=float(sigma))


def centred_view(survey: Survey) -> Survey:
    """The same readings without their view angles: what a head model that takes every reading
    as centred sees (the comparison in docs/head-calibration.md)."""
    return replace(survey, observations=[replace(o, view_pan=None, view_tilt=None) for o in survey.observations])
