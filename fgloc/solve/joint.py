"""The joint solve: every pan-tilt reading is a factor in one GTSAM graph.

Variables: one ``Pose3`` per camera base (key ``c<i>``, i = index in
``Survey.camera_ids``) and one node position per observed node (key ``l<j>``,
j = index in ``Survey.node_ids``): ``Point2`` on z = 0 for planar surveys,
``Point3`` for 3d surveys. The :class:`~factors.BaselinePrior` pins the gauge.

The initial estimate comes from the bearings alone
(:mod:`fgloc.init.planar`), the optimizer is Levenberg-Marquardt
(:mod:`fgloc.solve.levenberg_marquardt`), and the marginal covariances come from
``gtsam.Marginals`` on the final linearization. Camera pose covariances are
6x6 in GTSAM's body-frame tangent ``[omega, v]``. Implausible readings are judged
by :mod:`fgloc.solve.outliers`; :func:`solve_survey` re-solves without them.
"""

from __future__ import annotations

import enum
import logging
import re
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.model import CameraPose, NodeEstimate, NodeMode, Result, SolveStats, Survey
from fgloc.factors.baseline_prior import BaselinePrior
from fgloc.factors.pan_tilt_batch import PanTiltFactorSet
from fgloc.init.planar import initialize_planar
from fgloc.init.start import InitialEstimate
from fgloc.init.three_d import initialize_3d
from fgloc.solve.levenberg_marquardt import IterationCallback, LMOutcome, LMParams, levenberg_marquardt
from fgloc.solve.outliers import FLAG_CHI2, MAX_FLAG_ROUNDS, flag_readings, reflag
from fgloc.solve.schur_marginals import node_marginals

logger = logging.getLogger(__name__)

camera_key = gtsam.symbol_shorthand.C
node_key = gtsam.symbol_shorthand.L
#: Key of a view's (pan, tilt) head offset, ``Vector2`` radians (index in ``Survey.view_ids``).
view_key = gtsam.symbol_shorthand.V


class SolveError(FglocError):
    """The survey cannot be solved as given."""


class RobustKernel(str, enum.Enum):
    """Noise model of the pan-tilt factors. AUTO: Cauchy when RANSAC found outliers, else Gaussian."""

    AUTO = "auto"
    NONE = "none"
    HUBER = "huber"
    CAUCHY = "cauchy"


@dataclass(frozen=True)
class SolverOptions:
    """Settings of the joint solve."""

    lm: LMParams = LMParams()
    compute_marginals: bool = True
    robust: RobustKernel = RobustKernel.AUTO
    #: Kernel width in whitened units (multiples of sigma).
    robust_scale: float = 3.0
    #: Flag readings whose squared whitened residual exceeds this after the solve.
    flag_chi2: float = FLAG_CHI2
    #: Sigma of the gauge priors in baseline units; None scales it to the problem
    #: (see :func:`auto_gauge_sigma`).
    gauge_sigma: float | None = None
    #: :func:`solve_survey` eliminates the nodes in closed form and lets GTSAM optimize
    #: only the cameras (:mod:`fgloc.solve.eliminated`); False: the reference graph,
    #: one pan-tilt factor per reading. Same optimum and marginals.
    eliminate_nodes: bool = True


def auto_gauge_sigma(survey: Survey, initial: InitialEstimate) -> float:
    """A gauge sigma 1e-3 times a typical node standard deviation (sigma x camera range).

    Small enough that the gauge leaks ~1e-6 (relative) into the marginals, large
    enough that Cholesky stays well conditioned when cameras stand far away or
    high above a short baseline. The positions do not depend on it.
    """
    table = survey.observation_table
    node_pos = np.full((len(survey.node_ids), 3), np.nan)
    for j, nid in enumerate(survey.node_ids):
        if nid in initial.nodes:
            node_pos[j] = initial.nodes[nid]
    cam_pos = np.full((len(survey.camera_ids), 3), np.nan)
    for i, cid in enumerate(survey.camera_ids):
        if cid in initial.cameras:
            cam_pos[i] = initial.cameras[cid].position
    n_nodes = len(survey.node_ids)
    seen = np.zeros(len(survey.camera_ids) * n_nodes, dtype=bool)
    seen[table.camera_index.astype(np.int64) * n_nodes + table.node_index] = True
    pairs = np.flatnonzero(seen)  # each (camera, node) pair once
    cams, nodes = pairs // n_nodes, pairs % n_nodes
    keep = np.isfinite(cam_pos[cams, 0]) & np.isfinite(node_pos[nodes, 0])
    ranges = np.linalg.norm(node_pos[nodes[keep]] - cam_pos[cams[keep]], axis=1)
    typical_range = float(np.median(ranges)) if len(ranges) else 1.0
    return float(max(1e-3 * np.median(table.sigma) * typical_range, 1e-9))


@dataclass
class LocalizationProblem:
    """A survey as a factor graph, ready to optimize. Add your own factors to ``graph``.

    ``camera_keys`` / ``node_keys`` map ids to GTSAM keys; ``initial`` holds the
    starting values of every variable. Nodes without observations have no key.
    """

    survey: Survey
    graph: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    camera_keys: dict[str, int]
    node_keys: dict[str, int]
    pan_tilt: PanTiltFactorSet
    #: Index in ``survey.observations`` of each pan-tilt factor, in factor order.
    observation_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    unlocalized: dict[str, str] = field(default_factory=dict)
    #: View id -> key of its ``Vector2`` head offset (readings with a view, see :func:`view_offsets`).
    view_keys: dict[str, int] = field(default_factory=dict)

    def prepare(self, values: gtsam.Values) -> None:
        """Evaluate the pan-tilt factors at ``values`` in one vectorized pass.

        Call before ``graph.linearize(values)`` or ``graph.error(values)`` for
        speed; without it the factors compute one reading at a time.
        """
        self.pan_tilt.prepare(values)

    def error(self, values: gtsam.Values) -> float:
        """``graph.error(values)``, with the pan-tilt part summed in one numpy pass.

        Relies on :func:`build_problem` adding the pan-tilt factors first (indices
        0..len-1); every other factor (gauge, user factors) is evaluated by GTSAM.
        Falls back to ``graph.error`` when the pan-tilt noise is not plain Gaussian.
        """
        pan_tilt = self.pan_tilt.error(values)
        if pan_tilt is None:
            return float(self.graph.error(values))
        rest = sum(self.graph.at(i).error(values) for i in range(len(self.pan_tilt), self.graph.size()))
        return pan_tilt + float(rest)

    def add_factor(self, factor: gtsam.NonlinearFactor) -> None:
        """Add a user factor (e.g. a GPS anchor on a node key, a radio range between nodes)."""
        self.graph.add(factor)

    def elimination_ordering(self) -> gtsam.Ordering:
        """Nodes first, cameras last: eliminating the many small node blocks first
        leaves a dense but tiny camera system (a Schur complement)."""
        ordering = gtsam.Ordering()
        in_values = set(self.initial.keys())
        camera_set = set(self.camera_keys.values())
        for k in sorted(in_values - camera_set):
            ordering.push_back(k)
        for k in self.camera_keys.values():
            ordering.push_back(k)
        return ordering


def _pose3(cam: CameraPose) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(cam.rotation), np.asarray(cam.position, dtype=float))


def _noise_model(sigma: float | tuple[float, float], kernel: RobustKernel, scale: float) -> gtsam.noiseModel.Base:
    """Pan-tilt noise of sigma (radians; one value, or pan's and tilt's), robust if asked."""
    if isinstance(sigma, tuple) and sigma[0] != sigma[1]:
        base = gtsam.noiseModel.Diagonal.Sigmas(np.array(sigma, dtype=float))
    else:
        base = gtsam.noiseModel.Isotropic.Sigma(2, float(sigma[0] if isinstance(sigma, tuple) else sigma))
    if kernel is RobustKernel.HUBER:
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(scale), base)
    if kernel is RobustKernel.CAUCHY:
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(scale), base)
    return base


def build_problem(
    survey: Survey,
    initial: InitialEstimate,
    options: SolverOptions = SolverOptions(),
    exclude: frozenset[int] = frozenset(),
) -> LocalizationProblem:
    """One factor per observation, the gauge prior, and initial values from ``initial``.

    ``exclude`` lists observation indices to leave out (flagged outliers).
    Nodes left without observations get no variable. The kernel is
    ``options.robust`` (AUTO counts as NONE here; :func:`solve_survey` resolves it).
    Readings with a view (``Observation.view``) get the view's offset as a third key
    and the independent part of their sigma as noise; each view offset starts at zero
    with a zero-mean prior of ``view_sigma`` (:func:`view_offsets`).
    """
    planar = survey.mode is NodeMode.PLANAR
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    table = survey.observation_table
    kept = np.ones(len(table), dtype=bool)
    kept[list(exclude)] = False
    observed = set(np.asarray(survey.node_ids)[table.node_index[kept]].tolist()) if kept.any() else set()
    camera_keys = {cid: camera_key(i) for i, cid in enumerate(survey.camera_ids) if cid in initial.cameras}
    node_keys = {nid: node_key(j) for j, nid in enumerate(survey.node_ids) if nid in initial.nodes and nid in observed}
    for cid, key in camera_keys.items():
        values.insert(key, _pose3(initial.cameras[cid]))
    for nid, key in node_keys.items():
        p = np.asarray(initial.nodes[nid], dtype=float)
        if planar:
            values.insert(key, p[:2].copy())
        else:
            values.insert(key, p.copy())
    cam_key_of = np.array([camera_keys.get(c, -1) for c in survey.camera_ids], dtype=np.int64)
    node_key_of = np.array([node_keys.get(n, -1) for n in survey.node_ids], dtype=np.int64)
    obs_cam_keys = cam_key_of[table.camera_index]
    obs_node_keys = node_key_of[table.node_index]
    used = (obs_cam_keys >= 0) & (obs_node_keys >= 0) & kept
    kernel = RobustKernel.NONE if options.robust is RobustKernel.AUTO else options.robust
    offsets = view_offsets(survey, used)
    sigma = [(float(a), float(b)) for a, b in offsets.reading_sigma[used]]
    noise_cache = {s: _noise_model(s, kernel, options.robust_scale) for s in set(sigma)}
    view_keys = {survey.view_ids[v]: view_key(v) for v in offsets.views}
    obs_view_keys = np.where(table.view_index[used] >= 0, view_key(0) + table.view_index[used], -1) if len(
        view_keys) else None
    pan_tilt = PanTiltFactorSet(
        obs_cam_keys[used],
        obs_node_keys[used],
        table.pan[used],
        table.tilt[used],
        [noise_cache[s] for s in sigma],
        planar=planar,
        view_keys=obs_view_keys,
        view_pans=table.view_pan[used],
    )
    for f in pan_tilt.factors:
        graph.add(f)
    for v, s_v in zip(offsets.views, offsets.prior_sigma):
        values.insert(view_key(int(v)), np.zeros(2))
        graph.add(gtsam.PriorFactorVector(view_key(int(v)), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, s_v)))
    gauge_sigma = options.gauge_sigma if options.gauge_sigma is not None else auto_gauge_sigma(survey, initial)
    gauge = BaselinePrior(survey.mode, camera_keys[survey.gauge.origin], camera_keys[survey.gauge.baseline], gauge_sigma)
    for gauge_factor in gauge.factors():
        graph.add(gauge_factor)
    return LocalizationProblem(
        survey=survey,
        graph=graph,
        initial=values,
        camera_keys=camera_keys,
        node_keys=node_keys,
        pan_tilt=pan_tilt,
        observation_index=np.flatnonzero(used),
        unlocalized=dict(initial.unlocalized),
        view_keys=view_keys,
    )


@dataclass(frozen=True)
class ViewOffsets:
    """The view-offset variables of a problem.

    ``views``: indices into ``Survey.view_ids`` of the views with a used reading;
    ``prior_sigma``: their prior standard deviation (radians, per axis; the largest
    ``view_sigma`` among the view's readings); ``reading_sigma`` (M, 2): every reading's
    pan and tilt noise in the problem (the independent part for readings with a view).
    """

    views: np.ndarray
    prior_sigma: FloatArray
    reading_sigma: FloatArray


def view_offsets(survey: Survey, used: np.ndarray) -> ViewOffsets:
    """The view offsets the readings ``used`` (mask over the observations) need.

    Raises :class:`SolveError` when a reading's ``view_sigma`` is not below its sigma.
    """
    table = survey.observation_table
    has = (table.view_index >= 0) & used
    low = np.minimum(table.sigma, np.min(table.sigma_axes, axis=1))
    if np.any(table.view_sigma[has] >= low[has]):
        k = int(np.flatnonzero(has & (table.view_sigma >= low))[0])
        raise SolveError(f"observation {k}: view_sigma must be below the reading's sigma "
                         f"({table.view_sigma[k]} >= {low[k]})")
    views = np.unique(table.view_index[has])
    prior = np.zeros(len(survey.view_ids))
    np.maximum.at(prior, table.view_index[has], table.view_sigma[has])
    return ViewOffsets(views, prior[views], table.reading_sigma)


def initialize(survey: Survey) -> InitialEstimate:
    """Closed-form initial estimate for the survey's mode."""
    if survey.mode is NodeMode.PLANAR:
        return initialize_planar(survey)
    return initialize_3d(survey)


@dataclass
class Solution:
    """An optimized problem: the GTSAM values and the result built from them."""

    values: gtsam.Values
    result: Result


def solve(
    problem: LocalizationProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
) -> Result:
    """Optimize a built problem (e.g. one you added factors to) and return the result with marginals."""
    return solve_problem(problem, options, on_iteration).result


def solve_problem(
    problem: LocalizationProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
    stage_seconds: dict[str, float] | None = None,
    start: gtsam.Values | None = None,
) -> Solution:
    """Optimize a built problem and collect estimates and (optionally) marginal covariances."""
    stages = {} if stage_seconds is None else stage_seconds
    outcome = optimize(problem, options, on_iteration, stages, start)
    return Solution(values=outcome.values, result=collect_result(problem, outcome, options, stages))


def optimize(
    problem: LocalizationProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
    stage_seconds: dict[str, float] | None = None,
    start: gtsam.Values | None = None,
) -> LMOutcome:
    """Run Levenberg-Marquardt on a built problem from ``start`` (default: its initial values)."""
    stages = {} if stage_seconds is None else stage_seconds
    t0 = time.perf_counter()
    outcome = levenberg_marquardt(
        problem.graph,
        problem.initial if start is None else start,
        problem.elimination_ordering(),
        options.lm,
        on_iteration,
        problem.prepare,
        problem.error,
    )
    stages["optimize"] = stages.get("optimize", 0.0) + time.perf_counter() - t0
    return outcome


def _variable_named_in(message: str, problem: LocalizationProblem) -> str:
    """The camera or node id GTSAM's indeterminate-system message points at."""
    match = re.search(r"\(Symbol: ([a-z])(\d+)\)", message)
    if match is None:
        return "every variable"
    index = int(match.group(2))
    if match.group(1) == "c" and index < len(problem.survey.camera_ids):
        return f"camera {problem.survey.camera_ids[index]}"
    if match.group(1) == "l" and index < len(problem.survey.node_ids):
        return f"node {problem.survey.node_ids[index]}"
    return "every variable"


def collect_result(
    problem: LocalizationProblem,
    outcome: LMOutcome,
    options: SolverOptions = SolverOptions(),
    stage_seconds: dict[str, float] | None = None,
) -> Result:
    """Estimates at the optimizer's values, with marginal covariances when asked."""
    stages = {} if stage_seconds is None else stage_seconds
    values = outcome.values
    survey = problem.survey
    planar = survey.mode is NodeMode.PLANAR
    covariances: dict[str, np.ndarray] = {}
    if options.compute_marginals:
        t0 = time.perf_counter()
        try:
            problem.prepare(values)
            linear = problem.graph.linearize(values)
            # Batched Schur-complement marginals (fgloc.solve.schur_marginals); None when a
            # factor couples two nodes, then GTSAM's per-key Marginals. If the batched
            # Cholesky fails, GTSAM runs too, to name the undetermined variable.
            try:
                fast = node_marginals(linear, values.dims(), list(problem.node_keys.values()))
            except np.linalg.LinAlgError:
                fast = None
            if fast is not None:
                covariances = {nid: fast[key] for nid, key in problem.node_keys.items()}
            else:
                marginals = gtsam.Marginals(linear, values)
                covariances = {nid: marginals.marginalCovariance(key) for nid, key in problem.node_keys.items()}
        except RuntimeError as exc:
            raise SolveError(
                "marginal covariances are undefined: the readings do not determine "
                f"{_variable_named_in(str(exc), problem)} (too few or degenerate readings, "
                "or gauge cameras on one vertical)"
            ) from None
        stages["marginals"] = stages.get("marginals", 0.0) + time.perf_counter() - t0
    nodes: dict[str, NodeEstimate] = {}
    for nid, key in problem.node_keys.items():
        p = values.atPoint2(key) if planar else values.atPoint3(key)
        position = np.array([p[0], p[1], 0.0]) if planar else np.asarray(p, dtype=float)
        dim = 2 if planar else 3
        cov = covariances.get(nid, np.full((dim, dim), np.nan))
        nodes[nid] = NodeEstimate(position=position, covariance=np.asarray(cov, dtype=float))
    cameras = {}
    for cid, key in problem.camera_keys.items():
        pose = values.atPose3(key)
        cameras[cid] = CameraPose(position=np.asarray(pose.translation(), float), rotation=pose.rotation().matrix())
    stats = SolveStats(
        method="joint",
        iterations=outcome.iterations,
        initial_error=outcome.error_history[0],
        final_error=outcome.error_history[-1],
        converged=outcome.converged,
        stage_seconds=stages,
        error_history=outcome.error_history,
    )
    return Result(mode=survey.mode, nodes=nodes, cameras=cameras, unlocalized=dict(problem.unlocalized), stats=stats)


def estimate_from_values(problem: LocalizationProblem, values: gtsam.Values) -> InitialEstimate:
    """The problem's current values as an :class:`InitialEstimate` (gauge frame)."""
    planar = problem.survey.mode is NodeMode.PLANAR
    cameras = {}
    for cid, key in problem.camera_keys.items():
        pose = values.atPose3(key)
        cameras[cid] = CameraPose(np.asarray(pose.translation(), float), pose.rotation().matrix())
    nodes = {}
    for nid, key in problem.node_keys.items():
        p = values.atPoint2(key) if planar else values.atPoint3(key)
        nodes[nid] = np.array([p[0], p[1], 0.0]) if planar else np.asarray(p, float)
    return InitialEstimate(cameras=cameras, nodes=nodes, unlocalized=dict(problem.unlocalized))


def solve_survey(
    survey: Survey, options: SolverOptions = SolverOptions(), on_iteration: IterationCallback | None = None
) -> Result:
    """Initialize from the bearings, optimize, flag implausible readings, and compute marginals.

    1. Closed-form start (RANSAC inside). 2. Levenberg-Marquardt, with a Cauchy
    kernel when the start found outliers (``RobustKernel.AUTO``) or as asked.
    3. Flag readings whose whitened residual is implausible (chi-square, 2 dof);
    if a Gaussian solve flags any, re-solve robustly and flag again. 4. When
    anything was flagged or a kernel was used, a final Gaussian solve without
    the flagged readings gives the estimates and honest marginal covariances.
    Flagged readings are listed in ``Result.flagged``, never silently dropped.

    With ``options.eliminate_nodes`` (default) the same steps run on the camera graph
    of :mod:`fgloc.solve.eliminated` (nodes eliminated in closed form; same optimum
    and marginals); if that meets a numerically singular system, this reference
    graph runs instead (it names the undetermined variable).
    """
    if options.eliminate_nodes:
        from fgloc.solve.eliminated import EliminationFailed, solve_survey_eliminated

        try:
            return solve_survey_eliminated(survey, options, on_iteration)
        except EliminationFailed as exc:
            logger.info(f"nodes-eliminated solve failed ({exc}); solving the reference graph")
    return run_flagging_pipeline(survey, options, on_iteration, REFERENCE_GRAPH)


@dataclass(frozen=True)
class SolveSteps:
    """What :func:`run_flagging_pipeline` needs from one problem representation.

    The reference graph (one factor per reading, :data:`REFERENCE_GRAPH`) and the
    node-eliminated camera graph (:mod:`fgloc.solve.eliminated`) provide the same
    five operations, so the start / flag / re-solve / final-solve logic exists once.
    A problem must carry ``observation_index`` and ``unlocalized`` like
    :class:`LocalizationProblem`.
    """

    build: Callable[[Survey, InitialEstimate, SolverOptions, frozenset[int]], Any]
    optimize: Callable[[Any, SolverOptions, IterationCallback | None, dict[str, float]], LMOutcome]
    estimate: Callable[[Any, gtsam.Values], InitialEstimate]
    collect: Callable[[Any, LMOutcome, SolverOptions, dict[str, float]], Result]
    node_ids: Callable[[Any], Collection[str]]


REFERENCE_GRAPH = SolveSteps(
    build=build_problem,
    optimize=optimize,
    estimate=estimate_from_values,
    collect=collect_result,
    node_ids=lambda problem: problem.node_keys,
)


def _one_camera_nodes(survey: Survey, exclude: frozenset[int]) -> set[str]:
    """3d surveys: nodes whose readings outside ``exclude`` come from exactly one camera.

    One camera's bearings fix a free node only along a ray, so such a node would leave the
    final solve's information singular and no marginal (no result at all) could be written;
    it is reported unlocalized instead. Planar nodes are fixed by one camera (ray meets ground).
    """
    if survey.mode is NodeMode.PLANAR:
        return set()
    cameras: dict[str, set[str]] = {}
    for i, o in enumerate(survey.observations):
        if i not in exclude:
            cameras.setdefault(o.node, set()).add(o.camera)
    return {nid for nid, cams in cameras.items() if len(cams) == 1}


def run_flagging_pipeline(
    survey: Survey, options: SolverOptions, on_iteration: IterationCallback | None, steps: SolveSteps
) -> Result:
    """The steps of :func:`solve_survey` on one problem representation (see its docstring)."""
    stages: dict[str, float] = {}
    t0 = time.perf_counter()
    init = initialize(survey)
    stages["initialize"] = time.perf_counter() - t0
    kernel = options.robust
    if kernel is RobustKernel.AUTO:
        kernel = RobustKernel.CAUCHY if init.suspected_outliers > 0 else RobustKernel.NONE
    t0 = time.perf_counter()
    problem = steps.build(survey, init, replace(options, robust=kernel), frozenset())
    stages["build"] = time.perf_counter() - t0
    first = steps.optimize(problem, options, on_iteration, stages)
    values = first.values
    flagged, ambiguous = flag_readings(survey, steps.estimate(problem, values), problem.observation_index,
                                      options.flag_chi2)
    if flagged and kernel is RobustKernel.NONE and options.robust is RobustKernel.AUTO:
        kernel = RobustKernel.CAUCHY
        problem = steps.build(survey, steps.estimate(problem, values), replace(options, robust=kernel), frozenset())
        values = steps.optimize(problem, options, None, stages).values
        flagged, ambiguous = flag_readings(survey, steps.estimate(problem, values), problem.observation_index,
                                      options.flag_chi2)
    if not flagged and kernel is RobustKernel.NONE:
        return steps.collect(problem, first, options, stages)
    start = steps.estimate(problem, values)
    robust = replace(options, robust=kernel if kernel is not RobustKernel.NONE else RobustKernel.CAUCHY)
    for _ in range(MAX_FLAG_ROUNDS):
        # Re-check every reading, flagged ones included, against a robust solve
        # without the flagged ones: a misjudged reading is restored, a missed one caught.
        refl, ambiguous = reflag(survey, start, frozenset(f.index for f in flagged), ambiguous, options.flag_chi2)
        if {f.index for f in refl} == {f.index for f in flagged}:
            break
        flagged = refl
        loop_problem = steps.build(survey, start, robust, frozenset(f.index for f in flagged))
        start = steps.estimate(loop_problem, steps.optimize(loop_problem, options, None, stages).values)
    exclude = frozenset(f.index for f in flagged)
    one_camera = _one_camera_nodes(survey, exclude)
    unused = frozenset(i for i, o in enumerate(survey.observations) if o.node in one_camera)
    final_problem = steps.build(survey, start, replace(options, robust=RobustKernel.NONE), exclude | unused)
    final_problem.unlocalized.update(ambiguous)
    for nid in one_camera:
        if nid in start.nodes and nid not in final_problem.unlocalized:
            final_problem.unlocalized[nid] = ("the readings left after outlier flagging come from one camera "
                                              "(a 3d node needs two)")
    kept = set(steps.node_ids(final_problem))
    for nid in start.nodes:
        if nid not in kept and nid not in final_problem.unlocalized:
            final_problem.unlocalized[nid] = "all its readings were flagged as outliers"
    result = steps.collect(final_problem, steps.optimize(final_problem, options, None, stages), options, stages)
    result.flagged = flagged
    if result.stats is not None:
        result.stats.method = f"joint ({kernel.value} kernel, then Gaussian without flagged readings)"
        result.stats.initial_error = first.error_history[0]
        result.stats.error_history = first.error_history + result.stats.error_history[1:]
        result.stats.iterations += first.iterations
    return result
