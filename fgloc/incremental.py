"""Live estimates while a survey runs: an incremental solver on ``gtsam.ISAM2``.

Usage (the live survey)::

    loc = IncrementalLocalizer(camera_ids, Gauge("cam0", "cam1"), sigma)
    loc.add_observations(readings_of_one_node)   # as they arrive
    result = loc.estimate()                      # fgloc.model.Result, any time

How it works:

1. **Bootstrap.** Observations are buffered until the gauge cameras share
   ``min_camera_nodes`` (default 8; the closed-form start needs 4) nodes; then the batch pipeline
   (:func:`fgloc.joint_solver.solve_survey`) solves what has arrived, and its
   graph and optimum seed an ``ISAM2``.
2. **Each new node** is placed at once against the current camera estimates
   (weighted ray / ground-plane intersection, as in the closed-form start) and
   inserted with its readings; readings of known nodes just add factors. Only
   the new factors go to ``ISAM2.update`` (never the old ones again: passing a
   factor twice double counts it), then the buffers are cleared.
3. **A camera that was not in the bootstrap** waits until it sees
   ``min_camera_nodes`` placed nodes; the localizer then re-bootstraps from every reading so far (once
   per late camera).

``estimate()`` returns iSAM2's current estimate (linearization point plus the
incremental Gauss-Newton step) and, on request, each node's marginal
covariance. ``refine()`` re-optimizes every factor from the current estimate
and reseeds iSAM2, after which the estimate matches the batch solve to
numerical tolerance.

Factors are the reference per-reading pan-tilt factors: iSAM2 evaluates only
new or relinearized ones, so the vectorized cache of the batch solver brings
nothing here. A reference to ``isam.getLinearizationPoint()`` is held for the
localizer's lifetime: without it the Python binding copies the whole
linearization point for every factor callback (measured-pitfalls.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.baseline_prior import BaselinePrior
from factors.pan_tilt_factor import planar_pan_tilt_factor
from fgloc.geometry import pan_tilt_bearing
from fgloc.initialization import MIN_SHARED_PLANAR
from fgloc.joint_solver import (
    SolverOptions,
    auto_gauge_sigma,
    build_problem,
    camera_key,
    initialize,
    node_key,
    solve_problem,
)
from fgloc.levenberg_marquardt import levenberg_marquardt
from fgloc.model import CameraPose, FglocError, Gauge, NodeEstimate, NodeMode, Observation, Result, SolveStats, Survey


@dataclass(frozen=True)
class IncrementalParams:
    """iSAM2 settings. ``relinearize_threshold`` is on the tangent step (rad / baseline units)."""

    relinearize_threshold: float = 0.01
    relinearize_skip: int = 10
    gauge_sigma: float | None = None
    """Sigma of the gauge priors; None: :func:`fgloc.joint_solver.auto_gauge_sigma`
    of the first bootstrap, then kept (see ``IncrementalLocalizer.gauge_sigma``)."""
    bootstrap_nodes: int = 12
    """Nodes the gauge cameras must share before the first batch solve. With few
    nodes a two-camera planar problem is nearly degenerate (camera height trades
    against tilt); a failed bootstrap is retried after 4 more shared nodes."""
    batch_nodes: int = 1
    """New nodes buffered before one iSAM2 update (each is placed at once against
    the current cameras either way; ``estimate()`` always flushes first). An update
    re-eliminates the camera clique, whose cost grows with n, so batching k nodes
    divides that cost per node by about k."""
    min_camera_nodes: int = 8
    """Nodes a camera must see before it joins (at bootstrap, or later by a re-bootstrap).
    The closed-form start needs 4; a camera seen by exactly 4 is barely determined
    and made iSAM2's Cholesky fail in tests, so the default keeps a margin."""


class IncrementalLocalizer:
    """Planar survey estimates updated one batch of readings at a time (see module docstring)."""

    def __init__(self, camera_ids: list[str], gauge: Gauge, sigma: float, params: IncrementalParams = IncrementalParams()):
        for cid in (gauge.origin, gauge.baseline):
            if cid not in camera_ids:
                raise FglocError(f"gauge: camera {cid!r} is not among camera_ids")
        self.camera_ids = list(camera_ids)
        self.gauge = gauge
        self.sigma = float(sigma)
        self.params = params
        self._observations: list[Observation] = []
        self._by_node: dict[str, list[int]] = {}  # node id -> indices into _observations
        self._factored: set[int] = set()  # readings already passed to iSAM2 (or about to be)
        self._node_ids: list[str] = []
        self._node_index: dict[str, int] = {}
        self._cam_index = {c: i for i, c in enumerate(self.camera_ids)}
        self._isam: gtsam.ISAM2 | None = None
        self._next_bootstrap_at = 0
        self._pending_nodes = 0
        self.gauge_sigma: float | None = params.gauge_sigma
        self._linearization_point: gtsam.Values | None = None
        self._cameras: dict[str, CameraPose] = {}
        self._in_graph: set[str] = set()  # node ids with a variable in iSAM2
        self._waiting: list[Observation] = []  # readings of cameras not in the graph yet
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self.update_seconds: list[float] = []

    # ----------------------------------------------------------------- input
    def add_observations(self, observations: list[Observation]) -> None:
        """Take new readings (each reading exactly once) and update the estimate."""
        first = len(self._observations)
        for o in observations:
            if o.camera not in self._cam_index:
                raise FglocError(f"observation: camera: unknown camera {o.camera!r}")
            if o.node not in self._node_index:
                self._node_index[o.node] = len(self._node_ids)
                self._node_ids.append(o.node)
                self._by_node[o.node] = []
            self._by_node[o.node].append(len(self._observations))
            self._observations.append(o)
        if self._isam is None:
            shared = self._gauge_pair_shares()
            if shared >= max(MIN_SHARED_PLANAR, self.params.bootstrap_nodes, self._next_bootstrap_at):
                if not self._bootstrap(keep_on_failure=True):
                    self._next_bootstrap_at = shared + 4
            return
        t0 = time.perf_counter()
        for i in range(first, len(self._observations)):
            self._insert(i)
        if self._waiting and self._late_camera_ready() and self._bootstrap(keep_on_failure=True):
            pass
        elif self.params.batch_nodes <= 1 or self._pending_nodes >= self.params.batch_nodes:
            self._flush()
        self.update_seconds.append(time.perf_counter() - t0)

    @property
    def bootstrapped(self) -> bool:
        return self._isam is not None

    # ---------------------------------------------------------------- output
    def estimate(self, covariances: bool = True) -> Result:
        """Current node and camera estimates (gauge frame), node marginals if asked."""
        if self._isam is not None:
            self._flush()
        if self._isam is None:
            raise FglocError(
                f"not enough readings yet: the gauge cameras must share {MIN_SHARED_PLANAR} nodes before a first estimate"
            )
        values = self._isam.calculateEstimate()
        nodes: dict[str, NodeEstimate] = {}
        for nid in self._node_ids:
            if nid not in self._in_graph:
                continue
            key = node_key(self._node_index[nid])
            xy = values.atPoint2(key)
            cov = self._isam.marginalCovariance(key) if covariances else np.full((2, 2), np.nan)
            nodes[nid] = NodeEstimate(position=np.array([xy[0], xy[1], 0.0]), covariance=np.asarray(cov, float))
        cameras = {}
        for cid in self._cameras:
            pose = values.atPose3(camera_key(self._cam_index[cid]))
            cameras[cid] = CameraPose(np.asarray(pose.translation(), float), pose.rotation().matrix())
        unlocalized = {n: "not placed yet (no reading from a placed camera)" for n in self._node_ids if n not in self._in_graph}
        stats = SolveStats(
            method="isam2",
            iterations=len(self.update_seconds),
            initial_error=float("nan"),
            final_error=float("nan"),
            converged=True,
        )
        return Result(mode=NodeMode.PLANAR, nodes=nodes, cameras=cameras, unlocalized=unlocalized, stats=stats)

    def refine(self) -> None:
        """Converge to the joint optimum of every reading so far.

        iSAM2 only relinearizes variables whose step exceeds the threshold, so
        its estimate carries the linearization error of each node's placement.
        Here the full graph is optimized by the batch Levenberg-Marquardt loop
        from the current estimate and a fresh iSAM2 is seeded at the optimum
        (every factor relinearized there), which makes ``estimate()`` equal to
        the batch solve. Cost: a batch solve; meant for "survey done" or an
        idle background thread, not per reading.
        """
        if self._isam is None:
            return
        self._flush()
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(self._isam.getFactorsUnsafe())  # own the factor pointers; the old iSAM2 goes away
        values = self._isam.calculateEstimate()
        ordering = gtsam.Ordering()
        cams = {camera_key(self._cam_index[c]) for c in self._cameras}
        for k in values.keys():
            if k not in cams:
                ordering.push_back(k)
        for k in sorted(cams):
            ordering.push_back(k)
        outcome = levenberg_marquardt(graph, values, ordering)
        self._seed_isam(graph, outcome.values)

    def _seed_isam(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        isam_params = gtsam.ISAM2Params()
        isam_params.setRelinearizeThreshold(self.params.relinearize_threshold)
        isam_params.relinearizeSkip = self.params.relinearize_skip
        self._isam = gtsam.ISAM2(isam_params)
        # Hold the linearization point *before* the first update: the callbacks of
        # the first (largest) update otherwise each get a copy of all values, O(n^2)
        # (measured: 217 s instead of seconds for a 10,000-node bootstrap).
        self._linearization_point = self._isam.getLinearizationPoint()
        # Cameras last (a group above the nodes'): the Schur-complement order the
        # batch solver uses. COLAMD's own order failed Cholesky on small, strongly
        # gauge-weighted bootstraps.
        cameras_last = gtsam.KeyGroupMap()
        for cid in self._cameras:
            cameras_last.insert2(camera_key(self._cam_index[cid]), 1)
        update = gtsam.ISAM2UpdateParams()
        update.constrainedKeys = cameras_last
        self._isam.update(graph, values, update)
        self._linearization_point = self._isam.getLinearizationPoint()  # keep alive (see module docstring)
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._pending_nodes = 0
        self._refresh_cameras()

    # -------------------------------------------------------------- internals
    def survey(self) -> Survey:
        """Everything received so far as a planar :class:`Survey` (no truth)."""
        return self._survey_of(self.camera_ids)

    def _survey_of(self, cameras: list[str]) -> Survey:
        keep = set(cameras)
        return Survey(
            mode=NodeMode.PLANAR,
            gauge=self.gauge,
            sigma=self.sigma,
            camera_ids=[c for c in self.camera_ids if c in keep],
            node_ids=list(self._node_ids),
            observations=[o for o in self._observations if o.camera in keep],
        )

    def _gauge_pair_shares(self) -> int:
        seen: dict[str, set[str]] = {self.gauge.origin: set(), self.gauge.baseline: set()}
        for o in self._observations:
            if o.camera in seen:
                seen[o.camera].add(o.node)
        return len(seen[self.gauge.origin] & seen[self.gauge.baseline])

    def _factor(self, o: Observation) -> gtsam.CustomFactor:
        sigma = self.sigma if o.sigma is None else float(o.sigma)
        return planar_pan_tilt_factor(
            camera_key(self._cam_index[o.camera]), node_key(self._node_index[o.node]), o.pan, o.tilt, sigma
        )

    def _bootstrap(self, keep_on_failure: bool = False) -> bool:
        """Batch-solve everything received so far and seed a fresh iSAM2 with it.

        Cameras the closed-form start cannot place yet (fewer than 4 shared
        nodes) are left out and wait. Returns False (state unchanged) if
        ``keep_on_failure`` and the batch solve fails.
        """
        nodes_seen: dict[str, set[str]] = {}
        for o in self._observations:
            nodes_seen.setdefault(o.camera, set()).add(o.node)
        candidates = [c for c in self.camera_ids if len(nodes_seen.get(c, ())) >= self.params.min_camera_nodes]
        gauge_pair = [self.gauge.origin, self.gauge.baseline]
        result = None
        for cams in (candidates, gauge_pair):
            try:
                survey = self._survey_of(cams)
                init = initialize(survey)
                sigma = self.gauge_sigma if self.gauge_sigma is not None else auto_gauge_sigma(survey, init)
                options = SolverOptions(compute_marginals=False, gauge_sigma=sigma)
                result = solve_problem(build_problem(survey, init, options), options).result
                self.gauge_sigma = sigma
                break
            except (FglocError, RuntimeError):  # degenerate start, or indeterminate system
                continue
        if result is None:
            if keep_on_failure:
                return False
            raise FglocError("bootstrap: the readings so far cannot be solved (degenerate geometry)")
        previous = (self._isam, self._linearization_point, self._cameras, self._in_graph, self._factored, self._waiting)
        self._cameras = dict(result.cameras)
        self._in_graph = set(result.nodes)
        self._factored = set()
        self._waiting = []
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for cid, cam in result.cameras.items():
            values.insert(camera_key(self._cam_index[cid]), gtsam.Pose3(gtsam.Rot3(cam.rotation), cam.position))
        for nid, est in result.nodes.items():
            values.insert(node_key(self._node_index[nid]), np.asarray(est.position[:2], float))
        for i, o in enumerate(self._observations):
            if o.camera in self._cameras and o.node in self._in_graph:
                graph.add(self._factor(o))
                self._factored.add(i)
        gauge = BaselinePrior(
            NodeMode.PLANAR,
            camera_key(self._cam_index[self.gauge.origin]),
            camera_key(self._cam_index[self.gauge.baseline]),
            self.gauge_sigma,
        )
        for f in gauge.factors():
            graph.add(f)
        try:
            self._seed_isam(graph, values)
        except RuntimeError:
            if not keep_on_failure:
                raise FglocError("bootstrap: the readings so far give an indeterminate system") from None
            self._isam, self._linearization_point, self._cameras, self._in_graph, self._factored, self._waiting = previous
            return False
        for i in range(len(self._observations)):  # late cameras wait; unplaced nodes retry
            self._insert(i)
        self._flush()
        return True

    def _place(self, readings: list[Observation]) -> np.ndarray | None:
        """Weighted ground-plane intersection of the rays of ``readings`` from placed cameras."""
        points, weights = [], []
        for o in readings:
            cam = self._cameras[o.camera]
            d = cam.rotation @ pan_tilt_bearing(o.pan, o.tilt)
            if d[2] >= -1e-9 or cam.position[2] <= 0:
                continue
            s = -cam.position[2] / d[2]
            points.append((cam.position + s * d)[:2])
            weights.append((-d[2] / s) ** 2)
        if not points:
            return None
        w = np.array(weights)
        return (w[:, None] * np.array(points)).sum(0) / w.sum()

    def _insert(self, index: int) -> None:
        """Turn reading ``index`` into a factor (placing its node first if it is new)."""
        if index in self._factored:
            return
        o = self._observations[index]
        if o.camera not in self._cameras:
            self._waiting.append(o)
            return
        if o.node not in self._in_graph:
            readings = [
                i
                for i in self._by_node[o.node]
                if i not in self._factored and self._observations[i].camera in self._cameras
            ]
            xy = self._place([self._observations[i] for i in readings])
            if xy is None:
                return
            self._new_values.insert(node_key(self._node_index[o.node]), xy)
            self._in_graph.add(o.node)
            self._pending_nodes += 1
        else:
            readings = [index]
        for i in readings:
            self._new_factors.add(self._factor(self._observations[i]))
            self._factored.add(i)

    def _late_camera_ready(self) -> bool:
        for cid in {o.camera for o in self._waiting}:
            placed = {o.node for o in self._waiting if o.camera == cid and o.node in self._in_graph}
            if len(placed) >= max(MIN_SHARED_PLANAR, self.params.min_camera_nodes):
                return True
        return False

    def _flush(self) -> None:
        assert self._isam is not None
        if self._new_factors.size() == 0 and self._new_values.size() == 0:
            return
        try:
            self._isam.update(self._new_factors, self._new_values)
        except RuntimeError:
            # Ill-conditioned incremental system (e.g. a barely observed camera): start
            # over from a batch solve of every reading, which rebuilds iSAM2.
            self._bootstrap()
            return
        self._new_factors = gtsam.NonlinearFactorGraph()  # only new factors, then clear
        self._new_values = gtsam.Values()
        self._pending_nodes = 0
        self._refresh_cameras()

    def _refresh_cameras(self) -> None:
        """Camera poses for placing new nodes: iSAM2's linearization point (held
        reference, no solve); it trails the estimate by less than the
        relinearization threshold, plenty for a starting guess."""
        assert self._linearization_point is not None
        for cid in self._cameras:
            pose = self._linearization_point.atPose3(camera_key(self._cam_index[cid]))
            self._cameras[cid] = CameraPose(np.asarray(pose.translation(), float), pose.rotation().matrix())
