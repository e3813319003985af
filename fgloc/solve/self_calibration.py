"""Self-calibrating joint solve: head errors (:mod:`fgloc.core.head_model`) estimated with the survey.

The extended problem (:mod:`fgloc.solve.head_problem`: the reference graph with head-model
bearing factors, one head vector per camera and a datasheet prior on each) is optimized by
the same Levenberg-Marquardt as the ideal one, or on the node-eliminated fast path, and its
node covariances come from the same marginal code.

Observability (:mod:`fgloc.solve.head_observability`): ``HeadModel.FULL`` refuses (one-line
:class:`SelfCalibrationError`) a parameter whose information is rank deficient; ``AUTO``
leaves it out (pins it at zero). Weakly determined parameters stay in and lean on their
datasheet prior.

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
    HEAD_PARAMETERS,
    SHARED_DIM,
    head_dim,
    parameter_names,
    zoom_groups,
)
from fgloc.core.model import FlaggedObservation, Result, Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.head_observability import (
    ADMIT_ORDER,
    MIN_ZOOM_READINGS,
    RANK_TOL,
    HeadInformation,
    determinable_from_information,
    determinable_subset,
    head_information,
    head_observability,
    observability_from_information,
    whitened_head_information,
)
from fgloc.solve.head_problem import SelfCalibrationProblem, build_self_calibration_problem, head_key
from fgloc.solve.head_selection import ScoreTest, bayes_score_test
from fgloc.solve.joint import (
    SolverOptions,
    collect_result,
    estimate_from_values,
    optimize,
    solve_survey,
)

logger = logging.getLogger(__name__)

#: Re-exported: the problem and observability live in their own modules
#: (:mod:`fgloc.solve.head_problem`, :mod:`fgloc.solve.head_observability`).
__all__ = [
    "ADMIT_ORDER", "FAST_PATH_PAN_LIMIT", "LR_ALPHA", "MIN_ZOOM_READINGS", "RANK_TOL", "CameraHeadEstimate",
    "HeadCalibrationReport", "HeadInformation", "HeadModel", "SelfCalibratedSolve", "SelfCalibrationError",
    "SelfCalibrationProblem", "build_self_calibration_problem", "chi2_quantile", "determinable_from_information",
    "determinable_subset", "fast_path_is_safe", "has_off_centre", "head_information", "head_key", "head_observability",
    "observability_from_information", "solve_self_calibrated", "solve_with_head_model", "whitened_head_information",
]



class SelfCalibrationError(FglocError):
    """The survey cannot determine the head parameters asked for."""


class HeadModel(str, enum.Enum):
    """Which head parameters to estimate: none, all determinable (or refuse), or as the data support."""

    IDEAL = "ideal"
    FULL = "full"
    AUTO = "auto"


#: Level of the plain likelihood-ratio test, reported beside the Bayes score test that decides.
LR_ALPHA = 0.05


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
    (``scripts/bench_head_model.py``). Off-centre readings (:func:`has_off_centre`) always
    take the reference graph: the fast path models centred readings only."""
    if options.eliminate_nodes and fast_path and not has_off_centre(survey, exclude):
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
    beyond :data:`FAST_PATH_PAN_LIMIT` in |pan| and none is off-centre (carries view angles,
    ``Observation.view_angles``: the node-eliminated fast path models centred readings only,
    the reference graph predicts off-centre ones from their view)."""
    pan = np.asarray(survey.observation_table.pan)
    keep = np.ones(len(pan), dtype=bool)
    keep[[i for i in exclude if 0 <= i < len(pan)]] = False
    return bool(np.all(np.abs(pan[keep]) <= FAST_PATH_PAN_LIMIT)) and not has_off_centre(survey, exclude)


def has_off_centre(survey: Survey, exclude: frozenset[int] = frozenset()) -> bool:
    """True when a reading kept (not in ``exclude``) carries its view's angles (off-centre)."""
    return any(o.view_angles is not None for i, o in enumerate(survey.observations) if i not in exclude)


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
    views = {o.view_angles for o in survey.observations if o.camera == cid and o.view_angles is not None}
    if views and any(b in HEAD_PARAMETERS[:SHARED_DIM] for b in bad):
        notes.append(f"its off-centre readings come from {len(views)} views, and they see the head only "
                     "through each view's orientation")
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

