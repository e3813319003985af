"""Live estimates while a survey runs: an incremental solver on ``gtsam.ISAM2``.

Usage (the live survey)::

    loc = IncrementalLocalizer(camera_ids, Gauge("cam0", "cam1"), sigma)
    loc.add_observations(readings_of_one_node)   # as they arrive
    result = loc.estimate()                      # fgloc.core.model.Result, any time

How it works:

1. **Bootstrap.** Observations are buffered until the gauge cameras share
   ``min_camera_nodes`` (default 8; the closed-form start needs 4) nodes; then the batch pipeline
   (:func:`fgloc.solve.joint.solve_survey`) solves what has arrived, and its
   graph and optimum seed an ``ISAM2``.
2. **Each new node** is placed at once against the current camera estimates
   (weighted ray / ground-plane intersection, as in the closed-form start) and
   inserted with its readings; readings of known nodes just add factors. Only
   the new factors go to ``ISAM2.update`` (never the old ones again: passing a
   factor twice double counts it), then the buffers are cleared.
3. **A camera that was not in the bootstrap** waits until it sees
   ``min_camera_nodes`` placed nodes; the localizer then re-bootstraps from every reading so far (once
   per late camera).

4. **Old nodes leave iSAM2.** Every node is a child of the camera clique, and
   iSAM2 re-eliminates that clique with every update, summing one cached factor
   per child: O(n) per update (74 ms at 10,000 nodes x 8 cameras). So only the
   newest ``active_nodes`` nodes stay variables; when there are more, the oldest
   are marginalized in one step (a fixed-lag smoother over nodes): their
   readings are linearized at the current estimate, the nodes are eliminated,
   the Schur complement on the cameras joins one summary
   ``LinearContainerFactor`` that replaces those readings in iSAM2, and each
   node keeps its Gaussian conditional on the cameras
   (:mod:`fgloc.solve.node_conditionals`). A later reading of a marginalized node
   brings it back (variable plus its conditional as a linear factor).

``estimate()`` returns iSAM2's current estimate (linearization point plus the
incremental Gauss-Newton step) for cameras and active nodes, the back-substituted
conditionals for the others and, on request, every node's marginal covariance
(joint camera marginal from iSAM2, then batched numpy). ``refine()`` re-optimizes every factor from the current estimate
and reseeds iSAM2, after which the estimate matches the batch solve to
numerical tolerance.

Factors are the reference per-reading pan-tilt factors: iSAM2 evaluates only
new or relinearized ones, so the vectorized cache of the batch solver brings
nothing here. A marginalized node's readings are frozen at their linearization
(as iSAM2 leaves them anyway: a node's step rarely exceeds the relinearization
threshold); ``refine()`` relinearizes everything. A reference to ``isam.getLinearizationPoint()`` is held for the
localizer's lifetime: without it the Python binding copies the whole
linearization point for every factor callback (measured-pitfalls.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose, Gauge, NodeEstimate, NodeMode, Observation, Result, SolveStats, Survey
from fgloc.factors.baseline_prior import BaselinePrior
from fgloc.factors.pan_tilt_batch import PanTiltFactorSet
from fgloc.factors.pan_tilt_factor import planar_pan_tilt_factor
from fgloc.init.planar import MIN_SHARED_PLANAR
from fgloc.solve.joint import (
    SolverOptions,
    auto_gauge_sigma,
    build_problem,
    camera_key,
    initialize,
    node_key,
    solve_problem,
)
from fgloc.solve.levenberg_marquardt import levenberg_marquardt
from fgloc.solve.node_conditionals import MarginalizedNodes


@dataclass(frozen=True)
class IncrementalParams:
    """iSAM2 settings. ``relinearize_threshold`` is on the tangent step (rad / baseline units)."""

    relinearize_threshold: float = 0.001
    """About 0.6 node sigma at the paper's noise. 0.01 left nodes placed from a single
    reading (their other readings came later) up to 0.9 sigma off the batch optimum
    (scripts/stress_incremental.py); with the node window relinearizing costs little."""
    relinearize_skip: int = 1
    gauge_sigma: float | None = None
    """Sigma of the gauge priors; None: :func:`fgloc.solve.joint.auto_gauge_sigma`
    of the first bootstrap, then kept (see ``IncrementalLocalizer.gauge_sigma``)."""
    bootstrap_nodes: int = 12
    """Nodes the gauge cameras must share before the first batch solve. With few
    nodes a two-camera planar problem is nearly degenerate (camera height trades
    against tilt); a failed bootstrap is retried after 4 more shared nodes."""
    batch_nodes: int = 1
    """New nodes buffered before one iSAM2 update (each is placed at once against
    the current cameras either way; ``estimate()`` always flushes first)."""
    min_camera_nodes: int = 8
    """Nodes a camera must see before it joins (at bootstrap, or later by a re-bootstrap).
    The closed-form start needs 4; a camera seen by exactly 4 is barely determined
    and made iSAM2's Cholesky fail in tests, so the default keeps a margin."""
    active_nodes: int | None = 64
    """Nodes kept as iSAM2 variables (the newest). When there are more, the oldest
    are marginalized at once down to half this number, so an update costs
    O(active_nodes) instead of O(n). None keeps every node a variable."""

    def __post_init__(self) -> None:
        if self.active_nodes is not None and self.active_nodes < 2:
            raise ValueError(f"active_nodes must be >= 2 or None, got {self.active_nodes}")


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
        self._in_graph: set[str] = set()  # node ids with a variable in iSAM2 or a stored conditional
        self._waiting: list[Observation] = []  # readings of cameras not in the graph yet
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_owners: list[str | None] = []  # node of each factor in _new_factors
        self._new_values = gtsam.Values()
        self._reset_window()
        self.revived_nodes = 0
        """Marginalized nodes that became variables again because a reading of theirs came late."""
        self.update_seconds: list[float] = []

    def _reset_window(self) -> None:
        """Forget which factors iSAM2 holds and every marginalized node (a new iSAM2 follows)."""
        self._slots: dict[str, list[int]] = {}  # active node id -> its factors' slots in iSAM2
        self._readings: dict[str, list[int]] = {}  # active node id -> its readings held in iSAM2
        self._revived: dict[str, gtsam.LinearContainerFactor] = {}  # active node id -> its old conditional
        self._active: dict[str, None] = {}  # active node ids, oldest first
        self._summary: gtsam.LinearContainerFactor | None = None
        self._summary_slot: int | None = None
        self._marginalized = MarginalizedNodes(len(self.camera_ids))
        # The same conditionals as GTSAM objects: the only way back into iSAM2 for a node
        # seen by several cameras (Python builds JacobianFactors of at most 3 keys).
        self._conditionals: dict[str, gtsam.GaussianConditional] = {}

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

    @property
    def active_node_count(self) -> int:
        """Nodes that are iSAM2 variables now (the rest are stored conditionals)."""
        return len(self._active)

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
        positions = self._node_positions(values)
        node_cov = self._node_covariances() if covariances else {}
        nodes: dict[str, NodeEstimate] = {}
        for nid in self._node_ids:
            if nid in positions:
                xy = positions[nid]
                cov = node_cov.get(nid, np.full((2, 2), np.nan))
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

    def _node_positions(self, values: gtsam.Values) -> dict[str, np.ndarray]:
        """Every placed node's current (x, y): iSAM2's for active nodes, back-substituted for the rest."""
        positions = {nid: np.asarray(values.atPoint2(node_key(self._node_index[nid])), float) for nid in self._active}
        if len(self._marginalized):
            c6 = 6 * len(self.camera_ids)
            steps = np.zeros((len(self._marginalized.batches), c6))
            for b, batch in enumerate(self._marginalized.batches):
                for slot, pose in batch.camera_points.items():
                    steps[b, 6 * slot : 6 * slot + 6] = pose.localCoordinates(values.atPose3(camera_key(slot)))
            positions.update(zip(self._marginalized.node_ids(), self._marginalized.positions(steps)))
        return positions

    def _node_covariances(self) -> dict[str, np.ndarray]:
        """Every placed node's marginal covariance (2 x 2, baseline units squared)."""
        assert self._isam is not None
        covs = {nid: np.asarray(self._isam.marginalCovariance(node_key(self._node_index[nid])), float) for nid in self._active}
        if len(self._marginalized):
            slots = [self._cam_index[c] for c in self._cameras]
            joint = self._isam.jointMarginalCovariance([camera_key(s) for s in slots]).fullMatrix()
            c6 = 6 * len(self.camera_ids)
            camera_cov = np.zeros((c6, c6))
            cols = np.concatenate([np.arange(6 * s, 6 * s + 6) for s in slots])
            camera_cov[np.ix_(cols, cols)] = joint
            covs.update(zip(self._marginalized.node_ids(), self._marginalized.covariances(camera_cov)))
        return covs

    def refine(self) -> None:
        """Converge to the joint optimum of every reading so far.

        iSAM2 only relinearizes variables whose step exceeds the threshold, and
        marginalized nodes are frozen, so the estimate carries the linearization
        error of each node's placement. Here the full graph of every reading is
        optimized by the batch Levenberg-Marquardt loop from the current estimate
        and a fresh iSAM2 is seeded at the optimum (every factor relinearized
        there), which makes ``estimate()`` equal to the batch solve. Cost: a
        batch solve; meant for "survey done" or an idle moment, not per reading.
        """
        if self._isam is None:
            return
        self._flush()
        current = self._isam.calculateEstimate()
        values = self._camera_values(current)
        cams = set(values.keys())
        for nid, xy in self._node_positions(current).items():
            values.insert(node_key(self._node_index[nid]), xy)
        readings = self._factor_set(sorted(self._factored))
        graph = gtsam.NonlinearFactorGraph()
        for f in readings.factors + self._gauge_factors():
            graph.add(f)
        ordering = gtsam.Ordering()
        for k in values.keys():
            if k not in cams:
                ordering.push_back(k)
        for k in sorted(cams):
            ordering.push_back(k)
        outcome = levenberg_marquardt(graph, values, ordering, prepare=readings.prepare)
        self._seed_isam(outcome.values)

    def _camera_values(self, source: gtsam.Values) -> gtsam.Values:
        """A new ``Values`` with the pose of every camera in the graph, taken from ``source``."""
        values = gtsam.Values()
        for cid in self._cameras:
            key = camera_key(self._cam_index[cid])
            values.insert(key, source.atPose3(key))
        return values

    def _gauge_factors(self) -> list[gtsam.NonlinearFactor]:
        assert self.gauge_sigma is not None  # fixed by the bootstrap
        gauge = BaselinePrior(
            NodeMode.PLANAR,
            camera_key(self._cam_index[self.gauge.origin]),
            camera_key(self._cam_index[self.gauge.baseline]),
            self.gauge_sigma,
        )
        return list(gauge.factors())

    def _factor_set(self, readings: list[int]) -> PanTiltFactorSet:
        """The readings ``readings`` (indices into the observations) as vectorized factors:
        one numpy pass per linearization point (call ``prepare`` first) instead of a
        Python callback's arithmetic per reading."""
        obs = [self._observations[i] for i in readings]
        noise: dict[float, gtsam.noiseModel.Base] = {}
        sigmas = [self.sigma if o.sigma is None else float(o.sigma) for o in obs]
        return PanTiltFactorSet(
            np.array([camera_key(self._cam_index[o.camera]) for o in obs], np.int64),
            np.array([node_key(self._node_index[o.node]) for o in obs], np.int64),
            np.array([o.pan for o in obs]),
            np.array([o.tilt for o in obs]),
            [noise.setdefault(s, gtsam.noiseModel.Isotropic.Sigma(2, s)) for s in sigmas],
            planar=True,
        )

    def _seed_isam(self, values: gtsam.Values) -> None:
        """A fresh iSAM2 on every reading in ``_factored`` at ``values`` (cameras and placed nodes).

        Only the newest nodes become variables; the older ones are eliminated
        right here (never linearized by iSAM2) and enter as the summary factor.
        """
        self._reset_window()
        for i in sorted(self._factored):
            self._readings.setdefault(self._observations[i].node, []).append(i)
        ordered = [nid for nid in self._node_ids if nid in self._readings]  # oldest first
        limit = self.params.active_nodes
        cut = max(len(ordered) - limit // 2, 0) if limit is not None and len(ordered) > limit else 0
        graph = gtsam.NonlinearFactorGraph()
        owners: list[str | None] = []
        for f in self._gauge_factors():
            graph.add(f)
            owners.append(None)
        summary_at = None
        if cut:
            summary_at = graph.size()
            graph.add(self._eliminate(ordered[:cut], values))
            owners.append(None)
        seed_values = self._camera_values(values)
        for nid in ordered[cut:]:
            key = node_key(self._node_index[nid])
            seed_values.insert(key, values.atPoint2(key))
            for i in self._readings[nid]:
                graph.add(self._factor(self._observations[i]))
                owners.append(nid)
        isam_params = gtsam.ISAM2Params()
        isam_params.setRelinearizeThreshold(self.params.relinearize_threshold)
        isam_params.relinearizeSkip = self.params.relinearize_skip
        isam = gtsam.ISAM2(isam_params)
        # Hold the linearization point *before* the first update: the callbacks of
        # the first (largest) update otherwise each get a copy of all values, O(n^2)
        # (measured: 217 s instead of seconds for a 10,000-node bootstrap).
        lin_point = isam.getLinearizationPoint()
        # Cameras last (a group above the nodes'): the Schur-complement order the
        # batch solver uses. COLAMD's own order failed Cholesky on small, strongly
        # gauge-weighted bootstraps.
        cameras_last = gtsam.KeyGroupMap()
        for cid in self._cameras:
            cameras_last.insert2(camera_key(self._cam_index[cid]), 1)
        update = gtsam.ISAM2UpdateParams()
        update.constrainedKeys = cameras_last
        result = isam.update(graph, seed_values, update)
        self._isam = isam
        self._linearization_point = isam.getLinearizationPoint()  # keep alive (see module docstring)
        del lin_point
        self._record_slots(result, owners)
        if summary_at is not None:
            self._summary_slot = int(result.getNewFactorsIndices()[summary_at])
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_owners = []
        self._new_values = gtsam.Values()
        self._pending_nodes = 0
        self._refresh_cameras()

    def _record_slots(self, result: gtsam.ISAM2Result, owners: list[str | None]) -> None:
        """Note where iSAM2 put each new factor; new owners become active nodes."""
        for slot, nid in zip(result.getNewFactorsIndices(), owners):
            if nid is not None:
                self._slots.setdefault(nid, []).append(int(slot))
                self._active.setdefault(nid, None)

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
        previous = dict(self.__dict__)
        self._cameras = dict(result.cameras)
        self._in_graph = set(result.nodes)
        self._factored = {
            i for i, o in enumerate(self._observations) if o.camera in self._cameras and o.node in self._in_graph
        }
        self._waiting = []
        values = gtsam.Values()
        for cid, cam in result.cameras.items():
            values.insert(camera_key(self._cam_index[cid]), gtsam.Pose3(gtsam.Rot3(cam.rotation), cam.position))
        for nid, est in result.nodes.items():
            values.insert(node_key(self._node_index[nid]), np.asarray(est.position[:2], float))
        try:
            self._seed_isam(values)
        except RuntimeError:
            if not keep_on_failure:
                raise FglocError("bootstrap: the readings so far give an indeterminate system") from None
            self.__dict__.update(previous)
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
            if o.node in self._marginalized:
                self._revive(o.node)
            readings = [index]
        for i in readings:
            self._new_factors.add(self._factor(self._observations[i]))
            self._new_owners.append(o.node)
            self._readings.setdefault(o.node, []).append(i)
            self._factored.add(i)

    def _revive(self, nid: str) -> None:
        """Make a marginalized node a variable again: its conditional goes back in as a
        linear factor beside the summary, which together restore its readings' information."""
        batch, theta, _, _, _ = self._marginalized.pop(nid)
        conditional = self._conditionals.pop(nid)
        key = node_key(self._node_index[nid])
        points = self._marginalized.batches[batch].camera_points
        lin = gtsam.Values()
        lin.insert(key, theta)
        for k in conditional.keys()[1:]:
            lin.insert(k, points[int(gtsam.Symbol(k).index())])
        self._new_values.insert(key, theta)
        factor = gtsam.LinearContainerFactor(conditional, lin)
        self._new_factors.add(factor)
        self._new_owners.append(nid)
        self._revived[nid] = factor
        self.revived_nodes += 1

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
            result = self._isam.update(self._new_factors, self._new_values)
        except RuntimeError:
            # Ill-conditioned incremental system (e.g. a barely observed camera): start
            # over from a batch solve of every reading, which rebuilds iSAM2.
            self._bootstrap()
            return
        self._record_slots(result, self._new_owners)
        self._new_factors = gtsam.NonlinearFactorGraph()  # only new factors, then clear
        self._new_owners = []
        self._new_values = gtsam.Values()
        self._pending_nodes = 0
        self._marginalize_excess()
        self._refresh_cameras()

    def _marginalize_excess(self) -> None:
        limit = self.params.active_nodes
        if limit is not None and len(self._active) > limit:
            self._marginalize(list(self._active)[: len(self._active) - limit // 2])

    def _marginalize(self, node_ids: list[str]) -> None:
        """Move ``node_ids`` out of iSAM2 (see module docstring, step 4)."""
        assert self._isam is not None and self._linearization_point is not None
        estimate = self._isam.calculateEstimate()
        lin = self._camera_values(self._linearization_point)
        remove: list[int] = []
        for nid in node_ids:
            key = node_key(self._node_index[nid])
            lin.insert(key, estimate.atPoint2(key))  # relinearize the leaving node at its estimate
            remove.extend(self._slots.pop(nid))
            del self._active[nid]
        if self._summary_slot is not None:
            remove.append(self._summary_slot)
        summary = self._eliminate(node_ids, lin)
        update = gtsam.ISAM2UpdateParams()
        update.removeFactorIndices = remove
        new = gtsam.NonlinearFactorGraph()
        new.add(summary)
        result = self._isam.update(new, gtsam.Values(), update)
        self._summary_slot = int(result.getNewFactorsIndices()[0])

    def _eliminate(self, node_ids: list[str], lin: gtsam.Values) -> gtsam.LinearContainerFactor:
        """Eliminate ``node_ids`` from their factors linearized at ``lin`` (cameras and those nodes).

        Stores each node's conditional and returns the new summary: the Schur
        complement on the cameras plus the previous summary, as one linear factor.
        Readings are linearized in one vectorized pass (``PanTiltFactorSet``).
        """
        factor_set = self._factor_set([i for nid in node_ids for i in self._readings.pop(nid)])
        graph = gtsam.NonlinearFactorGraph()
        for f in factor_set.factors:
            graph.add(f)
        ordering = gtsam.Ordering()
        for nid in node_ids:
            ordering.push_back(node_key(self._node_index[nid]))
            if nid in self._revived:
                graph.add(self._revived.pop(nid))
        factor_set.prepare(lin)
        linear = graph.linearize(lin)
        if self._summary is not None:
            linear.push_back(self._summary.linearize(lin))
        conditionals, rest = linear.eliminatePartialSequential(ordering)
        summary_factor = gtsam.HessianFactor(rest)
        summary_lin = gtsam.Values()
        camera_points: dict[int, gtsam.Pose3] = {}
        for k in summary_factor.keys():
            pose = lin.atPose3(k)
            summary_lin.insert(k, pose)
            camera_points[int(gtsam.Symbol(k).index())] = pose
        batch = self._marginalized.new_batch(camera_points)
        c6 = 6 * len(self.camera_ids)
        for i in range(conditionals.size()):
            cond = conditionals.at(i)
            keys = cond.keys()
            nid = self._node_ids[int(gtsam.Symbol(keys[0]).index())]
            s_parents = cond.S()
            s_full = np.zeros((2, c6))
            for j, k in enumerate(keys[1:]):
                slot = int(gtsam.Symbol(k).index())
                s_full[:, 6 * slot : 6 * slot + 6] = s_parents[:, 6 * j : 6 * j + 6]
            self._marginalized.add(batch, nid, lin.atPoint2(keys[0]), cond.R(), s_full, cond.d())
            self._conditionals[nid] = cond
        self._summary = gtsam.LinearContainerFactor(summary_factor, summary_lin)
        return self._summary

    def _refresh_cameras(self) -> None:
        """Camera poses for placing new nodes: iSAM2's linearization point (held
        reference, no solve); it trails the estimate by less than the
        relinearization threshold, plenty for a starting guess."""
        assert self._linearization_point is not None
        for cid in self._cameras:
            pose = self._linearization_point.atPose3(camera_key(self._cam_index[cid]))
            self._cameras[cid] = CameraPose(np.asarray(pose.translation(), float), pose.rotation().matrix())
