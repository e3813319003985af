"""Self-calibrating joint solve: head errors (:mod:`fgloc.core.head_model`) estimated with the survey.

The extended problem is the reference graph of :func:`fgloc.solve.joint.build_problem`
(same keys, gauge and start) with every pan-tilt factor replaced by a head-model
factor (:mod:`fgloc.factors.pan_tilt_head_factor`), one head-calibration Vector
per camera (key ``h<i>``) holding the parameters chosen for it, and a zero-mean
datasheet prior on each. It is optimized by the same Levenberg-Marquardt and
its node covariances come from the same marginal code.

Observability. :func:`head_observability` linearizes the data factors (no head
prior) and reports, per camera and parameter group, the numerical rank of the
head parameters' Fisher information after the poses and nodes are eliminated
(Schur complement), and the data-only standard deviation of each parameter.
``HeadModel.FULL`` refuses (one-line :class:`SelfCalibrationError`) a parameter
whose information is rank deficient; ``AUTO`` leaves it out (pins it at zero).
Weakly determined parameters stay in and lean on their datasheet prior.

Model selection (``AUTO``): the Bayes score test of the ideal head against heads
from the prior's population (:mod:`fgloc.solve.head_selection`, level 1 %). Rejected: every
determinable parameter of every camera is estimated with its prior (none is
dropped for being insignificant: its effect would be missing from the
covariance). Not rejected: the ideal head's estimates, with covariances equal to
their mean squared error under the extended model's posterior (its covariance
plus the squared offset of the ideal estimate from its estimate).
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.head_model import (
    DEFAULT_PRIOR_SIGMAS,
    HEAD_DIM,
    HEAD_PARAMETERS,
    SHARED_DIM,
    extend_vector,
    head_dim,
    head_groups,
    lever_group,
    parameter_names,
    reading_params,
    zoom_groups,
)
from fgloc.core.model import FlaggedObservation, Result, Survey
from fgloc.factors.pan_tilt_head_factor import HeadFactorSet, head_prior_factor
from fgloc.init.start import InitialEstimate
from fgloc.solve.head_selection import ScoreTest, bayes_score_test
from fgloc.solve.joint import (
    LocalizationProblem,
    RobustKernel,
    SolverOptions,
    build_problem,
    collect_result,
    estimate_from_values,
    optimize,
    solve_survey,
)

logger = logging.getLogger(__name__)

head_key = gtsam.symbol_shorthand.H


class SelfCalibrationError(FglocError):
    """The survey cannot determine the head parameters asked for."""


class HeadModel(str, enum.Enum):
    """Which head parameters to estimate: none, all determinable (or refuse), or as the data support."""

    IDEAL = "ideal"
    FULL = "full"
    AUTO = "auto"


#: Relative singular-value tolerance of the numerical rank.
RANK_TOL = 1e-12
#: Level of the plain likelihood-ratio test, reported beside the Bayes score test that decides.
LR_ALPHA = 0.05
#: Readings a zoom group needs before its lever arm counts as determinable: with one reading
#: the two lever-arm components absorb its two residuals exactly, with two they leave two
#: residual dof to check four numbers; from three the group's readings over-determine it.
MIN_ZOOM_READINGS = 3


def chi2_quantile(p: float, dof: int) -> float:
    """Chi-square quantile: exact for 1 and 2 dof, Wilson-Hilferty above (within 1 % for p in [0.9, 0.999])."""
    if dof == 1:
        return 2.0 * _erfinv(p) ** 2
    z = math.sqrt(2.0) * _erfinv(2.0 * p - 1.0)
    if dof == 2:
        return -2.0 * math.log(1.0 - p)
    a = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - a + z * math.sqrt(a)) ** 3)


def _erfinv(y: float) -> float:
    """Inverse error function (Giles' single-precision approximation refined by Newton)."""
    w = -math.log((1.0 - y) * (1.0 + y))
    if w < 5.0:
        w -= 2.5
        c = [2.81022636e-08, 3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087,
             -0.00125372503, -0.00417768164, 0.246640727, 1.50140941]
    else:
        w = math.sqrt(w) - 3.0
        c = [-0.000200214257, 0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773,
             -0.0076224613, 0.00943887047, 1.00167406, 2.83297682]
    x = c[0]
    for ci in c[1:]:
        x = x * w + ci
    x *= y
    for _ in range(2):
        x -= (math.erf(x) - y) / (2.0 / math.sqrt(math.pi) * math.exp(-x * x))
    return x


@dataclass
class CameraHeadEstimate:
    """One camera's head calibration estimate.

    ``values`` (7,) in :data:`HEAD_PARAMETERS` order (zero where not estimated);
    ``std`` (7,) their marginal standard deviations (0 where not estimated);
    ``estimated`` the parameter names in the model; ``data_std`` the data-only
    standard deviation of each parameter (inf where rank deficient).
    """

    values: FloatArray
    std: FloatArray
    estimated: tuple[str, ...]
    data_std: FloatArray
    covariance: FloatArray | None = None
    #: The camera's zoom groups: with several, ``values``/``std``/``data_std`` are extended
    #: vectors (one lever arm per zoom, :mod:`fgloc.core.head_model`) and ``estimated`` names
    #: the lever arms ``lever_y@<zoom>``.
    zooms: tuple[float | None, ...] = (None,)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the entries of ``values`` (:func:`fgloc.core.head_model.parameter_names`)."""
        return parameter_names(self.zooms)

    def block(self) -> dict:
        """This camera's entry of the result's ``head_calibration`` block. ``values``/``std``
        stay 7-vectors in :data:`HEAD_PARAMETERS` order (the first zoom group's lever arm, so a
        reader that knows one lever arm per camera keeps working); with several zooms the
        optional ``lever_arm_per_zoom`` lists each zoom's lever arm."""
        first = [*range(SHARED_DIM), SHARED_DIM, SHARED_DIM + 1]
        names = self.names
        est = set(self.estimated)
        out: dict = {"estimated": [HEAD_PARAMETERS[k] for k, i in enumerate(first) if names[i] in est],
                     "values": [float(self.values[i]) for i in first], "std": [float(self.std[i]) for i in first]}
        if len(self.zooms) > 1:
            out["lever_arm_per_zoom"] = [
                {"zoom": z, "values": [float(self.values[i]) for i in ix], "std": [float(self.std[i]) for i in ix],
                 "estimated": all(names[i] in est for i in ix)}
                for g, z in enumerate(self.zooms) for ix in [(SHARED_DIM + 2 * g, SHARED_DIM + 2 * g + 1)]]
        return out


@dataclass
class HeadCalibrationReport:
    """What the self-calibration decided and estimated, per camera."""

    model: HeadModel
    cameras: dict[str, CameraHeadEstimate]
    decision: str
    lr_statistic: float = float("nan")
    lr_threshold: float = float("nan")
    score: ScoreTest | None = None
    ranks: dict[str, dict[str, int]] = field(default_factory=dict)

    def to_json(self) -> dict:
        """The ``head_calibration`` block of result.json (radians, unit-less scales, survey units)."""
        return {
            "model": self.model.value,
            "decision": self.decision,
            "parameters": list(HEAD_PARAMETERS),
            "lr_statistic": self.lr_statistic if math.isfinite(self.lr_statistic) else None,
            "lr_threshold": self.lr_threshold if math.isfinite(self.lr_threshold) else None,
            **({} if self.score is None else {"score_test": {
                "statistic": self.score.statistic, "threshold": self.score.threshold,
                "p_value": self.score.p_value, "level": self.score.alpha}}),
            "cameras": {cid: c.block() | {"fisher_rank": self.ranks.get(cid, {})} for cid, c in self.cameras.items()},
        }

    def summary(self) -> str:
        """Lines for people: the decision and each estimated parameter with its 1-sigma."""
        lines = [f"head model {self.model.value}: {self.decision}"]
        for cid, c in self.cameras.items():
            if not c.estimated:
                lines.append(f"  {cid}: ideal head")
                continue
            parts = []
            for name in c.estimated:
                i = c.names.index(name)
                if i <= 2:
                    parts.append(f"{name} {np.rad2deg(c.values[i]):+.4f}±{np.rad2deg(c.std[i]):.4f}°")
                elif i <= 4:
                    parts.append(f"{name} {100 * c.values[i]:+.3f}±{100 * c.std[i]:.3f}%")
                else:
                    parts.append(f"{name} {c.values[i]:+.5f}±{c.std[i]:.5f}")
            lines.append(f"  {cid}: " + ", ".join(parts))
        return "\n".join(lines)


@dataclass
class SelfCalibrationProblem(LocalizationProblem):
    """A :class:`LocalizationProblem` whose bearings go through head-model factors."""

    heads: HeadFactorSet | None = None
    head_keys: dict[str, int] = field(default_factory=dict)
    active: dict[str, tuple[int, ...]] = field(default_factory=dict)
    #: Per camera its zoom groups (:func:`fgloc.core.head_model.zoom_groups`): one lever arm each.
    zooms: dict[str, tuple[float | None, ...]] = field(default_factory=dict)

    def prepare(self, values: gtsam.Values) -> None:
        assert self.heads is not None
        self.heads.prepare(values)

    def data_error(self, values: gtsam.Values) -> float:
        """0.5 * chi-square of the bearings alone (no gauge, no head prior)."""
        assert self.heads is not None
        return self.heads.error(values)

    def error(self, values: gtsam.Values) -> float:
        assert self.heads is not None
        rest = sum(self.graph.at(i).error(values) for i in range(len(self.heads), self.graph.size()))
        return self.heads.error(values) + float(rest)

    def elimination_ordering(self) -> gtsam.Ordering:
        ordering = gtsam.Ordering()
        late = set(self.camera_keys.values()) | set(self.head_keys.values())
        for k in sorted(set(self.initial.keys()) - late):
            ordering.push_back(k)
        for k in list(self.camera_keys.values()) + list(self.head_keys.values()):
            ordering.push_back(k)
        return ordering


def build_self_calibration_problem(
    survey: Survey,
    initial: InitialEstimate,
    active: dict[str, tuple[int, ...]],
    head_start: dict[str, FloatArray] | None = None,
    options: SolverOptions = SolverOptions(),
    exclude: frozenset[int] = frozenset(),
    prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS,
    with_prior: bool = True,
) -> SelfCalibrationProblem:
    """The reference problem with head factors; ``active[cid]`` lists the indices estimated for it
    (into the camera's extended vector, :func:`fgloc.core.head_model.head_dim` of its zoom groups;
    ``head_start[cid]`` and ``prior_sigmas`` as extended vectors, a 7-vector prior is extended)."""
    base = build_problem(survey, initial, replace(options, robust=RobustKernel.NONE), exclude)
    zooms, group_of = zoom_groups(survey)
    dims = {cid: head_dim(len(zooms[cid])) for cid in survey.camera_ids}
    values = gtsam.Values(base.initial)
    head_keys: dict[str, int] = {}

    def start_of(cid: str) -> FloatArray:  # a 7-vector start gives every zoom its lever arm
        zero = np.zeros(dims[cid])
        if head_start is None or cid not in head_start:
            return zero
        return extend_vector(np.asarray(head_start[cid], dtype=float), len(zooms[cid]))

    for i, cid in enumerate(survey.camera_ids):
        idx = tuple(sorted(active.get(cid, ())))
        if cid in base.camera_keys and idx:
            head_keys[cid] = head_key(i)
            values.insert(head_keys[cid], start_of(cid)[list(idx)].copy())
    pt = base.pan_tilt
    cam_of_key = {v: k for k, v in base.camera_keys.items()}
    obs_head = np.array([head_keys.get(cam_of_key[int(k)], -1) for k in pt.camera_keys], dtype=np.int64)
    obs_group = group_of[base.observation_index] if len(pt) else np.zeros(0, dtype=np.int64)
    fixed = np.zeros((len(pt), HEAD_DIM))
    if head_start is not None:
        for j, k in enumerate(pt.camera_keys):
            fixed[j] = reading_params(start_of(cam_of_key[int(k)]), obs_group[j:j + 1])[0]
    sigma = survey.observation_table.sigma[base.observation_index]
    noise = {float(s): gtsam.noiseModel.Isotropic.Sigma(2, float(s)) for s in np.unique(sigma)}
    heads = HeadFactorSet(
        pt.camera_keys, pt.node_keys, obs_head,
        {head_keys[c]: tuple(sorted(active[c])) for c in head_keys}, fixed, pt.pan, pt.tilt,
        [noise[float(s)] for s in sigma], planar=pt.planar, zoom_group=obs_group,
    )
    graph = gtsam.NonlinearFactorGraph()
    for f in heads.factors:
        graph.add(f)
    for i in range(len(pt), base.graph.size()):
        graph.add(base.graph.at(i))
    if with_prior:
        for cid, key in head_keys.items():
            graph.add(head_prior_factor(key, tuple(sorted(active[cid])), None,
                                        extend_vector(prior_sigmas, len(zooms[cid]))))
    return SelfCalibrationProblem(
        survey=survey, graph=graph, initial=values, camera_keys=base.camera_keys, node_keys=base.node_keys,
        pan_tilt=pt, observation_index=base.observation_index, unlocalized=dict(base.unlocalized),
        heads=heads, head_keys=head_keys, active={c: tuple(sorted(active[c])) for c in head_keys}, zooms=zooms,
    )


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


@dataclass
class SelfCalibratedSolve:
    """The extended problem at its optimum: result, head estimates and chi-square of the bearings."""

    problem: SelfCalibrationProblem
    values: gtsam.Values
    result: Result
    heads: dict[str, tuple[FloatArray, FloatArray]]  # cid -> (values (D,), covariance (D, D)), D = 7 per zoom
    chi2: float


def solve_self_calibrated(
    survey: Survey, start: InitialEstimate, active: dict[str, tuple[int, ...]],
    options: SolverOptions = SolverOptions(), exclude: frozenset[int] = frozenset(),
    prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS, fast_path: bool = False,
) -> SelfCalibratedSolve:
    """Optimize the extended problem from ``start`` (ideal heads) and collect marginals.

    With ``fast_path`` and ``options.eliminate_nodes`` on the node-eliminated fast path
    (:mod:`fgloc.solve.eliminated_heads`; same optimum and marginals from the same basin,
    ``tests/test_camera_side.py``). Not the default: from the ideal start its different
    steps can end in another local minimum where the pan scale's reading jumps at the
    +-180 degree pan seam (a seeded 40-node, 3-camera survey of
    ``tests/test_head_calibration.py``: cost 147 against the reference graph's 81), and
    the head model's forward solve, not the graph, dominates the time
    (``scripts/bench_head_model.py``)."""
    if options.eliminate_nodes and fast_path:
        from fgloc.solve.eliminated_heads import solve_self_calibrated_eliminated

        fast: SelfCalibratedSolve = solve_self_calibrated_eliminated(survey, start, active, options, exclude,
                                                                     prior_sigmas)
        return fast
    problem = build_self_calibration_problem(survey, start, active, None, options, exclude, prior_sigmas)
    outcome = optimize(problem, options)
    result = collect_result(problem, outcome, options)
    heads: dict[str, tuple[FloatArray, FloatArray]] = {}
    if problem.head_keys and options.compute_marginals:
        problem.prepare(outcome.values)
        marginals = gtsam.Marginals(problem.graph.linearize(outcome.values), outcome.values)
    for cid in survey.camera_ids:
        d = head_dim(len(problem.zooms.get(cid, (None,))))
        vals, cov = np.zeros(d), np.zeros((d, d))
        if cid in problem.head_keys:
            idx = list(problem.active[cid])
            vals[idx] = np.asarray(outcome.values.atVector(problem.head_keys[cid]))
            if options.compute_marginals:
                cov[np.ix_(idx, idx)] = marginals.marginalCovariance(problem.head_keys[cid])
        heads[cid] = (vals, cov)
    return SelfCalibratedSolve(problem, outcome.values, result, heads, 2.0 * problem.data_error(outcome.values))


def _fit_and_flag(
    survey: Survey, start: InitialEstimate, active: dict[str, tuple[int, ...]], options: SolverOptions,
    prior_sigmas: FloatArray, fast_path: bool = False,
) -> tuple[SelfCalibratedSolve, frozenset[int], list[FlaggedObservation]]:
    """Fit with every reading, flag those implausible under the head model (chi-square, 2 dof), refit without.

    Readings the ideal model flags are often only the head errors showing; they are judged again here.
    """
    fit = solve_self_calibrated(survey, start, active, options, frozenset(), prior_sigmas, fast_path)
    heads = fit.problem.heads
    assert heads is not None
    m2 = np.sum((heads.errors(fit.values) * heads.inv_sigmas) ** 2, axis=1)
    bad = np.flatnonzero(m2 > options.flag_chi2)
    if len(bad) == 0:
        return fit, frozenset(), []
    index = fit.problem.observation_index
    flagged = [FlaggedObservation(survey.observations[int(index[b])].camera, survey.observations[int(index[b])].node,
                                  int(index[b]), float(math.sqrt(m2[b]))) for b in bad]
    exclude = frozenset(int(index[b]) for b in bad)
    start = estimate_from_values(fit.problem, fit.values)
    return solve_self_calibrated(survey, start, active, options, exclude, prior_sigmas, fast_path), exclude, flagged


def _report(model: HeadModel, fit: SelfCalibratedSolve | None, survey: Survey, decision: str,
            data_std: dict[str, FloatArray], ranks: dict[str, dict[str, int]]) -> HeadCalibrationReport:
    cams = {}
    zooms, _ = zoom_groups(survey)
    for cid in survey.camera_ids:
        d = head_dim(len(zooms[cid]))
        if fit is None or cid not in fit.problem.head_keys:
            cams[cid] = CameraHeadEstimate(np.zeros(d), np.zeros(d), (), data_std.get(cid, np.full(d, np.inf)),
                                           zooms=zooms[cid])
            continue
        vals, cov = fit.heads[cid]
        names = parameter_names(zooms[cid])
        est = tuple(names[i] for i in fit.problem.active[cid])
        cams[cid] = CameraHeadEstimate(vals, np.sqrt(np.clip(np.diag(cov), 0, None)), est,
                                       data_std.get(cid, np.full(d, np.inf)), cov, zooms[cid])
    return HeadCalibrationReport(model, cams, decision, ranks=ranks)


#: The fast path is taken by default only when every reading's pan lies within this (rad) of
#: zero. A head that turns +-170 degrees (EVI-D70, SNC-RZ25N) reads up to 170 (1 + k_p); with
#: |k_p| <= 2 % (four prior sigmas) a reading of 175 degrees is a mechanical pan >= 1.4 degrees
#: from the +-180 degree seam where the pan scale's reading jumps, ~10x what a node's estimate
#: moves between the ideal start and the head model's optimum (docs/head-calibration.md).
FAST_PATH_PAN_LIMIT = math.radians(175.0)


def fast_path_is_safe(survey: Survey, exclude: frozenset[int] = frozenset()) -> bool:
    """True when no reading kept (``exclude``: indices into ``survey.observations``) lies
    beyond :data:`FAST_PATH_PAN_LIMIT` in |pan|."""
    pan = np.asarray(survey.observation_table.pan)
    keep = np.ones(len(pan), dtype=bool)
    keep[[i for i in exclude if 0 <= i < len(pan)]] = False
    return bool(np.all(np.abs(pan[keep]) <= FAST_PATH_PAN_LIMIT))


def solve_with_head_model(
    survey: Survey, model: HeadModel = HeadModel.AUTO, options: SolverOptions = SolverOptions(),
    prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS, fast_path: bool | None = None,
) -> tuple[Result, HeadCalibrationReport]:
    """Solve ``survey`` with the ideal, the full or the data-selected head model.

    ``fast_path`` (see :func:`solve_self_calibrated`): ``None`` (default) takes the
    node-eliminated fast path when ``options.eliminate_nodes`` and every reading the ideal
    solve kept has |pan| <= 175 degrees (:func:`fast_path_is_safe`), the reference graph
    otherwise; ``True`` / ``False`` force one.

    The ideal solve (:func:`fgloc.solve.joint.solve_survey`, outlier flagging
    included) gives the start; the extended model judges every reading again
    (readings the ideal head flags are often the head errors themselves). Raises :class:`SelfCalibrationError` when ``FULL``
    asks for a parameter the survey cannot determine (rank-deficient information).
    """
    ideal = solve_survey(survey, options)
    exclude = frozenset(f.index for f in ideal.flagged)
    if fast_path is None:
        fast_path = options.eliminate_nodes and fast_path_is_safe(survey, exclude)
    start = InitialEstimate(cameras=dict(ideal.cameras),
                            nodes={n: e.position for n, e in ideal.nodes.items()}, unlocalized=dict(ideal.unlocalized))
    if model is HeadModel.IDEAL:
        return ideal, _report(model, None, survey, "ideal head (not estimated)", {}, {})
    hi = whitened_head_information(survey, start, prior_sigmas, exclude)
    ranks, data_std = observability_from_information(hi)
    if model is HeadModel.FULL:
        for cid, std in data_std.items():
            bad = [_names(survey, cid)[i] for i in range(len(std)) if not np.isfinite(std[i])]
            if bad:
                raise SelfCalibrationError(
                    f"--head-model full: camera {cid}: the survey cannot determine {', '.join(bad)} "
                    f"(Fisher information rank deficient{_thin_note(survey, cid, bad)}); use --head-model auto")
        active = {cid: tuple(range(len(std))) for cid, std in data_std.items()}
        fit, exclude, flagged = _fit_and_flag(survey, start, active, options, prior_sigmas, fast_path)
        return _finish(fit, flagged, _report(model, fit, survey, "all parameters estimated", data_std, ranks))
    # AUTO: candidates are the parameters the data determine at all (full-rank information);
    # when the survey cannot determine them all, a largest determinable subset, the rest pinned.
    if all(np.all(np.isfinite(std)) for std in data_std.values()):
        active = {cid: tuple(range(len(std))) for cid, std in data_std.items()}
    else:
        active = determinable_from_information(hi)
    k = sum(len(a) for a in active.values())
    if k == 0:
        return ideal, _report(model, None, survey, "ideal head: the survey determines no head parameter", data_std, ranks)
    fit, exclude, flagged = _fit_and_flag(survey, start, active, options, prior_sigmas, fast_path)
    # The ideal head on the same readings (those the head model judged plausible).
    chi2_ideal = solve_self_calibrated(survey, start, {}, replace(options, compute_marginals=False), exclude,
                                       prior_sigmas, fast_path).chi2
    lr = chi2_ideal - fit.chi2
    lr_threshold = chi2_quantile(1.0 - LR_ALPHA, k)
    rows = [r for r, (cid, i) in enumerate(hi.labels) if i in fit.problem.active.get(cid, ())]
    prior_chi2 = sum(float((fit.heads[hi.labels[r][0]][0][hi.labels[r][1]] / hi.scale[r]) ** 2) for r in rows)
    test = bayes_score_test(chi2_ideal, fit.chi2, prior_chi2, hi.info[np.ix_(rows, rows)])
    verdict = (f"Bayes score {test.statistic:.1f} {'>' if test.rejects_ideal else '<'} {test.threshold:.1f} "
               f"(p {test.p_value:.3g}, level {test.alpha:g}; LR {lr:.1f}, {k} dof)")
    if not test.rejects_ideal:
        # The data show no head error, yet errors within the prior may hide in directions the
        # bearings cannot see (they move the geometry instead): the ideal head's estimates, with
        # their mean squared error under the extended model's posterior as covariance.
        honest = _with_posterior_mse(ideal, fit.result)
        report = _report(model, None, survey, f"ideal head kept ({verdict}); "
                         "node covariances: the head model's posterior error of these estimates", data_std, ranks)
        report.lr_statistic, report.lr_threshold, report.score = lr, lr_threshold, test
        return honest, report
    # Rejected: every determinable parameter of every camera stays in with its prior. Dropping
    # a camera's or a parameter's insignificant errors would leave their effect out of the
    # covariance (post-selection overconfidence, docs/head-calibration.md).
    n_est = sum(len(a) for a in fit.problem.active.values())
    report = _report(model, fit, survey, f"ideal head rejected ({verdict}); "
                     f"{n_est} parameters on {len(fit.problem.active)} cameras", data_std, ranks)
    report.lr_statistic, report.lr_threshold, report.score = lr, lr_threshold, test
    return _finish(fit, flagged, report)


def _names(survey: Survey, cid: str) -> tuple[str, ...]:
    """Names of camera ``cid``'s extended head vector."""
    return parameter_names(zoom_groups(survey)[0][cid])


def _thin_note(survey: Survey, cid: str, bad: list[str]) -> str:
    """``, or zoom Z has N readings, a lever arm needs 3`` for the refused lever arms of thin zoom groups."""
    zooms, group_of = zoom_groups(survey)
    cam = np.array([o.camera == cid for o in survey.observations], dtype=bool)
    notes = []
    for g, z in enumerate(zooms[cid]):
        n = int(np.sum(cam & (group_of == g)))
        if len(zooms[cid]) > 1 and n < MIN_ZOOM_READINGS and parameter_names(zooms[cid])[SHARED_DIM + 2 * g] in bad:
            notes.append(f"{'no zoom given' if z is None else f'zoom {z:g}'} has {n} readings, "
                         f"a lever arm needs {MIN_ZOOM_READINGS}")
    return "".join(f"; {n}" for n in notes)


def _with_posterior_mse(ideal: Result, extended: Result) -> Result:
    """``ideal``'s estimates with covariances = their mean squared error under the extended
    model's posterior: its covariance ``P_i`` plus the squared offset ``d_i d_i'`` of the
    ideal estimate from the extended one (``d_i = x_ideal - x_extended``).

    If the extended posterior is right, ``E[e e' | readings] = P_i + d_i d_i'`` for the
    ideal estimate's error ``e``: its NEES has expectation = dof for every survey.
    """
    nodes = {}
    for n, e in ideal.nodes.items():
        x = extended.nodes.get(n)
        if x is None or not np.all(np.isfinite(x.covariance)):
            nodes[n] = e
            continue
        dim = np.asarray(x.covariance).shape[0]
        d = (np.asarray(e.position) - np.asarray(x.position))[:dim]
        nodes[n] = replace(e, covariance=np.asarray(x.covariance) + np.outer(d, d))
    return replace(ideal, nodes=nodes)


def _finish(fit: SelfCalibratedSolve, flagged: list[FlaggedObservation],
            report: HeadCalibrationReport) -> tuple[Result, HeadCalibrationReport]:
    result = fit.result
    result.flagged = flagged
    if result.stats is not None:
        result.stats.method = f"joint, self-calibrating head ({report.model.value})"
    logger.info("%s", report.summary())
    return result, report

