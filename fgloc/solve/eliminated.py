"""The fast solve: GTSAM optimizes only the cameras; the nodes are eliminated in closed form.

Same problem, same optimum and same marginals as the reference graph of
:mod:`fgloc.solve.joint` (one pan-tilt factor per reading), by the structure
of a survey: every reading links one camera to one node. The camera graph holds

* one :class:`~fgloc.factors.eliminated_readings.EliminatedReadings` factor on
  all camera keys (every reading, the nodes solved and eliminated inside it in
  vectorized numpy; robust kernels as IRLS weights per reading),
* the gauge priors (:class:`~fgloc.factors.baseline_prior.BaselinePrior`),
* any user factor on camera keys (or on variables of the user's own).

It is optimized by the same Levenberg-Marquardt loop
(:mod:`fgloc.solve.levenberg_marquardt`) on a graph of k cameras instead of
k + n variables and one linear factor per reading. The camera marginals come from
``gtsam.Marginals`` on that small graph; the node positions and marginals by
back-substitution (``A_j^-1 + G_j Sigma_cc G_j^T``, ``G_j = A_j^-1 B_j``).

:func:`solve_survey_eliminated` mirrors :func:`fgloc.solve.joint.solve_survey`
step by step (start, kernel choice, flagging rounds, final Gaussian solve).
User factors on node keys need the reference graph (:func:`fgloc.solve.joint.build_problem`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.core.model import CameraPose, NodeEstimate, NodeMode, Result, SolveStats, Survey
from fgloc.factors.baseline_prior import BaselinePrior
from fgloc.factors.eliminated_readings import EliminatedReadings, Kernel
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import (
    RobustKernel,
    SolverOptions,
    SolveSteps,
    ViewOffsets,
    auto_gauge_sigma,
    camera_key,
    node_key,
    run_flagging_pipeline,
    view_key,
    view_offsets,
)
from fgloc.solve.levenberg_marquardt import IterationCallback, LMOutcome, levenberg_marquardt

#: Key of a camera's head calibration Vector (as :mod:`fgloc.solve.self_calibration`).
head_key = gtsam.symbol_shorthand.H


class EliminationFailed(RuntimeError):
    """The fast path met a numerically singular node or camera system; use the reference graph."""


_KERNELS = {RobustKernel.NONE: Kernel.GAUSSIAN, RobustKernel.AUTO: Kernel.GAUSSIAN,
            RobustKernel.HUBER: Kernel.HUBER, RobustKernel.CAUCHY: Kernel.CAUCHY}


@dataclass
class EliminatedProblem:
    """A survey as a camera graph with the readings' node-eliminated factor. Add camera factors to ``graph``."""

    survey: Survey
    graph: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    camera_keys: dict[str, int]
    node_ids: list[str]  # row order of readings.nodes
    readings: EliminatedReadings
    observation_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    unlocalized: dict[str, str] = field(default_factory=dict)
    #: View id -> key of its ``Vector2`` head offset (as the reference graph's ``view_keys``).
    view_keys: dict[str, int] = field(default_factory=dict)
    #: Camera id -> key of its head calibration Vector, and the 7-vector indices it holds.
    head_keys: dict[str, int] = field(default_factory=dict)
    active: dict[str, tuple[int, ...]] = field(default_factory=dict)

    def node_values(self, values: gtsam.Values) -> gtsam.Values:
        """``values`` plus every node at its optimum for those cameras (keys ``L(j)`` as the reference graph)."""
        nodes = self.readings.at(values).nodes
        out = gtsam.Values(values)
        index = {n: j for j, n in enumerate(self.survey.node_ids)}
        planar = self.survey.mode is NodeMode.PLANAR
        for row, nid in enumerate(self.node_ids):
            p = nodes[row]
            if planar:
                out.insert(node_key(index[nid]), np.array(p[:2]))
            else:
                out.insert(node_key(index[nid]), np.array(p))
        return out


@dataclass(frozen=True)
class HeadSpec:
    """Head calibration vectors for :func:`build_eliminated` (as
    :func:`fgloc.solve.self_calibration.build_self_calibration_problem`): ``active[cid]``
    the extended-vector indices estimated for camera ``cid`` (:mod:`fgloc.core.head_model`:
    one lever arm per zoom group), ``start[cid]`` the starting (and, where not active, fixed)
    extended values, a zero-mean prior of ``prior_sigmas`` (7,, lever arm repeated per zoom)
    when ``with_prior``."""

    active: dict[str, tuple[int, ...]]
    start: dict[str, FloatArray] | None
    prior_sigmas: FloatArray
    with_prior: bool = True


def build_eliminated(
    survey: Survey,
    initial: InitialEstimate,
    options: SolverOptions = SolverOptions(),
    exclude: frozenset[int] = frozenset(),
    heads: HeadSpec | None = None,
) -> EliminatedProblem:
    """The camera graph of :func:`fgloc.solve.joint.build_problem`'s problem (same readings, gauge, kernel).

    Readings with a view get the view's head offset (a ``Vector2`` camera-side variable with
    its zero-mean prior, as in the reference graph); with ``heads``, each camera's head
    calibration vector (the reference graph of :mod:`fgloc.solve.self_calibration`).
    """
    planar = survey.mode is NodeMode.PLANAR
    table = survey.observation_table
    kept = np.ones(len(table), dtype=bool)
    kept[list(exclude)] = False
    camera_keys = {cid: camera_key(i) for i, cid in enumerate(survey.camera_ids) if cid in initial.cameras}
    cam_slot = np.array([list(camera_keys).index(c) if c in camera_keys else -1 for c in survey.camera_ids], dtype=np.int64)
    has_node = np.array([n in initial.nodes for n in survey.node_ids], dtype=bool)
    used = kept & (cam_slot[table.camera_index] >= 0) & has_node[table.node_index]
    node_rows = np.unique(table.node_index[used])
    row_of = np.full(len(survey.node_ids), -1, dtype=np.int64)
    row_of[node_rows] = np.arange(len(node_rows))
    node_ids = [survey.node_ids[j] for j in node_rows]
    dim = 2 if planar else 3
    start = np.array([np.asarray(initial.nodes[n], dtype=float)[:dim] for n in node_ids]).reshape(-1, dim)
    kernel = _KERNELS[options.robust]
    offsets = view_offsets(survey, used)
    if heads is not None:
        # The reference self-calibration graph takes readings as independent (total sigma, no views).
        offsets = ViewOffsets(np.zeros(0, dtype=np.int64), np.zeros(0), np.column_stack([table.sigma] * 2))
    views = [int(v) for v in offsets.views]
    view_slot = np.full(len(survey.view_ids), -1, dtype=np.int64)
    view_slot[views] = np.arange(len(views))
    obs_view = (np.where(table.view_index[used] >= 0, view_slot[np.maximum(table.view_index[used], 0)], -1)
                if views else None)
    head_keys: dict[str, int] = {}
    active: dict[str, tuple[int, ...]] = {}
    side = fixed = None
    if heads is not None or views:
        # Imported here: an ideal survey without views (the common case) needs neither.
        from fgloc.core.head_model import extend_vector, head_dim, zoom_groups
        from fgloc.factors.camera_side import CameraSide

        zooms, group_of = zoom_groups(survey) if heads is not None else ({}, None)
        fixed = np.zeros((len(camera_keys), max([head_dim(len(z)) for z in zooms.values()] + [head_dim(1)])))
    if heads is not None and fixed is not None:
        for slot, cid in enumerate(camera_keys):
            idx = tuple(sorted(heads.active.get(cid, ())))
            if heads.start is not None and cid in heads.start:
                fixed[slot, :len(heads.start[cid])] = heads.start[cid]
            if idx:
                head_keys[cid], active[cid] = head_key(survey.camera_ids.index(cid)), idx
    if fixed is not None:
        side = CameraSide(
            len(camera_keys), cam_slot[table.camera_index[used]],
            head_keys=[head_keys.get(c, -1) for c in camera_keys], head_active=[active.get(c, ()) for c in camera_keys],
            head_fixed=fixed, view_keys=[view_key(v) for v in views], view=obs_view, view_pan=table.view_pan[used],
            head_group=None if group_of is None else group_of[used])
    readings = EliminatedReadings(
        list(camera_keys.values()),
        cam_slot[table.camera_index[used]],
        row_of[table.node_index[used]],
        table.pan[used],
        table.tilt[used],
        offsets.reading_sigma[used],
        start,
        kernel,
        options.robust_scale,
        side,
    )
    graph = gtsam.NonlinearFactorGraph()
    graph.add(readings.factor())
    gauge_sigma = options.gauge_sigma if options.gauge_sigma is not None else auto_gauge_sigma(survey, initial)
    for f in BaselinePrior(survey.mode, camera_keys[survey.gauge.origin], camera_keys[survey.gauge.baseline],
                           gauge_sigma).factors():
        graph.add(f)
    values = gtsam.Values()
    for cid, key in camera_keys.items():
        cam = initial.cameras[cid]
        values.insert(key, gtsam.Pose3(gtsam.Rot3(cam.rotation), np.asarray(cam.position, dtype=float)))
    for v, s_v in zip(views, offsets.prior_sigma):
        values.insert(view_key(v), np.zeros(2))
        graph.add(gtsam.PriorFactorVector(view_key(v), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, s_v)))
    for cid, key in head_keys.items():
        assert heads is not None and fixed is not None
        from fgloc.factors.pan_tilt_head_factor import head_prior_factor

        values.insert(key, fixed[list(camera_keys).index(cid)][list(active[cid])].copy())
        if heads.with_prior:
            graph.add(head_prior_factor(key, active[cid], None, extend_vector(heads.prior_sigmas, len(zooms[cid]))))
    return EliminatedProblem(survey, graph, values, camera_keys, node_ids, readings, np.flatnonzero(used),
                             dict(initial.unlocalized), {survey.view_ids[v]: view_key(v) for v in views},
                             head_keys, active)


def optimize_eliminated(
    problem: EliminatedProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
    stage_seconds: dict[str, float] | None = None,
) -> LMOutcome:
    """Levenberg-Marquardt over the cameras (and any user variables) of the camera graph."""
    stages = {} if stage_seconds is None else stage_seconds
    callback: IterationCallback | None = None
    if on_iteration is not None:
        def callback(k: int, values: gtsam.Values, error: float) -> None:
            on_iteration(k, problem.node_values(values), error)
    t0 = time.perf_counter()
    try:
        outcome = levenberg_marquardt(problem.graph, problem.initial, None, options.lm, callback)
    except (np.linalg.LinAlgError, RuntimeError) as exc:
        raise EliminationFailed(str(exc)) from None
    stages["optimize"] = stages.get("optimize", 0.0) + time.perf_counter() - t0
    problem.readings.at(outcome.values)  # nodes at their optimum for the final cameras
    return outcome


def estimate_eliminated(problem: EliminatedProblem, values: gtsam.Values) -> InitialEstimate:
    """Cameras of ``values`` and the nodes at their optimum for them (gauge frame)."""
    nodes = problem.readings.at(values).nodes
    planar = problem.survey.mode is NodeMode.PLANAR
    cameras = {}
    for cid, key in problem.camera_keys.items():
        pose = values.atPose3(key)
        cameras[cid] = CameraPose(np.asarray(pose.translation(), float), pose.rotation().matrix())
    points = {nid: (np.array([p[0], p[1], 0.0]) if planar else np.array(p, dtype=float))
              for nid, p in zip(problem.node_ids, nodes)}
    return InitialEstimate(cameras=cameras, nodes=points, unlocalized=dict(problem.unlocalized))


def camera_covariance(problem: EliminatedProblem, values: gtsam.Values) -> np.ndarray:
    """Joint marginal covariance of the reduced system's unknowns (camera slot order, [omega, v]
    blocks, then head vectors / view offsets: ``readings.keys``), 6k x 6k without extras."""
    keys, dims = problem.readings.keys, problem.readings.dims
    try:
        joint = gtsam.Marginals(problem.graph, values).jointMarginalCovariance(keys)
    except RuntimeError as exc:
        raise EliminationFailed(str(exc)) from None
    off = np.concatenate([[0], np.cumsum(dims)]).astype(int)
    out = np.empty((off[-1], off[-1]))
    for a, ka in enumerate(keys):
        for b, kb in enumerate(keys):
            out[off[a] : off[a + 1], off[b] : off[b + 1]] = joint.at(ka, kb)
    return out


def collect_eliminated(
    problem: EliminatedProblem,
    outcome: LMOutcome,
    options: SolverOptions = SolverOptions(),
    stage_seconds: dict[str, float] | None = None,
) -> Result:
    """Estimates at the optimizer's cameras, node positions and (optionally) marginals by back-substitution."""
    stages = {} if stage_seconds is None else stage_seconds
    values = outcome.values
    survey = problem.survey
    planar = survey.mode is NodeMode.PLANAR
    dim = 2 if planar else 3
    estimate = estimate_eliminated(problem, values)
    covs = np.full((len(problem.node_ids), dim, dim), np.nan)
    if options.compute_marginals:
        t0 = time.perf_counter()
        sigma_cc = camera_covariance(problem, values)
        covs = problem.readings.node_covariances(sigma_cc, values)
        variances = np.diagonal(covs, axis1=1, axis2=2)
        if not np.all(np.isfinite(covs)) or np.any(variances <= 0):
            raise EliminationFailed("node information is not positive definite")
        stages["marginals"] = stages.get("marginals", 0.0) + time.perf_counter() - t0
    nodes = {nid: NodeEstimate(position=estimate.nodes[nid], covariance=covs[row])
             for row, nid in enumerate(problem.node_ids)}
    stats = SolveStats(
        method="joint",  # the same joint solve as the reference graph
        iterations=outcome.iterations,
        initial_error=outcome.error_history[0],
        final_error=outcome.error_history[-1],
        converged=outcome.converged,
        stage_seconds=stages,
        error_history=outcome.error_history,
    )
    return Result(mode=survey.mode, nodes=nodes, cameras=estimate.cameras, unlocalized=dict(problem.unlocalized),
                  stats=stats)


def solve_eliminated(
    problem: EliminatedProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
    stage_seconds: dict[str, float] | None = None,
) -> Result:
    """Optimize a built camera graph and collect the result (with marginals if asked)."""
    stages = {} if stage_seconds is None else stage_seconds
    return collect_eliminated(problem, optimize_eliminated(problem, options, on_iteration, stages), options, stages)


ELIMINATED_GRAPH = SolveSteps(
    build=build_eliminated,
    optimize=optimize_eliminated,
    estimate=estimate_eliminated,
    collect=collect_eliminated,
    node_ids=lambda problem: problem.node_ids,
)


def solve_survey_eliminated(
    survey: Survey, options: SolverOptions = SolverOptions(), on_iteration: IterationCallback | None = None
) -> Result:
    """:func:`fgloc.solve.joint.solve_survey` with the nodes eliminated (same steps, same results).

    Raises :class:`EliminationFailed` when a node or camera system is numerically
    singular; the caller then runs the reference graph, which names the culprit.
    """
    return run_flagging_pipeline(survey, options, on_iteration, ELIMINATED_GRAPH)
