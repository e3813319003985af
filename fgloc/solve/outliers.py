"""Outlier readings of a solved survey: deletion residuals, flagging, consensus re-placement.

A reading is judged by its *deletion residual*: the (pan, tilt) residual at the
estimate with the reading itself left out of its node's information, whitened
by its predicted covariance (chi-square, 2 dof, under the noise model). Angles
in radians, positions in the gauge frame (baseline = 1). Used by
:func:`fgloc.solve.joint.solve_survey`; nothing here builds or solves a graph.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.geometry import bearing_pan_tilt, pan_tilt_bearing, pan_tilt_jacobian, pan_tilt_residual
from fgloc.core.model import FlaggedObservation, NodeMode, Survey
from fgloc.init.planar import consensus_ground_point, ground_hits
from fgloc.init.start import InitialEstimate

#: chi-square quantile (2 dof) above which a reading's squared whitened residual is
#: implausible: P = 1 - 1e-6 (about 5.3 sigma), so clean surveys lose no readings
#: while gross detection errors (degrees, i.e. tens of sigma) stand out.
FLAG_CHI2 = 2.0 * np.log(1e6)

#: Rounds of "solve without the flagged readings, re-check all readings".
MAX_FLAG_ROUNDS = 4


def deletion_residuals(survey: Survey, estimate: InitialEstimate, included: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis norm of every reading's residual with the reading itself left out.

    For reading k of node j: ``r^T S^-1 r`` with ``S = sigma^2 I + J Sigma_j J^T``,
    where J is d(pan, tilt)/d(node position) and ``Sigma_j`` the node's
    covariance from its other included readings (cameras held fixed). Under the
    noise model it is chi-square with 2 degrees of freedom, also where a reading
    is very sensitive to the node (near the pole, pan moves a lot for a small
    shift). NaN where the camera or node has no estimate or no other reading
    determines the node.
    """
    t = survey.observation_table
    dim = survey.mode.position_dim
    n_obs = len(t)
    r = np.full((n_obs, 2), np.nan)
    jac = np.full((n_obs, 2, dim), np.nan)
    for i, cid in enumerate(survey.camera_ids):
        cam = estimate.cameras.get(cid)
        if cam is None:
            continue
        rows = np.flatnonzero(t.camera_index == i)
        have = np.array([survey.node_ids[j] in estimate.nodes for j in t.node_index[rows]], dtype=bool)
        rows = rows[have]
        if not len(rows):
            continue
        pts = np.array([estimate.nodes[survey.node_ids[j]] for j in t.node_index[rows]])
        q = (pts - cam.position) @ cam.rotation
        pan, tilt = bearing_pan_tilt(q)
        r[rows] = pan_tilt_residual(t.pan[rows], t.tilt[rows], pan, tilt)
        jac[rows] = (pan_tilt_jacobian(q) @ cam.rotation.T)[:, :, :dim]
    valid = np.all(np.isfinite(r), axis=1)
    info = np.zeros((n_obs, dim, dim))
    info[valid] = np.einsum("mki,mkj->mij", jac[valid], jac[valid]) / t.sigma[valid, None, None] ** 2
    node_info = np.zeros((len(survey.node_ids), dim, dim))
    use = valid & included
    np.add.at(node_info, t.node_index[use], info[use])
    loo = node_info[t.node_index] - np.where(use[:, None, None], info, 0.0)
    out = np.full(n_obs, np.nan)
    k = np.flatnonzero(valid)
    if not len(k):
        return out
    # Batched: eigenvalues tell whether the other readings determine the node.
    eig = np.linalg.eigvalsh(loo[k])
    ok = eig[:, 0] > 1e-12 * np.maximum(eig[:, -1], 1e-300)
    k = k[ok]
    cov = np.linalg.inv(loo[k])
    S = t.sigma[k, None, None] ** 2 * np.eye(2) + jac[k] @ cov @ np.transpose(jac[k], (0, 2, 1))
    out[k] = np.einsum("mi,mi->m", r[k], np.linalg.solve(S, r[k][..., None])[..., 0])
    return out


def replace_by_consensus(survey: Survey, estimate: InitialEstimate) -> None:
    """Re-place every planar node with three or more readings at the consensus of its
    readings' ground points (z = 0, gauge frame) under the estimated cameras, when at
    least two of them agree; ``estimate.nodes`` is updated in place."""
    t = survey.observation_table
    cam_ids = survey.camera_ids
    order = np.argsort(t.node_index, kind="stable")  # rows of each node, found once (not O(n m))
    bounds = np.searchsorted(t.node_index[order], np.arange(len(survey.node_ids) + 1))
    for j in np.flatnonzero(np.bincount(t.node_index, minlength=len(survey.node_ids)) >= 3):
        rows = order[bounds[j] : bounds[j + 1]]
        rows = rows[[cam_ids[c] in estimate.cameras for c in t.camera_index[rows]]]
        if len(rows) < 3:
            continue
        cams = [estimate.cameras[cam_ids[c]] for c in t.camera_index[rows]]
        dirs = np.array([c.rotation @ b for c, b in zip(cams, pan_tilt_bearing(t.pan[rows], t.tilt[rows]))])
        pts, tol, ok = ground_hits(np.array([c.position for c in cams]), dirs, float(np.median(t.sigma[rows])))
        if ok.sum() >= 3:
            xy, inliers = consensus_ground_point(pts[ok], tol[ok])
            if inliers.sum() >= 2:
                estimate.nodes[survey.node_ids[j]] = np.array([xy[0], xy[1], 0.0])


def flag_readings(
    survey: Survey, estimate: InitialEstimate, observation_index: np.ndarray, flag_chi2: float
) -> tuple[list[FlaggedObservation], dict[str, str]]:
    """Readings with an implausible residual, and nodes whose readings cannot be told apart.

    Only the readings at ``observation_index`` (indices into ``survey.observations``,
    those in the solved problem) are judged, against ``estimate`` (gauge frame, e.g.
    the solver's values); a reading is implausible when its squared deletion
    residual (:func:`deletion_residuals`, whitened) exceeds ``flag_chi2``.

    A node read exactly twice (planar: either reading alone places it; 3d: two
    readings are the minimum) cannot say which of its two readings is wrong:
    both are flagged and the node is reported unlocalized rather than guessed.
    """
    obs_index = observation_index
    included = np.zeros(len(survey.observations), dtype=bool)
    included[obs_index] = True
    m2 = deletion_residuals(survey, estimate, included)[obs_index]
    r = np.sqrt(m2)
    bad = m2 > flag_chi2
    node_of = survey.observation_table.node_index[obs_index]
    counts = np.bincount(node_of, minlength=len(survey.node_ids))
    ambiguous_nodes = set(node_of[bad & (counts[node_of] <= 2)].tolist())
    bad |= np.isin(node_of, list(ambiguous_nodes))
    flagged = [
        FlaggedObservation(
            camera=survey.observations[k].camera,
            node=survey.observations[k].node,
            index=int(k),
            whitened_residual=float(r[i]),
        )
        for i, k in enumerate(obs_index)
        if bad[i]
    ]
    reasons = {
        survey.node_ids[j]: "its two readings disagree (a gross error in one of them) and cannot be told apart"
        for j in sorted(ambiguous_nodes)
    }
    return flagged, reasons


def reflag(
    survey: Survey,
    estimate: InitialEstimate,
    previous: frozenset[int],
    ambiguous: dict[str, str],
    flag_chi2: float,
) -> tuple[list[FlaggedObservation], dict[str, str]]:
    """Flag readings implausible under ``estimate``; readings of undecidable nodes stay flagged.

    Every reading is judged, including the ``previous``ly flagged ones (indices into
    ``survey.observations``), which are left out of the node information; ``ambiguous``
    maps undecidable node ids to their reason and is returned unchanged.

    Planar nodes with three or more readings are first re-placed by consensus of
    all their readings' ground points under the estimated cameras, so a node the
    robust solve left at a bad reading's ray is pulled back to where its good
    readings agree (``estimate`` is updated in place).
    """
    t = survey.observation_table
    if survey.mode is NodeMode.PLANAR:
        replace_by_consensus(survey, estimate)
    included = ~np.isin(np.arange(len(t)), list(previous))
    m2 = deletion_residuals(survey, estimate, included)
    r = np.sqrt(m2)
    amb_idx = {survey.node_ids.index(n) for n in ambiguous}
    bad = (m2 > flag_chi2) | (np.isnan(m2) & ~included)
    bad |= np.isin(t.node_index, list(amb_idx))
    flagged = [
        FlaggedObservation(survey.observations[k].camera, survey.observations[k].node, int(k),
                           float(r[k]) if np.isfinite(r[k]) else float("inf"))
        for k in np.flatnonzero(bad)
    ]
    return flagged, ambiguous
