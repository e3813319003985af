"""Inject head errors (:mod:`fgloc.core.head_model`) into a simulated survey.

:func:`inject_head_errors` moves every reading of a survey with truth by the
difference between what a head with the given calibration reads and what the
ideal head reads, so the noise draw is unchanged: the same survey with and
without head errors differ only by the head. :func:`typical_head_errors` draws
errors of the sizes issue 17 calls typical (tilt index 0.3 degree, collimation
and trunnion 0.2 degree, encoder scales 0.5 %, lever arm 0.05 % of the
baseline), with random signs and lever-arm direction; :func:`sample_head_errors`
draws a head from the population those sizes are the one-sigma spread of (zero-mean
Gaussian, :data:`fgloc.core.head_model.DEFAULT_PRIOR_SIGMAS`), the population the
self-calibration's prior describes: Monte Carlo runs that check its covariances
draw each run's heads from it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, bearing_pan_tilt, wrap_angle
from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS, head_pan_tilt
from fgloc.core.model import Survey

#: Magnitudes of typical head errors (rad, rad, rad, 1, 1, baseline units for the lever arm's length):
#: the population's one-sigma spread, equal to the self-calibration prior.
TYPICAL_MAGNITUDES: FloatArray = np.array(
    [np.deg2rad(0.3), np.deg2rad(0.2), np.deg2rad(0.2), 0.005, 0.005, 0.0005, 0.0005]
)


def typical_head_errors(camera_ids: list[str], rng: np.random.Generator) -> dict[str, FloatArray]:
    """Per camera a 7-vector with the typical magnitudes, random signs, lever arm |l| = 0.0005."""
    out = {}
    for cid in camera_ids:
        p = TYPICAL_MAGNITUDES * rng.choice([-1.0, 1.0], size=HEAD_DIM)
        ang = rng.uniform(0.0, 2.0 * np.pi)
        p[5], p[6] = 0.0005 * np.cos(ang), 0.0005 * np.sin(ang)
        out[cid] = p
    return out


def sample_head_errors(
    camera_ids: list[str], rng: np.random.Generator, sigmas: FloatArray = TYPICAL_MAGNITUDES
) -> dict[str, FloatArray]:
    """Per camera a 7-vector drawn from the population of heads: independent zero-mean
    Gaussians with one-sigma ``sigmas`` (default: the typical sizes, which are the prior)."""
    return {cid: np.asarray(sigmas, dtype=float) * rng.standard_normal(HEAD_DIM) for cid in camera_ids}


def parse_head_errors(text: str, camera_ids: list[str], rng: np.random.Generator) -> dict[str, FloatArray]:
    """``typical``, ``sampled`` or ``name=value,...`` (angles in degrees, scales in percent, lever arm in
    baseline units).

    ``typical``: :func:`typical_head_errors`; ``sampled``: :func:`sample_head_errors`, both per camera.
    Otherwise the same values apply to every camera. Raises :class:`FglocError` naming the bad item.
    """
    if text.strip() == "typical":
        return typical_head_errors(camera_ids, rng)
    if text.strip() == "sampled":
        return sample_head_errors(camera_ids, rng)
    p = np.zeros(HEAD_DIM)
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, _, value = item.partition("=")
        if name not in HEAD_PARAMETERS:
            raise FglocError(f"simulate: --head-errors: unknown parameter ({name!r}; one of {', '.join(HEAD_PARAMETERS)})")
        try:
            v = float(value)
        except ValueError:
            raise FglocError(f"simulate: --head-errors: {name} needs a number ({value!r})") from None
        if not np.isfinite(v):
            raise FglocError(f"simulate: --head-errors: {name} must be finite ({value!r})")
        i = HEAD_PARAMETERS.index(name)
        p[i] = np.deg2rad(v) if i <= 2 else v / 100.0 if i <= 4 else v
    return {cid: p.copy() for cid in camera_ids}


def inject_head_errors(survey: Survey, heads: dict[str, FloatArray]) -> Survey:
    """The survey with each camera's readings as its head ``heads[cid]`` (7,) would give them."""
    truth = survey.truth
    if truth is None:
        raise FglocError("head errors can only be injected into a survey with truth")
    rows = [j for j, o in enumerate(survey.observations) if o.camera in heads and np.any(heads[o.camera])]
    if not rows:
        return survey
    obs = [survey.observations[j] for j in rows]
    R = np.array([truth.cameras[o.camera].rotation for o in obs])
    c = np.array([truth.cameras[o.camera].position for o in obs])
    x = np.array([truth.nodes[o.node] for o in obs], dtype=float)
    q = np.einsum("nji,nj->ni", R, x - c)  # R^T (x - c): base frame
    params = np.array([heads[o.camera] for o in obs], dtype=float)
    ideal_pan, ideal_tilt = bearing_pan_tilt(q)
    pan, tilt, _, _ = head_pan_tilt(q, params, jacobians=False)
    new_pan = wrap_angle(np.array([o.pan for o in obs]) + (pan - ideal_pan))
    new_tilt = np.clip(np.array([o.tilt for o in obs]) + (tilt - ideal_tilt), -np.pi / 2, np.pi / 2)
    observations = list(survey.observations)
    for k, j in enumerate(rows):
        observations[j] = replace(obs[k], pan=float(new_pan[k]), tilt=float(new_tilt[k]))
    return replace(survey, observations=observations)
