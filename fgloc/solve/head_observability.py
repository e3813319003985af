"""Observability of the head parameters: their data-only information, ranks and the determinable subset.

:func:`head_information` linearizes the data factors (no head prior) and eliminates poses
and nodes (Schur complement, block by block); :func:`head_observability` reports, per camera
and parameter group, the numerical rank of that information and the data-only standard
deviation of each parameter. ``HeadModel.FULL`` refuses (one-line error) a parameter whose
information is rank deficient; ``AUTO`` leaves it out (:func:`determinable_subset`) and its
score test weighs the rest by the same information (:mod:`fgloc.solve.head_selection`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.core.head_model import (
    DEFAULT_PRIOR_SIGMAS,
    HEAD_DIM,
    extend_vector,
    head_dim,
    head_groups,
    lever_group,
    zoom_groups,
)
from fgloc.core.model import Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.head_problem import SelfCalibrationProblem, build_self_calibration_problem
from fgloc.solve.joint import SolverOptions

#: Relative singular-value tolerance of the numerical rank.
RANK_TOL = 1e-12
#: Readings a zoom group needs before its lever arm counts as determinable: with one reading
#: the two lever-arm components absorb its two residuals exactly, with two they leave two
#: residual dof to check four numbers; from three the group's readings over-determine it.
MIN_ZOOM_READINGS = 3


def head_information(problem: SelfCalibrationProblem, values: gtsam.Values) -> tuple[FloatArray, list[tuple[str, int]]]:
    """Data-only Fisher information of the head parameters with poses and nodes eliminated.

    Returns the matrix (in the whitened units of the parameters themselves) and
    its rows as (camera id, parameter index). Uses the bearings and the gauge, no head prior.

    ``J_h' (I - P_x) J_h`` with ``P_x`` the projection on the pose and node columns, computed
    by block elimination instead of a dense least squares (4 s at 1000 nodes x 4 cameras):
    each node's 2x2 / 3x3 block is eliminated from the sum of its readings' normal equations,
    then the poses from the small pose-and-head system. The gauge prior pins the poses' null
    space; it does not change the heads' information (at the ideal head, where this is
    linearized, the gauge moves no head parameter).
    """
    assert problem.heads is not None
    problem.prepare(values)
    head_keys = set(problem.head_keys.values())
    sub = gtsam.NonlinearFactorGraph()
    for i in range(problem.graph.size()):
        f = problem.graph.at(i)
        if not set(f.keys()) <= head_keys:  # every factor but the head priors
            sub.add(f)
    linear = sub.linearize(values)
    node_keys = set(problem.node_keys.values())
    dims = values.dims()
    # Global columns: cameras first, then heads (rows of the result), in a fixed order.
    global_keys = list(problem.camera_keys.values()) + list(problem.head_keys.values())
    offset, gcol = 0, {}
    for k in global_keys:
        gcol[k] = slice(offset, offset + int(dims[k]))
        offset += int(dims[k])
    n_cam = sum(int(dims[k]) for k in problem.camera_keys.values())
    lam = np.zeros((offset, offset))
    per_node: dict[int, list[tuple[FloatArray, FloatArray]]] = {}
    for i in range(linear.size()):
        factor: gtsam.JacobianFactor = linear.at(i)  # type: ignore[assignment]
        if factor is None:
            continue
        A = np.asarray(factor.jacobian()[0])
        A_g = np.zeros((A.shape[0], offset))
        A_n: FloatArray = np.zeros((A.shape[0], 0))
        node = None
        col = 0
        for k in factor.keys():
            d = int(dims[k])
            if k in node_keys:
                node, A_n = k, A[:, col:col + d]
            else:
                A_g[:, gcol[k]] = A[:, col:col + d]
            col += d
        if node is None:
            lam += A_g.T @ A_g
        else:
            per_node.setdefault(node, []).append((A_n, A_g))
    for blocks in per_node.values():
        A_n = np.vstack([b[0] for b in blocks])
        A_g = np.vstack([b[1] for b in blocks])
        h_ng = A_n.T @ A_g
        lam += A_g.T @ A_g - h_ng.T @ np.linalg.pinv(A_n.T @ A_n) @ h_ng
    lam = 0.5 * (lam + lam.T)
    c, h = slice(0, n_cam), slice(n_cam, offset)
    info = lam[h, h] - lam[h, c] @ np.linalg.solve(lam[c, c], lam[c, h])
    labels: list[tuple[str, int]] = []
    for cid in problem.head_keys:
        labels += [(cid, i) for i in problem.active[cid]]
    return 0.5 * (info + info.T), labels


def head_observability(
    survey: Survey, estimate: InitialEstimate, prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS,
    exclude: frozenset[int] = frozenset(),
) -> tuple[dict[str, dict[str, int]], dict[str, FloatArray]]:
    """Fisher rank per camera and parameter group, and each parameter's data-only std.

    Linearized at ``estimate`` with ideal heads. ``ranks[cid][group]`` is the
    numerical rank of that group's (Schur-complemented) information, its size
    when fully determined; ``data_std[cid]`` (the camera's extended vector, 7 for one
    zoom) is inf where the data say nothing. A zoom group with fewer than
    :data:`MIN_ZOOM_READINGS` readings has rank 0 and inf for its lever arm.
    """
    return observability_from_information(whitened_head_information(survey, estimate, prior_sigmas, exclude))


@dataclass(frozen=True)
class HeadInformation:
    """The data-only information of every camera's head parameters (all its zooms' lever arms),
    poses and nodes eliminated, in prior-sigma units (``info``), its rows as (camera, extended
    index) (``labels``), each row's prior sigma (``scale``), the camera's zoom groups
    (``zooms``) and the lever-arm rows of zoom groups with too few readings (``thin``)."""

    info: FloatArray
    labels: list[tuple[str, int]]
    scale: FloatArray
    zooms: dict[str, tuple[float | None, ...]]
    thin: set[tuple[str, int]]


def whitened_head_information(
    survey: Survey, estimate: InitialEstimate, prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS,
    exclude: frozenset[int] = frozenset(),
) -> HeadInformation:
    """:class:`HeadInformation` linearized at ``estimate`` with ideal heads (one dense-free
    computation, shared by observability, the determinable subset and ``auto``'s test)."""
    problem = _all_parameters_problem(survey, estimate, exclude)
    info, labels = head_information(problem, problem.initial)
    scale = np.array([extend_vector(prior_sigmas, len(problem.zooms[c]))[i] for c, i in labels])
    zooms = {cid: tuple(problem.zooms[cid]) for cid in problem.head_keys}
    return HeadInformation(info * np.outer(scale, scale), labels, scale, zooms, _thin_levers(problem))


def observability_from_information(
    hi: HeadInformation,
) -> tuple[dict[str, dict[str, int]], dict[str, FloatArray]]:
    """:func:`head_observability` from :func:`whitened_head_information`."""
    info_n, labels, scale, thin = hi.info, hi.labels, hi.scale, hi.thin
    ranks: dict[str, dict[str, int]] = {}
    data_std: dict[str, FloatArray] = {}
    for cid in dict.fromkeys(c for c, _ in labels):
        rows = [r for r, (c, _) in enumerate(labels) if c == cid]
        ranks[cid] = {}
        for group, idx in head_groups(hi.zooms[cid]).items():
            sel = [r for r in rows if labels[r][1] in idx]
            sv = np.linalg.svd(info_n[np.ix_(sel, sel)], compute_uv=False)
            ranks[cid][group] = 0 if (cid, idx[0]) in thin else int(
                np.sum(sv > RANK_TOL * max(np.max(np.abs(info_n)), 1e-300)))
        std = np.full(head_dim(len(hi.zooms[cid])), np.inf)
        # Data-only std of each parameter with all others of every camera free (pseudo-inverse).
        w, v = np.linalg.eigh(0.5 * (info_n + info_n.T))
        good = w > RANK_TOL * max(w.max(), 1e-300)
        cov_n = (v[:, good] / w[good]) @ v[:, good].T
        for r in rows:
            null_part = np.sum(v[r, ~good] ** 2)
            thin_r = (cid, labels[r][1]) in thin
            std[labels[r][1]] = np.inf if null_part > 1e-6 or thin_r else math.sqrt(max(cov_n[r, r], 0.0)) * scale[r]
        data_std[cid] = std
    return ranks, data_std


def _all_parameters_problem(survey: Survey, estimate: InitialEstimate, exclude: frozenset[int],
                            options: SolverOptions = SolverOptions()) -> SelfCalibrationProblem:
    """The extended problem with every parameter of every camera (all its zooms' lever arms), no prior."""
    zooms, _ = zoom_groups(survey)
    all_active = {cid: tuple(range(head_dim(len(zooms[cid])))) for cid in survey.camera_ids
                  if cid in estimate.cameras}
    return build_self_calibration_problem(survey, estimate, all_active, options=options, exclude=exclude,
                                          with_prior=False)


def _thin_levers(problem: SelfCalibrationProblem) -> set[tuple[str, int]]:
    """(camera, extended index) of the lever-arm entries whose zoom group has fewer than
    :data:`MIN_ZOOM_READINGS` readings in ``problem`` (only with several zooms: a camera's one
    lever arm is judged by the rank alone, as before zoom groups)."""
    heads = problem.heads
    assert heads is not None
    out: set[tuple[str, int]] = set()
    for cid, key in problem.head_keys.items():
        if len(problem.zooms[cid]) <= 1:
            continue
        mine = heads.zoom_group[heads.head_keys == key]
        for i in problem.active[cid]:
            g = lever_group(i)
            if g is not None and int(np.sum(mine == g)) < MIN_ZOOM_READINGS:
                out.add((cid, i))
    return out


#: Order in which AUTO admits parameters when the survey cannot determine them all (the
#: lever arms of further zoom groups, extended indices 7, 8, ..., come last).
ADMIT_ORDER = (0, 3, 1, 2, 4, 5, 6)


def determinable_subset(
    survey: Survey, estimate: InitialEstimate, exclude: frozenset[int] = frozenset(),
    prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS,
) -> dict[str, tuple[int, ...]]:
    """A largest set of head parameters with full-rank information, admitted greedily in
    :data:`ADMIT_ORDER` (camera by camera for each parameter); the rest stay pinned. A zoom
    group with fewer than :data:`MIN_ZOOM_READINGS` readings keeps its lever arm pinned."""
    return determinable_from_information(whitened_head_information(survey, estimate, prior_sigmas, exclude))


def determinable_from_information(hi: HeadInformation) -> dict[str, tuple[int, ...]]:
    """:func:`determinable_subset` from :func:`whitened_head_information`."""
    info_n, labels, thin = hi.info, hi.labels, hi.thin
    tol = RANK_TOL * max(float(np.max(np.abs(info_n))), 1e-300)
    chosen: list[int] = []
    widest = max((head_dim(len(z)) for z in hi.zooms.values()), default=HEAD_DIM)
    for i in ADMIT_ORDER + tuple(range(HEAD_DIM, widest)):
        for cid in hi.zooms:
            if (cid, i) not in labels or (cid, i) in thin:
                continue
            r = labels.index((cid, i))
            trial = chosen + [r]
            if np.linalg.eigvalsh(info_n[np.ix_(trial, trial)])[0] > tol:
                chosen = trial
    out: dict[str, tuple[int, ...]] = {}
    for r in chosen:
        cid, i = labels[r]
        out[cid] = tuple(sorted(out.get(cid, ()) + (i,)))
    return out
