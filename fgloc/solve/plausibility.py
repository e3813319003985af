"""Is a solution physically possible, and do the readings fit it as the noise model says?

Two checks of a solved survey, independent of the solver that produced it:

* **Goodness of fit.** Under the noise model (independent Gaussian pan and tilt
  errors of standard deviation sigma, radians) the sum of the squared whitened
  residuals of the readings used, ``chi2 = sum(((measured - predicted) / sigma)^2)``
  (pan wrapped), is chi-square distributed with ``dof = 2 M - p`` degrees of
  freedom: M readings used (flagged ones left out), p free parameters (6 per
  camera; 2 per planar node or 3 per 3d node; minus the gauge's 4 in planar mode:
  translation in the plane, turn about z, scale; 7 in 3d: translation, rotation,
  scale). ``p_value`` is the chance of a chi2 at least this large under the model
  (Wilson-Hilferty); below :data:`POOR_FIT_P` the readings do not fit any scene
  with the stated sigma: gross errors left in, a wrong sigma, or nonsense. Having
  flagged readings removed, a good survey's chi2 runs slightly below ``dof``.
* **Cameras on the +z side** (planar mode): the contract puts the nodes on z = 0
  and the cameras above it; a camera at z <= 0 is a problem. A tilt sign flipped in
  every reading mirrors the scene in each base's x-y plane, which bearings explain
  exactly by heads hanging upside down above the plane: that is physically possible
  (ceiling mounts), so it is reported as a note naming the cameras, not a problem.

The 3d gauge fixes no ground plane, so only the fit is judged there.
"""

from __future__ import annotations

import math

import numpy as np

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_residual
from fgloc.core.model import FitReport, NodeMode, Result, Survey

#: p-value of chi2 below which a fit is called poor (the readings do not fit the model).
POOR_FIT_P = 1e-3

#: Parameters the gauge removes: planar (x, y shift, turn about z, scale); 3d (similarity).
GAUGE_FREEDOMS = {NodeMode.PLANAR: 4, NodeMode.THREE_D: 7}


def chi2_upper_tail(chi2: float, dof: int) -> float:
    """P(X >= chi2) for X chi-square with ``dof`` degrees of freedom (Wilson-Hilferty cube root;
    absolute error below 1e-3 from 10 dof up, far below the :data:`POOR_FIT_P` decision's needs)."""
    if dof <= 0:
        return math.nan
    if chi2 <= 0:
        return 1.0
    k = float(dof)
    z = ((chi2 / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / math.sqrt(2.0 / (9.0 * k))
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def fit_statistics(survey: Survey, result: Result) -> tuple[float, int, int]:
    """(chi2, dof, readings used): whitened residuals of the readings whose camera and node have
    estimates, flagged ones left out (see the module docstring)."""
    t = survey.observation_table
    flagged = np.zeros(len(t), dtype=bool)
    flagged[[f.index for f in result.flagged if 0 <= f.index < len(t)]] = True
    chi2, used = 0.0, 0
    node_pos = np.full((len(survey.node_ids), 3), np.nan)
    for j, nid in enumerate(survey.node_ids):
        if nid in result.nodes:
            node_pos[j] = result.nodes[nid].position
    for i, cid in enumerate(survey.camera_ids):
        cam = result.cameras.get(cid)
        if cam is None:
            continue
        rows = np.flatnonzero((t.camera_index == i) & ~flagged)
        rows = rows[np.isfinite(node_pos[t.node_index[rows], 0])]
        if not len(rows):
            continue
        q = (node_pos[t.node_index[rows]] - cam.position) @ cam.rotation
        pan, tilt = bearing_pan_tilt(q)
        r = pan_tilt_residual(t.pan[rows], t.tilt[rows], pan, tilt) / t.sigma[rows, None]
        chi2 += float(np.sum(r * r))
        used += len(rows)
    params = 6 * len(result.cameras) + survey.mode.position_dim * len(result.nodes) - GAUGE_FREEDOMS[survey.mode]
    return chi2, 2 * used - params, used


def assess(survey: Survey, result: Result, least_squares: bool = True) -> FitReport:
    """Goodness of fit and physical plausibility of ``result`` (a solution of ``survey``).

    The chi-square judgement holds for the least-squares solution (the joint solve) only;
    with ``least_squares=False`` (e.g. the subset-averaging baseline, whose estimate is not
    the minimum of the cost) chi2 is reported but a large one is not a problem.
    """
    chi2, dof, used = fit_statistics(survey, result)
    p = chi2_upper_tail(chi2, dof)
    problems: list[str] = []
    notes: list[str] = []
    if survey.mode is NodeMode.PLANAR:
        for cid, cam in result.cameras.items():
            z = float(cam.position[2])
            if not z > 0:
                problems.append(f"camera {cid} is not above the node plane (z = {z:.4g}); the contract puts "
                                "cameras on the +z side: is the tilt sign flipped?")
        # Not impossible (ceiling mounts hang heads upside down), but what a flipped tilt sign
        # produces from level heads: every reading's tilt mirrored is an upside-down base.
        upside_down = sorted(cid for cid, cam in result.cameras.items() if cam.rotation[2, 2] < 0)
        if upside_down:
            notes.append(f"camera(s) {', '.join(upside_down)} hang upside down (base z axis pointing down): "
                         "right for a ceiling mount; for heads standing upright the tilt sign is flipped")
    if least_squares and dof > 0 and p < POOR_FIT_P:
        problems.append(f"the readings do not fit: chi2 {chi2:.4g} for {dof} degrees of freedom "
                        f"(they scatter {math.sqrt(chi2 / dof):.3g} x the stated sigma; p = {p:.2g})")
    return FitReport(chi2=chi2, dof=dof, readings=used, p_value=p, problems=problems, notes=notes)
