"""Where to put the cameras: greedy selection by the Cramér–Rao bound.

Objectives (all minimized, on node covariances in metres):

* ``mean``: mean over nodes of the trace (A-optimal, mean squared error, m^2);
* ``worst``: the largest node trace (m^2);
* ``logdet``: minus log det of the joint node information (D-optimal, nats).

Selection runs in the camera-independent node-cloud gauge of
:mod:`fgloc.plan.fisher`, where ``logdet`` is monotone submodular: greedy
selection under a cardinality constraint is within (1 - 1/e) of the best gain
(Nemhauser et al.), and within 1/2 when sites offer several heights (a
partition matroid). ``logdet`` uses lazy evaluation (stale gains are upper
bounds, so lazy greedy picks exactly what plain greedy picks); ``mean`` and
``worst`` are not submodular and are evaluated in full at every step.
The gauge pair is then the pair of chosen cameras whose solver-gauge Cramér–Rao
bound scores best on the same objective, and the prediction is reported in that
gauge (the frame fgloc's solve reports).
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.plan.fisher import (
    CandidateInfo,
    CloudEvaluation,
    Jacobians,
    candidate_info,
    cloud_evaluate,
    gauge_frame_covariances,
    traces,
)
from fgloc.plan.site import PlanProblem

log = logging.getLogger(__name__)

OBJECTIVES = ("mean", "worst", "logdet")


def objective_value(objective: str, ev: CloudEvaluation) -> float:
    """The value to minimize of a node-cloud evaluation."""
    if objective == "mean":
        return float(np.mean(traces(ev.covariances)))
    if objective == "worst":
        return float(np.max(traces(ev.covariances)))
    if objective == "logdet":
        return -ev.logdet
    raise FglocError(f"objective: expected one of {', '.join(OBJECTIVES)} ({objective!r})")


def gauge_objective(objective: str, cov: FloatArray) -> float:
    """The objective on solver-gauge node covariances (logdet: sum of per-node log det, nats)."""
    if objective == "mean":
        return float(np.mean(traces(cov)))
    if objective == "worst":
        return float(np.max(traces(cov)))
    return float(np.sum(np.log(np.linalg.det(cov))))


@dataclass(frozen=True)
class PredictedError:
    """Predicted node error in metres under the CRB Gaussian model.

    ``median``, ``p95``, ``worst``: the expected median, 95th percentile and maximum over the
    nodes of one survey's errors (averaged over draws, the statistics a simulated survey
    reports); ``rms``: root of the mean trace."""

    median: float
    p95: float
    worst: float
    rms: float


def predicted_error(cov: FloatArray, draws: int = 256, seed: int = 0) -> PredictedError:
    """Expected per-survey error statistics of nodes with covariances (N, 2, 2) m^2."""
    ok = np.all(np.isfinite(cov.reshape(len(cov), -1)), axis=1)
    if not np.all(ok):
        return PredictedError(np.inf, np.inf, np.inf, np.inf)
    chol = np.linalg.cholesky(cov + 1e-30 * np.eye(2))
    rng = np.random.default_rng(seed)
    e = np.einsum("nij,dnj->dni", chol, rng.standard_normal((draws, len(cov), 2)))
    dist = np.linalg.norm(e, axis=2)
    return PredictedError(
        median=float(np.mean(np.median(dist, axis=1))),
        p95=float(np.mean(np.percentile(dist, 95, axis=1))),
        worst=float(np.mean(np.max(dist, axis=1))),
        rms=float(np.sqrt(np.mean(traces(cov)))),
    )


@dataclass(frozen=True, eq=False)
class PlacementPlan:
    """A chosen placement: candidate indices (gauge pair first: origin, baseline), prediction, bookkeeping."""

    problem: PlanProblem
    objective: str
    chosen: tuple[int, ...]
    covariances: FloatArray  # (N, 2, 2) m^2, solver gauge of chosen[0], chosen[1]
    predicted: PredictedError
    cloud_objective: float  # selection objective (node-cloud gauge)
    evaluations: int
    localizable: np.ndarray  # (N,) bool

    @property
    def gauge(self) -> tuple[int, int]:
        return self.chosen[0], self.chosen[1]

    @property
    def baseline_m(self) -> float:
        a, b = self.gauge
        return float(np.linalg.norm(self.problem.xy[a] - self.problem.xy[b]))


def default_prior_m(problem: PlanProblem) -> float:
    """The weak node prior: the field's diameter (metres)."""
    span = problem.nodes_xy.max(axis=0) - problem.nodes_xy.min(axis=0)
    return float(max(np.hypot(*span), 1e-3))


def greedy_select(
    info: CandidateInfo,
    site_ids: tuple[str, ...],
    n_cameras: int,
    objective: str,
    lazy: bool | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[int], float, int]:
    """Greedy selection of ``n_cameras`` candidates, one per site. Returns (chosen, objective, evaluations).

    ``lazy`` (default: only for ``logdet``) keeps stale gains in a heap and re-evaluates the top one
    until it stays on top (exact for submodular objectives)."""
    if lazy is None:
        lazy = objective == "logdet"
    n_sites = len(set(site_ids))
    if n_cameras > n_sites:
        raise FglocError(f"cameras: more cameras than candidate sites ({n_cameras} > {n_sites})")
    chosen: list[int] = []
    used: set[str] = set()
    current = objective_value(objective, cloud_evaluate(info, {}))
    evaluations = 1

    def value_with(c: int) -> float:
        nonlocal evaluations
        evaluations += 1
        return objective_value(objective, cloud_evaluate(info, {i: 1.0 for i in [*chosen, c]}))

    heap: list[tuple[float, int, int]] = []  # (-gain, candidate, step at which the gain was evaluated)
    for step in range(n_cameras):
        if lazy and step > 0:
            while True:
                neg_gain, c, at = heapq.heappop(heap)
                if site_ids[c] in used:
                    continue
                if at == step:
                    best, best_value = c, current + neg_gain
                    break
                heapq.heappush(heap, (value_with(c) - current, c, step))
        else:
            free = [c for c in range(len(site_ids)) if site_ids[c] not in used]
            values = {c: value_with(c) for c in free}
            best = min(free, key=lambda c: (values[c], c))
            best_value = values[best]
            if lazy:
                heap = [(v - current, c, step) for c, v in values.items() if c != best]
                heapq.heapify(heap)
        chosen.append(best)
        used.add(site_ids[best])
        current = best_value
        log.info("placement step %d: candidate %d, %s = %.6g", step + 1, best, objective, current)
        if progress is not None:
            progress(step + 1, n_cameras)
    return chosen, current, evaluations


def swap_refine(
    info: CandidateInfo,
    site_ids: tuple[str, ...],
    chosen: list[int],
    objective: str,
    value: float,
    max_rounds: int = 10,
) -> tuple[list[int], float, int]:
    """Exchange refinement after greedy: replace each chosen candidate by the best other one (one per
    site; another height at the same site included) while that lowers the objective.

    A round visits every chosen position once; it stops after a round without improvement or
    after ``max_rounds``. Returns (chosen, objective, evaluations). The objective never rises,
    so a refined plan is at least as good as greedy's on the selection objective."""
    chosen = list(chosen)
    evaluations = 0
    for round_ in range(max_rounds):
        improved = False
        for i in range(len(chosen)):
            others = chosen[:i] + chosen[i + 1:]
            used = {site_ids[c] for c in others}
            best, best_value = chosen[i], value
            for c in range(len(site_ids)):
                if c == chosen[i] or site_ids[c] in used:
                    continue
                evaluations += 1
                v = objective_value(objective, cloud_evaluate(info, {k: 1.0 for k in [*others, c]}))
                if v < best_value - 1e-12 * abs(best_value):
                    best, best_value = c, v
            if best != chosen[i]:
                log.info("placement swap round %d: candidate %d -> %d, %s = %.6g", round_ + 1, chosen[i], best,
                         objective, best_value)
                chosen[i], value, improved = best, best_value, True
        if not improved:
            break
    return chosen, value, evaluations


def best_gauge_pair(jac: Jacobians, chosen: list[int], objective: str) -> tuple[tuple[int, int], FloatArray, np.ndarray]:
    """The ordered gauge pair among ``chosen`` with the best solver-gauge objective, its covariances and mask."""
    best: tuple[float, tuple[int, int], FloatArray, np.ndarray] | None = None
    for a, b in itertools.combinations(chosen, 2):
        cov, ok = gauge_frame_covariances(jac, chosen, (a, b))
        value = gauge_objective(objective, cov) if np.all(ok) else np.inf
        if best is None or value < best[0]:
            best = (value, (a, b), cov, ok)
    assert best is not None
    return best[1], best[2], best[3]


def plan_placement(
    problem: PlanProblem,
    n_cameras: int,
    objective: str = "mean",
    prior_m: float | None = None,
    lazy: bool | None = None,
    progress: Callable[[int, int], None] | None = None,
    refine: bool = False,
) -> PlacementPlan:
    """Choose ``n_cameras`` (>= 2) candidates of ``problem`` minimizing ``objective``; see the module docstring.

    ``refine``: follow greedy by :func:`swap_refine` (exchanges while the objective improves)."""
    if objective not in OBJECTIVES:
        raise FglocError(f"objective: expected one of {', '.join(OBJECTIVES)} ({objective!r})")
    if n_cameras < 2:
        raise FglocError(f"cameras: a plan needs at least 2 cameras ({n_cameras})")
    jac = problem.jacobians()
    info = candidate_info(jac, problem.nodes_xy, prior_m if prior_m is not None else default_prior_m(problem))
    chosen, value, evaluations = greedy_select(info, problem.site_ids, n_cameras, objective, lazy, progress)
    if refine:
        chosen, value, more = swap_refine(info, problem.site_ids, chosen, objective, value)
        evaluations += more
    (a, b), cov, ok = best_gauge_pair(jac, chosen, objective)
    order = (a, b, *[c for c in chosen if c not in (a, b)])
    if not np.all(ok):
        log.warning("%d nodes cannot be localized by the chosen cameras", int(np.sum(~ok)))
    return PlacementPlan(problem, objective, order, cov, predicted_error(cov), value, evaluations, ok)


def evaluate_placement(problem: PlanProblem, chosen: list[int], objective: str = "mean",
                       prior_m: float | None = None) -> PlacementPlan:
    """The prediction for a given placement (e.g. the naive one); the gauge pair is chosen as in planning."""
    jac = problem.jacobians()
    info = candidate_info(jac, problem.nodes_xy, prior_m if prior_m is not None else default_prior_m(problem))
    value = objective_value(objective, cloud_evaluate(info, {c: 1.0 for c in chosen}))
    (a, b), cov, ok = best_gauge_pair(jac, list(chosen), objective)
    order = (a, b, *[c for c in chosen if c not in (a, b)])
    return PlacementPlan(problem, objective, order, cov, predicted_error(cov), value, 1, ok)
