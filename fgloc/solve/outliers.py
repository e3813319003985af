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


def _node_positions(survey: Survey, estimate: InitialEstimate) -> np.ndarray:
    """(n_nodes, 3) estimated node positions in survey node order; NaN rows where none."""
    pos = np.full((len(survey.node_ids), 3), np.nan)
    for j, nid in enumerate(survey.node_ids):
        p = estimate.nodes.get(nid)
        if p is not None:
            pos[j] = p
    return pos


def deletion_residuals(survey: Survey, estimate: InitialEstimate, included: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis norm of every reading's residual with the reading itself left out.

    For reading k of node j: ``r^T S^-1 r`` with ``S = sigma^2 I + J Sigma_j J^T``,
    where J is d(pan, tilt)/d(node position) and ``Sigma_j`` the node's
    covariance from its other included readings (cameras held fixed). Under the
    noise model it is chi-square with 2 degrees of freedom, also where a reading
    is very sensitive to the node (near the pole, pan moves a lot for a small
    shift). NaN where the camera or node has no estimate or no other reading
    determines the node. One vectorized pass over all readings (node sums by
    ``np.add.at``), no loop over nodes.
    """
    t = survey.observation_table
    dim = survey.mode.position_dim
    n_obs = len(t)
    r = np.full((n_obs, 2), np.nan)
    jac = np.full((n_obs, 2, dim), np.nan)
    node_pos = _node_positions(survey, estimate)
    have_node = np.all(np.isfinite(node_pos), axis=1)[t.node_index]
    for i, cid in enumerate(survey.camera_ids):
        cam = estimate.cameras.get(cid)
        if cam is None:
            continue
        rows = np.flatnonzero((t.camera_index == i) & have_node)
        if not len(rows):
            continue
        q = (node_pos[t.node_index[rows]] - cam.position) @ cam.rotation
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


def _segment_median(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """(n_groups,) ``np.median`` of ``values`` within each group (NaN for empty groups)."""
    order = np.lexsort((values, group))
    v, g = values[order], group[order]
    starts = np.searchsorted(g, np.arange(n_groups + 1))
    counts = np.diff(starts)
    lo = starts[:-1] + np.maximum(counts - 1, 0) // 2
    hi = starts[:-1] + counts // 2
    out = np.full(n_groups, np.nan)
    has = counts > 0
    out[has] = (v[lo[has]] + v[hi[has]]) / 2.0
    return out


#: Nodes with at most this many ground hits get the consensus in one batched pass per
#: hit count; nodes with more (many repeats) go through :func:`consensus_ground_point`.
_BATCHED_CONSENSUS_HITS = 64


def replace_by_consensus(survey: Survey, estimate: InitialEstimate) -> None:
    """Re-place every planar node with three or more readings at the consensus of its
    readings' ground points (z = 0, gauge frame) under the estimated cameras, when at
    least two of them agree; ``estimate.nodes`` is updated in place.

    The same 1-point consensus as :func:`fgloc.init.planar.consensus_ground_point`,
    batched: ground hits of all readings at once, then one ``(nodes, h, h)``
    agreement table per hit count h; only nodes with more than
    ``_BATCHED_CONSENSUS_HITS`` hits are handled one by one.
    """
    t = survey.observation_table
    cam_ids = survey.camera_ids
    n_nodes = len(survey.node_ids)
    placed = np.array([c in estimate.cameras for c in cam_ids], dtype=bool)
    rotations = np.array([estimate.cameras[c].rotation if p else np.eye(3) for c, p in zip(cam_ids, placed)])
    positions = np.array([estimate.cameras[c].position if p else np.zeros(3) for c, p in zip(cam_ids, placed)])
    rows = np.flatnonzero(placed[t.camera_index])
    node = t.node_index[rows]
    n_rows = np.bincount(node, minlength=n_nodes)
    sigma = _segment_median(t.sigma[rows], node, n_nodes)  # per node, over its placed readings
    ci = t.camera_index[rows]
    dirs = np.einsum("mij,mj->mi", rotations[ci], pan_tilt_bearing(t.pan[rows], t.tilt[rows]))
    pts, tol, ok = ground_hits(positions[ci], dirs, sigma[node])  # type: ignore[arg-type]
    ok &= n_rows[node] >= 3
    rows, node, pts, tol = rows[ok], node[ok], pts[ok], tol[ok]
    order = np.argsort(node, kind="stable")  # hits grouped by node, reading order within a node
    node, pts, tol = node[order], pts[order], tol[order]
    starts = np.searchsorted(node, np.arange(n_nodes + 1))
    hits = np.diff(starts)
    new_xy = np.full((n_nodes, 2), np.nan)
    for h in np.unique(hits[hits >= 3]):
        js = np.flatnonzero(hits == h)
        if h > _BATCHED_CONSENSUS_HITS:
            for j in js:
                seg = slice(starts[j], starts[j + 1])
                xy, inliers = consensus_ground_point(pts[seg], tol[seg])
                if inliers.sum() >= 2:
                    new_xy[j] = xy
            continue
        idx = starts[js][:, None] + np.arange(h)[None, :]  # (nj, h)
        p, tl = pts[idx], tol[idx]  # (nj, h, 2), (nj, h)
        dist = np.hypot(p[:, :, None, 0] - p[:, None, :, 0], p[:, :, None, 1] - p[:, None, :, 1])
        agree = dist < tl[:, :, None] + tl[:, None, :]
        counts = agree.sum(axis=2)
        # Most agreeing hits, ties to the sharpest, then the first (lexsort((tol, -counts))[0]).
        best_tol = np.where(counts == counts.max(axis=1, keepdims=True), tl, np.inf)
        best = np.argmin(best_tol, axis=1)
        inliers = agree[np.arange(len(js)), best]  # (nj, h)
        w = np.where(inliers, 1.0 / tl**2, 0.0)
        xy = (w[:, :, None] * p).sum(axis=1) / w.sum(axis=1)[:, None]
        good = inliers.sum(axis=1) >= 2
        new_xy[js[good]] = xy[good]
    for j in np.flatnonzero(np.isfinite(new_xy[:, 0])):
        estimate.nodes[survey.node_ids[j]] = np.array([new_xy[j, 0], new_xy[j, 1], 0.0])


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
