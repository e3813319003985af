"""The joint solve: every pan-tilt reading is a factor in one GTSAM graph.

Variables: one ``Pose3`` per camera base (key ``c<i>``, i = index in
``Survey.camera_ids``) and one node position per observed node (key ``l<j>``,
j = index in ``Survey.node_ids``): ``Point2`` on z = 0 for planar surveys,
``Point3`` for 3d surveys. The :class:`~factors.BaselinePrior` pins the gauge.

The initial estimate comes from the bearings alone
(:mod:`fgloc.initialization`), the optimizer is Levenberg-Marquardt
(:mod:`fgloc.levenberg_marquardt`), and the marginal covariances come from
``gtsam.Marginals`` on the final linearization. Camera pose covariances are
6x6 in GTSAM's body-frame tangent ``[omega, v]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.baseline_prior import BaselinePrior
from factors.pan_tilt_batch import PanTiltFactorSet
from fgloc.initialization import InitialEstimate, initialize_planar
from fgloc.levenberg_marquardt import IterationCallback, LMParams, levenberg_marquardt
from fgloc.model import CameraPose, FglocError, NodeEstimate, NodeMode, Result, SolveStats, Survey

camera_key = gtsam.symbol_shorthand.C
node_key = gtsam.symbol_shorthand.L


class SolveError(FglocError):
    """The survey cannot be solved as given."""


@dataclass(frozen=True)
class SolverOptions:
    """Settings of the joint solve."""

    lm: LMParams = LMParams()
    compute_marginals: bool = True
    #: Sigma of the gauge priors in baseline units; None scales it to the problem
    #: (see :func:`auto_gauge_sigma`).
    gauge_sigma: float | None = None


def auto_gauge_sigma(survey: Survey, initial: InitialEstimate) -> float:
    """A gauge sigma 1e-3 times a typical node standard deviation (sigma x camera range).

    Small enough that the gauge leaks ~1e-6 (relative) into the marginals, large
    enough that Cholesky stays well conditioned when cameras stand far away or
    high above a short baseline. The positions do not depend on it.
    """
    table = survey.observation_table
    ranges = []
    for cid, cam in initial.cameras.items():
        i = survey.camera_ids.index(cid)
        js = np.unique(table.node_index[table.camera_index == i])
        pts = [initial.nodes[survey.node_ids[j]] for j in js if survey.node_ids[j] in initial.nodes]
        if pts:
            ranges.append(np.linalg.norm(np.asarray(pts) - cam.position, axis=1))
    typical_range = float(np.median(np.concatenate(ranges))) if ranges else 1.0
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
    unlocalized: dict[str, str] = field(default_factory=dict)

    def prepare(self, values: gtsam.Values) -> None:
        """Evaluate the pan-tilt factors at ``values`` in one vectorized pass.

        Call before ``graph.linearize(values)`` or ``graph.error(values)`` for
        speed; without it the factors compute one reading at a time.
        """
        self.pan_tilt.prepare(values)

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


def build_problem(survey: Survey, initial: InitialEstimate, options: SolverOptions = SolverOptions()) -> LocalizationProblem:
    """One factor per observation, the gauge prior, and initial values from ``initial``."""
    planar = survey.mode is NodeMode.PLANAR
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    camera_keys = {cid: camera_key(i) for i, cid in enumerate(survey.camera_ids) if cid in initial.cameras}
    node_keys = {nid: node_key(j) for j, nid in enumerate(survey.node_ids) if nid in initial.nodes}
    for cid, key in camera_keys.items():
        values.insert(key, _pose3(initial.cameras[cid]))
    for nid, key in node_keys.items():
        p = np.asarray(initial.nodes[nid], dtype=float)
        if planar:
            values.insert(key, p[:2].copy())
        else:
            values.insert(key, p.copy())
    table = survey.observation_table
    cam_key_of = np.array([camera_keys.get(c, -1) for c in survey.camera_ids], dtype=np.int64)
    node_key_of = np.array([node_keys.get(n, -1) for n in survey.node_ids], dtype=np.int64)
    obs_cam_keys = cam_key_of[table.camera_index]
    obs_node_keys = node_key_of[table.node_index]
    used = (obs_cam_keys >= 0) & (obs_node_keys >= 0)
    noise_cache: dict[float, gtsam.noiseModel.Base] = {}
    for sigma in np.unique(table.sigma[used]):
        noise_cache[float(sigma)] = gtsam.noiseModel.Isotropic.Sigma(2, float(sigma))
    pan_tilt = PanTiltFactorSet(
        obs_cam_keys[used],
        obs_node_keys[used],
        table.pan[used],
        table.tilt[used],
        [noise_cache[float(s)] for s in table.sigma[used]],
        planar=planar,
    )
    for f in pan_tilt.factors:
        graph.add(f)
    gauge_sigma = options.gauge_sigma if options.gauge_sigma is not None else auto_gauge_sigma(survey, initial)
    gauge = BaselinePrior(survey.mode, camera_keys[survey.gauge.origin], camera_keys[survey.gauge.baseline], gauge_sigma)
    for f in gauge.factors():
        graph.add(f)
    return LocalizationProblem(
        survey=survey,
        graph=graph,
        initial=values,
        camera_keys=camera_keys,
        node_keys=node_keys,
        pan_tilt=pan_tilt,
        unlocalized=dict(initial.unlocalized),
    )


def initialize(survey: Survey) -> InitialEstimate:
    """Closed-form initial estimate for the survey's mode."""
    if survey.mode is NodeMode.PLANAR:
        return initialize_planar(survey)
    raise SolveError("3d surveys are not supported yet")


def solve_problem(
    problem: LocalizationProblem,
    options: SolverOptions = SolverOptions(),
    on_iteration: IterationCallback | None = None,
    stage_seconds: dict[str, float] | None = None,
) -> Result:
    """Optimize a built problem and collect estimates and marginal covariances."""
    stages = {} if stage_seconds is None else stage_seconds
    t0 = time.perf_counter()
    outcome = levenberg_marquardt(
        problem.graph, problem.initial, problem.elimination_ordering(), options.lm, on_iteration, problem.prepare
    )
    stages["optimize"] = time.perf_counter() - t0
    values = outcome.values
    survey = problem.survey
    planar = survey.mode is NodeMode.PLANAR
    covariances: dict[str, np.ndarray] = {}
    if options.compute_marginals:
        t0 = time.perf_counter()
        try:
            problem.prepare(values)
            marginals = gtsam.Marginals(problem.graph.linearize(values), values)
            covariances = {nid: marginals.marginalCovariance(key) for nid, key in problem.node_keys.items()}
        except RuntimeError as exc:
            raise SolveError(f"marginal covariances are undefined (the graph is rank deficient): {exc}") from None
        stages["marginals"] = time.perf_counter() - t0
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


def solve_survey(
    survey: Survey, options: SolverOptions = SolverOptions(), on_iteration: IterationCallback | None = None
) -> Result:
    """Initialize from the bearings, build the graph, optimize, and compute marginals."""
    stages: dict[str, float] = {}
    t0 = time.perf_counter()
    init = initialize(survey)
    stages["initialize"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem = build_problem(survey, init, options)
    stages["build"] = time.perf_counter() - t0
    return solve_problem(problem, options, on_iteration, stages)
