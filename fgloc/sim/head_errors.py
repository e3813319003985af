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

A real head also has a limited pan range (an EVI-D70 or SNC-RZ25N turns +-170 degrees,
an EVI-D100 +-100 degrees): ``pan_range`` of :func:`inject_head_errors` drops the readings
whose mechanical pan the head could not take (:func:`mechanical_pan`,
:func:`limit_pan_range`). Without it a simulated head can look straight behind itself,
across the +-180 degree seam where the model's pan-scale reading jumps.

Zoom: the optical centre moves with zoom. ``zoom_levers`` (:data:`ZoomLevers`, camera id ->
zoom -> ``(l_y, l_z)``, survey units) gives a camera's lever arm at the zooms listed; a
reading taken at such a zoom (``Observation.zoom``) sees it instead of its head vector's
(which stays the lever arm of every other zoom and of readings without a zoom).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, bearing_pan_tilt, wrap_angle
from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS, ZOOM_DIGITS, head_pan_tilt
from fgloc.core.model import Survey

log = logging.getLogger(__name__)

#: Magnitudes of typical head errors (rad, rad, rad, 1, 1, baseline units for the lever arm's length):
#: the population's one-sigma spread, equal to the self-calibration prior.
TYPICAL_MAGNITUDES: FloatArray = np.array(
    [np.deg2rad(0.3), np.deg2rad(0.2), np.deg2rad(0.2), 0.005, 0.005, 0.0005, 0.0005]
)


#: Per camera, zoom (fraction of the optical range) -> lever arm ``(l_y, l_z)`` at that zoom.
ZoomLevers = dict[str, dict[float, tuple[float, float]]]


def lever_at(zoom_levers: ZoomLevers | None, camera: str, zoom: float | None) -> tuple[float, float] | None:
    """The lever arm ``zoom_levers`` gives ``camera`` at ``zoom`` (None: not listed)."""
    if zoom_levers is None or zoom is None or camera not in zoom_levers:
        return None
    for z, lever in zoom_levers[camera].items():
        if round(float(z), ZOOM_DIGITS) == round(float(zoom), ZOOM_DIGITS):
            return (float(lever[0]), float(lever[1]))
    return None


def reading_heads(survey: Survey, heads: dict[str, FloatArray],
                  zoom_levers: ZoomLevers | None = None) -> FloatArray:
    """(M, 7) the head vector each observation sees: its camera's ``heads`` entry (zero when
    absent) with the lever arm of the reading's zoom where ``zoom_levers`` lists it."""
    out = np.zeros((len(survey.observations), HEAD_DIM))
    for j, o in enumerate(survey.observations):
        out[j] = heads.get(o.camera, np.zeros(HEAD_DIM))
        lever = lever_at(zoom_levers, o.camera, o.zoom)
        if lever is not None:
            out[j, 5:7] = lever
    return out


def sample_zoom_levers(camera_ids: list[str], zooms: list[float], rng: np.random.Generator,
                       sigma: float = float(TYPICAL_MAGNITUDES[5])) -> ZoomLevers:
    """Per camera and zoom a lever arm drawn from the population (zero-mean Gaussian, ``sigma``
    per component, survey units; default the typical 0.05 % of the baseline = the prior)."""
    return {c: {float(z): (float(sigma * rng.standard_normal()), float(sigma * rng.standard_normal()))
                for z in zooms} for c in camera_ids}


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


def mechanical_pan(survey: Survey, heads: dict[str, FloatArray] | None = None,
                   zoom_levers: ZoomLevers | None = None) -> FloatArray:
    """Per observation the true mechanical pan phi (rad, in (-pi, pi]) at which the camera's head
    (``heads[cid]``, ideal when absent) looks at the node: the encoder reading divided by
    ``1 + pan_scale``, from the survey's truth."""
    truth = survey.truth
    if truth is None:
        raise FglocError("a mechanical pan needs a survey with truth")
    obs = survey.observations
    if not obs:
        return np.zeros(0)
    heads = heads or {}
    R = np.array([truth.cameras[o.camera].rotation for o in obs])
    c = np.array([truth.cameras[o.camera].position for o in obs])
    x = np.array([truth.nodes[o.node] for o in obs], dtype=float)
    q = np.einsum("nji,nj->ni", R, x - c)  # R^T (x - c): base frame
    params = reading_heads(survey, heads, zoom_levers)
    pan, _, _, _ = head_pan_tilt(q, params, jacobians=False)
    return np.asarray(pan / (1.0 + params[:, 3]), dtype=float)


def limit_pan_range(
    survey: Survey, pan_range: float, heads: dict[str, FloatArray] | None = None,
    zoom_levers: ZoomLevers | None = None,
) -> tuple[Survey, list[int]]:
    """The survey without the readings whose true mechanical pan ``|phi|`` exceeds ``pan_range``
    (rad; a head limited to +-pan_range cannot take them), and the indices of the dropped
    readings in ``survey.observations``. ``heads`` as in :func:`mechanical_pan`."""
    if not pan_range > 0.0:
        raise FglocError(f"pan range must be positive ({pan_range!r} rad)")
    phi = mechanical_pan(survey, heads, zoom_levers)
    dropped = [int(j) for j in np.flatnonzero(np.abs(phi) > pan_range)]
    if not dropped:
        return survey, []
    gone = set(dropped)
    kept = [o for j, o in enumerate(survey.observations) if j not in gone]
    return replace(survey, observations=kept), dropped


def inject_head_errors(
    survey: Survey, heads: dict[str, FloatArray], pan_range: float | None = None,
    zoom_levers: ZoomLevers | None = None,
) -> Survey:
    """The survey with each camera's readings as its head ``heads[cid]`` (7,) would give them
    (at a zoom ``zoom_levers`` lists, with that zoom's lever arm).

    ``pan_range`` (rad, None = unlimited): readings whose true mechanical pan lies beyond
    +-pan_range are dropped first (:func:`limit_pan_range`, logged at INFO with their count),
    as a head with that range could not take them.
    """
    if pan_range is not None:
        survey, dropped = limit_pan_range(survey, pan_range, heads, zoom_levers)
        if dropped:
            log.info("pan range +-%.1f deg: dropped %d of %d readings", np.rad2deg(pan_range), len(dropped),
                     len(survey.observations) + len(dropped))
    return _inject(survey, heads, zoom_levers)


def _inject(survey: Survey, heads: dict[str, FloatArray], zoom_levers: ZoomLevers | None = None) -> Survey:
    truth = survey.truth
    if truth is None:
        raise FglocError("head errors can only be injected into a survey with truth")
    every = reading_heads(survey, heads, zoom_levers)
    rows = [j for j in range(len(survey.observations)) if np.any(every[j])]
    if not rows:
        return survey
    obs = [survey.observations[j] for j in rows]
    R = np.array([truth.cameras[o.camera].rotation for o in obs])
    c = np.array([truth.cameras[o.camera].position for o in obs])
    x = np.array([truth.nodes[o.node] for o in obs], dtype=float)
    q = np.einsum("nji,nj->ni", R, x - c)  # R^T (x - c): base frame
    params = every[rows]
    ideal_pan, ideal_tilt = bearing_pan_tilt(q)
    pan, tilt, _, _ = head_pan_tilt(q, params, jacobians=False)
    new_pan = wrap_angle(np.array([o.pan for o in obs]) + (pan - ideal_pan))
    new_tilt = np.clip(np.array([o.tilt for o in obs]) + (tilt - ideal_tilt), -np.pi / 2, np.pi / 2)
    observations = list(survey.observations)
    for k, j in enumerate(rows):
        observations[j] = replace(obs[k], pan=float(new_pan[k]), tilt=float(new_tilt[k]))
    return replace(survey, observations=observations)
