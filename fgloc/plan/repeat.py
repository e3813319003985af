"""What to re-measure: the next readings (camera, node) that shrink the Cramér–Rao bound most.

Linearized at a solve's estimate, in the survey's gauge frame (planar surveys;
lengths in baseline units). The unknowns are every camera pose (the two gauge
cameras restricted to motions that keep their ground point, as the solver's
gauge does) and every node's (x, y); the joint information ``H`` is small enough
to hold its inverse ``Sigma`` densely (6K + 2N). A new reading of pair p with
whitened Jacobian ``J`` (2 x 8) changes it by a rank-2 update, with gains:

* ``logdet``: ``log det(I + J Sigma_pp J^T)`` (nats; monotone submodular, so lazy
  greedy is exact and within (1 - 1/e) of the best budget-B choice);
* ``mean``: the drop of the summed node traces,
  ``tr((I + J Sigma_pp J^T)^-1 J Sigma_pN Sigma_Np J^T)`` (lazy greedy as a heuristic);
* ``worst``: the drop of the trace of the currently worst node.

Only pairs already read at least once (the camera can see the node) are candidates.
``RepeatPlan.logdet_bound`` is the concavity bound ``f(w) + B max_p g_p - w . g`` with
``g_p = tr(J_p Sigma(w) J_p^T)`` evaluated at the greedy plan itself only (loose); the solved
convex relaxation, for ``mean`` and ``logdet``, and the "every reading 3x" certificate are in
:mod:`fgloc.plan.repeat_bound`.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.model import NodeMode, Result, Survey
from fgloc.factors.pan_tilt_batch import batch_pan_tilt_error
from fgloc.plan.fisher import gauge_basis


@dataclass(frozen=True)
class Reading:
    """One planned reading and its predicted gain (objective units) when taken in plan order."""

    camera: str
    node: str
    gain: float


@dataclass(frozen=True, eq=False)
class RepeatPlan:
    """The readings in order, the objective and the summed node trace (baseline units^2) before and after."""

    objective: str
    readings: list[Reading]
    before: float
    after: float
    trace_before: float
    trace_after: float
    logdet_bound: float  # bound on log det gain over the current survey (nats), logdet objective only
    logdet_gain: float
    n_pairs: int
    n_readings_now: int


class RepeatModel:
    """The dense joint covariance of a solved survey and its candidate readings (see the module docstring)."""

    def __init__(self, survey: Survey, result: Result) -> None:
        if survey.mode is not NodeMode.PLANAR:
            raise FglocError(f"survey: nodes: repeat planning supports planar surveys ({survey.mode.value})")
        cams = [c for c in survey.camera_ids if c in result.cameras]
        nodes = [n for n in survey.node_ids if n in result.nodes]
        gauge = (survey.gauge.origin, survey.gauge.baseline)
        bases = {c: gauge_basis(result.cameras[c].rotation) if c in gauge else np.eye(6) for c in cams}
        off, self.cam_slice = 0, {}
        for c in cams:
            self.cam_slice[c] = np.arange(off, off + bases[c].shape[1])
            off += bases[c].shape[1]
        self.node_index = {n: off + 2 * j for j, n in enumerate(nodes)}
        self.dim, self.node_dims = off + 2 * len(nodes), np.arange(off, off + 2 * len(nodes))
        weight: dict[tuple[str, str], float] = {}
        for o in survey.observations:
            if o.camera in result.cameras and o.node in result.nodes:
                s = survey.sigma if o.sigma is None else o.sigma
                weight[(o.camera, o.node)] = weight.get((o.camera, o.node), 0.0) + 1.0 / s**2
        self.pairs = sorted(weight)
        self.n_readings = sum(1 for o in survey.observations if (o.camera, o.node) in weight)
        rot = np.array([result.cameras[c].rotation for c, _ in self.pairs])
        pos = np.array([result.cameras[c].position for c, _ in self.pairs])
        pts = np.array([result.nodes[n].position for _, n in self.pairs])
        zeros = np.zeros(len(self.pairs))
        _, h_pose, h_point = batch_pan_tilt_error(rot, pos, pts, zeros, zeros)
        basis = np.array([np.pad(bases[c], ((0, 0), (0, 6 - bases[c].shape[1]))) for c, _ in self.pairs])
        self.jac = np.concatenate([h_pose @ basis, h_point[:, :, :2]], axis=2) / survey.sigma  # (P, 2, 8)
        self.loc = np.array([np.concatenate([np.pad(self.cam_slice[c], (0, 6 - len(self.cam_slice[c])),
                                                    constant_values=self.cam_slice[c][0]),
                                             [self.node_index[n], self.node_index[n] + 1]]) for c, n in self.pairs])
        # The gauge cameras have 4 unknowns; their padded columns repeat index 0 with zero Jacobian.
        pad = np.array([[k >= len(self.cam_slice[c]) and k < 6 for k in range(8)] for c, _ in self.pairs])
        self.jac[pad[:, None, :].repeat(2, axis=1)] = 0.0
        h = np.zeros((self.dim, self.dim))
        w = np.array([weight[p] * survey.sigma**2 for p in self.pairs])
        for p in range(len(self.pairs)):
            idx = self.loc[p]
            np.add.at(h, (idx[:, None], idx[None, :]), w[p] * self.jac[p].T @ self.jac[p])
        self.information = h
        self.base_weights = w  # readings per pair at the survey's sigma (the one-pass information is sum w J^T J)
        self.covariance = np.linalg.inv(h)

    def node_traces(self, cov: FloatArray | None = None) -> FloatArray:
        c = self.covariance if cov is None else cov
        d = np.diag(c)[self.node_dims]
        return d[0::2] + d[1::2]

    def gains(self, objective: str, which: np.ndarray | None = None) -> FloatArray:
        """Gain of one more reading for candidate pairs ``which`` (default all)."""
        idx = np.arange(len(self.pairs)) if which is None else which
        loc = self.loc[idx]
        jac = self.jac[idx]
        s_loc = self.covariance[loc[:, :, None], loc[:, None, :]]
        k = np.eye(2) + jac @ s_loc @ jac.transpose(0, 2, 1)
        if objective == "logdet":
            return np.linalg.slogdet(k)[1]
        if objective == "mean":
            cross = self.covariance[self.node_dims[0]:, :][:, loc].transpose(1, 0, 2)  # (P, 2N, 8); node dims are last
            g = jac @ np.einsum("pki,pkj->pij", cross, cross) @ jac.transpose(0, 2, 1)
            return np.einsum("pij,pji->p", np.linalg.inv(k), g)
        worst = int(np.argmax(self.node_traces()))
        rows = self.node_dims[2 * worst: 2 * worst + 2]
        cross = self.covariance[rows][:, loc].transpose(1, 0, 2)  # (P, 2, 8)
        g = jac @ np.einsum("pki,pkj->pij", cross, cross) @ jac.transpose(0, 2, 1)
        return np.einsum("pij,pji->p", np.linalg.inv(k), g)

    def take(self, p: int) -> None:
        """Add one reading of pair ``p``: rank-2 update of the covariance."""
        loc, jac = self.loc[p], self.jac[p]
        sj = self.covariance[:, loc] @ jac.T  # (D, 2)
        k = np.eye(2) + jac @ sj[loc]
        self.covariance -= sj @ np.linalg.solve(k, sj.T)
        np.add.at(self.information, (loc[:, None], loc[None, :]), jac.T @ jac)


def objective_of(model: RepeatModel, objective: str) -> float:
    if objective == "logdet":
        return -float(np.linalg.slogdet(model.information)[1])
    t = model.node_traces()
    return float(t.sum() if objective == "mean" else t.max())


def plan_repeats(survey: Survey, result: Result, budget: int, objective: str = "mean",
                 stop_trace: float | None = None, progress: Callable[[int, int], None] | None = None) -> RepeatPlan:
    """The next ``budget`` readings by lazy greedy (stop early once the summed node trace <= ``stop_trace``)."""
    if objective not in ("mean", "worst", "logdet"):
        raise FglocError(f"objective: expected one of mean, worst, logdet ({objective!r})")
    if budget < 0:
        raise FglocError(f"budget: must be >= 0 ({budget})")
    model = RepeatModel(survey, result)
    before, trace_before = objective_of(model, objective), float(model.node_traces().sum())
    logdet0 = float(np.linalg.slogdet(model.information)[1])
    readings: list[Reading] = []
    counts = np.zeros(len(model.pairs))
    lazy = objective != "worst"  # the worst node changes: re-evaluate everything
    heap = [(-g, p, 0) for p, g in enumerate(model.gains(objective))]
    heapq.heapify(heap)
    for step in range(budget):
        if stop_trace is not None and model.node_traces().sum() <= stop_trace:
            break
        if not lazy and step > 0:
            heap = [(-g, p, step) for p, g in enumerate(model.gains(objective))]
            heapq.heapify(heap)
        while True:
            neg, p, at = heapq.heappop(heap)
            if at == step:
                break
            heapq.heappush(heap, (-float(model.gains(objective, np.array([p]))[0]), p, step))
        model.take(p)
        counts[p] += 1
        heapq.heappush(heap, (-float(model.gains(objective, np.array([p]))[0]), p, step + 1))
        cam, node = model.pairs[p]
        readings.append(Reading(cam, node, -neg))
        if progress is not None:
            progress(step + 1, budget)
    logdet1 = float(np.linalg.slogdet(model.information)[1])
    g = model.gains("logdet") if readings else np.zeros(0)
    # concave f(w) = log det(H0 + sum w_p F_p); gradient g_p = tr(J Sigma J^T), not log det(I + ...)
    grad = np.einsum("pij,pji->p", model.jac, model.covariance[model.loc[:, :, None], model.loc[:, None, :]]
                     @ model.jac.transpose(0, 2, 1)) if readings else g
    bound = logdet1 + len(readings) * float(grad.max(initial=0.0)) - float(counts @ grad) if readings else logdet1
    return RepeatPlan(objective, readings, before, objective_of(model, objective), trace_before,
                      float(model.node_traces().sum()), bound - logdet0, logdet1 - logdet0, len(model.pairs),
                      model.n_readings)
