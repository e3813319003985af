"""Convex relaxation of repeat selection (Joshi & Boyd, 2009): how far a repeat plan can be from the best.

Frame and units as :mod:`fgloc.plan.repeat` (the survey's gauge frame, lengths in
baseline units, information whitened by the survey's sigma). Every candidate pair p
(camera, node) read at least once has a whitened Jacobian ``J_p = [Jc_p | Jn_p]``
(2 x m camera columns, 2 x 2 node columns) and a rank-2 information
``A_p = J_p^T J_p``. With ``w0`` the readings already taken per pair and ``w`` the
extra ones (integers in a plan)::

    F(w) = C0 + sum_p (w0_p + w_p) A_p          (C0: optional camera-block prior, zero for surveys)

The relaxation lets ``w`` be real, ``w >= 0``, ``sum w = B``. Objectives, minimized:

* ``mean``: ``f(w) = tr_nodes F(w)^-1`` (the summed node trace, convex), gradient
  ``df/dw_p = -||P F^-1 J_p^T||_F^2`` (P the node rows);
* ``logdet``: ``f(w) = -log det F(w)`` (convex), gradient ``-tr(J_p F^-1 J_p^T)``;
* ``worst`` (largest node trace) is convex but not smooth: no bound is offered.

Because f is monotone (more readings never raise it), the minimum over ``sum w <= B`` is the
one over ``sum w = B``; integer plans are feasible points, so for ANY feasible w the
Frank–Wolfe duality bound ::

    min over integer plans of B readings  >=  min_relaxed  >=  f(w) + B min_p g_p - g . w

(``g`` the gradient at w, the vertices of the scaled simplex being ``B e_p``) is a certified
lower bound. Its validity does not depend on how well the solver converged, only its tightness.

Evaluation uses the arrow structure of F (each pair couples one camera and one node): node
blocks ``D_n`` (2 x 2) are eliminated, leaving the camera Schur complement ``S`` (dc x dc,
dc = camera unknowns), so one value and gradient cost O(N dc^2 + P dc^2), no dense inverse.

Solver: spectral projected gradient (Barzilai–Borwein steps, Euclidean projection onto the
scaled simplex, non-monotone Armijo line search, Birgin–Martínez–Raydan 2000). The relaxed
optimum of these scenes spreads over thousands of pairs; Frank–Wolfe adds one vertex per
iteration and would need at least that many iterations, projected gradient moves every
coordinate at once. The duality bound is evaluated at every iterate and the best one kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.model import Result, Survey
from fgloc.plan.repeat import RepeatModel, plan_repeats

BOUND_OBJECTIVES = ("mean", "logdet")


@dataclass(frozen=True)
class PairSystem:
    """Candidate pairs in the arrow structure of F (see the module docstring).

    ``jc`` (P, 2, dc): whitened camera Jacobian scattered into the dc camera unknowns;
    ``jn`` (P, 2, 2): node Jacobian; ``node`` (P,): node index in [0, n_nodes);
    ``base`` (P,): readings already taken; ``cam_prior`` (dc, dc): extra camera information.
    """

    jc: FloatArray
    jn: FloatArray
    node: np.ndarray
    base: FloatArray
    n_nodes: int
    cam_prior: FloatArray

    @property
    def n_pairs(self) -> int:
        return len(self.node)

    @classmethod
    def from_model(cls, model: RepeatModel) -> PairSystem:
        """The pairs of a :class:`RepeatModel` (same unknowns, same information)."""
        dc = int(model.node_dims[0])
        p = len(model.pairs)
        jc = np.zeros((p, 2, dc))
        rows = np.arange(p)
        for k in range(6):  # padded gauge-camera columns repeat a real index with a zero Jacobian: add
            jc[rows, :, model.loc[:, k]] += model.jac[:, :, k]
        node = (model.loc[:, 6] - dc) // 2
        return cls(jc, model.jac[:, :, 6:].copy(), node.astype(int), np.asarray(model.base_weights, float),
                   len(model.node_index), np.zeros((dc, dc)))


@dataclass(frozen=True)
class Evaluation:
    """Objective value (``inf`` where F is singular), per-node traces and the gradient over pairs."""

    value: float
    node_traces: FloatArray
    logdet: float
    gradient: FloatArray | None


def _inv2(m: FloatArray) -> tuple[FloatArray, FloatArray]:
    det = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    inv = np.empty_like(m)
    inv[:, 0, 0], inv[:, 1, 1] = m[:, 1, 1], m[:, 0, 0]
    inv[:, 0, 1], inv[:, 1, 0] = -m[:, 0, 1], -m[:, 1, 0]
    return inv / np.where(det > 0, det, 1.0)[:, None, None], det


def evaluate(system: PairSystem, extra: FloatArray, objective: str = "mean", gradient: bool = True) -> Evaluation:
    """f and df/dw at extra readings ``extra`` (P,) on top of ``system.base`` (see the module docstring)."""
    w = system.base + np.asarray(extra, float)
    jc, jn, node, n = system.jc, system.jn, system.node, system.n_nodes
    dc = jc.shape[2]
    wjn = w[:, None, None] * jn
    d = np.zeros((n, 2, 2))
    np.add.at(d, node, wjn.transpose(0, 2, 1) @ jn)
    b = np.zeros((n, 2, dc))
    np.add.at(b, node, wjn.transpose(0, 2, 1) @ jc)
    xs = (np.sqrt(w)[:, None, None] * jc).reshape(-1, dc)
    a = system.cam_prior + xs.T @ xs
    d_inv, det = _inv2(d)
    inf = Evaluation(np.inf, np.full(n, np.inf), -np.inf, None)
    if np.any(det <= 1e-300 + 1e-14 * (d[:, 0, 0] + d[:, 1, 1]) ** 2):
        return inf
    wm = d_inv @ b  # W_n = D_n^-1 B_n  (N, 2, dc)
    wf = wm.reshape(-1, dc)
    s = a - b.reshape(-1, dc).T @ wf
    s = 0.5 * (s + s.T)
    try:
        chol = np.linalg.cholesky(s)
    except np.linalg.LinAlgError:
        return inf
    l_inv = np.linalg.solve(chol, np.eye(dc))
    s_inv = l_inv.T @ l_inv  # Sigma_cc
    traces = d_inv[:, 0, 0] + d_inv[:, 1, 1] + ((wf @ s_inv) * wf).sum(axis=1).reshape(n, 2).sum(axis=1)
    logdet = float(np.sum(np.log(det)) + 2.0 * np.sum(np.log(np.diag(chol))))
    value = float(traces.sum()) if objective == "mean" else -logdet
    if not gradient:
        return Evaluation(value, traces, logdet, None)
    wp_t, dp = wm[node].transpose(0, 2, 1), d_inv[node]  # W_j^T (P, dc, 2), D_j^-1
    q = wp_t @ jn.transpose(0, 2, 1) - jc.transpose(0, 2, 1)  # W_j^T Jn^T - Jc^T  (P, dc, 2)
    v = s_inv @ q  # Sigma_cc q
    if objective == "logdet":
        g = (v * q).sum(axis=(1, 2)) + ((jn @ dp) * jn).sum(axis=(1, 2))
        return Evaluation(value, traces, logdet, -g)
    x = dp @ jn.transpose(0, 2, 1)  # D_j^-1 Jn^T
    g = ((wf.T @ wf) @ v * v).sum(axis=(1, 2)) + 2.0 * ((wp_t @ x) * v).sum(axis=(1, 2)) + (x * x).sum(axis=(1, 2))
    return Evaluation(value, traces, logdet, -g)


def project_simplex(y: FloatArray, total: float) -> FloatArray:
    """Euclidean projection of ``y`` onto ``{w >= 0, sum w = total}`` (sort-based, O(P log P))."""
    u = np.sort(y)[::-1]
    css = np.cumsum(u) - total
    k = np.arange(1, len(y) + 1)
    rho = int(np.flatnonzero(u - css / k > 0)[-1])
    return np.maximum(y - css[rho] / (rho + 1.0), 0.0)


@dataclass(frozen=True)
class Relaxation:
    """The relaxed problem at budget B: ``weights`` the best point found, ``value`` f there (an upper
    bound on the relaxed minimum), ``bound`` the certified lower bound on every plan of B readings."""

    objective: str
    budget: float
    weights: FloatArray
    value: float
    bound: float
    iterations: int


def solve_relaxation(system: PairSystem, budget: float, objective: str = "mean", start: FloatArray | None = None,
                     rtol: float = 1e-4, max_iter: int = 3000, stop_below: float | None = None) -> Relaxation:
    """Minimize f over ``{w >= 0, sum w = budget}`` by spectral projected gradient (module docstring).

    Stops when ``value - bound <= rtol * (f(0) - bound)`` (the certificate within ``rtol`` of the
    largest possible gain), after ``max_iter`` iterations, or (feasibility questions) as soon as the
    bound exceeds ``stop_below`` or the value drops to it.
    """
    if objective not in BOUND_OBJECTIVES:
        raise FglocError(f"objective: the relaxation bound supports {', '.join(BOUND_OBJECTIVES)} ({objective!r})")
    p = system.n_pairs
    f_empty = evaluate(system, np.zeros(p), objective, gradient=False).value
    if budget <= 0:
        return Relaxation(objective, 0.0, np.zeros(p), f_empty, f_empty, 0)
    w = np.full(p, budget / p) if start is None or start.sum() <= 0 else project_simplex(
        np.asarray(start, float) * budget / float(np.sum(start)), budget)
    ev = evaluate(system, w, objective)
    if not np.isfinite(ev.value):
        w = np.full(p, budget / p)
        ev = evaluate(system, w, objective)
    assert ev.gradient is not None
    f, g = ev.value, ev.gradient
    best_w, best_f, bound = w, f, -np.inf
    history = [f]
    alpha = budget / max(float(np.max(np.abs(g))), 1e-300) / p
    it = 0
    for it in range(1, max_iter + 1):
        bound = max(bound, f + budget * float(g.min()) - float(g @ w))
        if f < best_f:
            best_w, best_f = w, f
        scale = f_empty - bound if np.isfinite(f_empty) else abs(best_f)  # no first pass: f(0) = inf
        if best_f - bound <= rtol * max(scale, 1e-300):
            break
        if stop_below is not None and (bound > stop_below or best_f <= stop_below):
            break
        dirn = project_simplex(w - alpha * g, budget) - w
        slope = float(g @ dirn)
        if slope >= 0:
            break
        f_ref, lam = max(history[-10:]), 1.0
        while True:
            w_new = w + lam * dirn
            ev = evaluate(system, w_new, objective)
            if ev.value <= f_ref + 1e-4 * lam * slope or lam < 1e-12:
                break
            lam *= 0.5
        if not np.isfinite(ev.value) or ev.gradient is None:
            break
        s_vec, y_vec = w_new - w, ev.gradient - g
        sy = float(s_vec @ y_vec)
        alpha = float(s_vec @ s_vec) / sy if sy > 0 else 10.0 * alpha
        w, f, g = w_new, ev.value, ev.gradient
        history.append(f)
    bound = max(bound, f + budget * float(g.min()) - float(g @ w))
    if f < best_f:
        best_w, best_f = w, f
    return Relaxation(objective, float(budget), best_w, float(best_f), float(bound), it)


@dataclass(frozen=True)
class RepeatBound:
    """A plan of ``budget`` extra readings against the relaxation.

    ``before``: f with no extra reading; ``achieved``: the plan's f; ``bound``: certified lower bound on f
    of every plan of ``budget`` readings; ``relaxed``: f at the relaxation's best point (>= the relaxed
    minimum >= ``bound``). ``mean``: summed node trace (baseline units^2); ``logdet``: -log det (nats).
    """

    objective: str
    budget: int
    before: float
    achieved: float
    bound: float
    relaxed: float
    iterations: int

    @property
    def gap(self) -> float:
        """How much the plan can be improved at most (objective units; nats for logdet)."""
        return self.achieved - self.bound

    @property
    def gap_percent(self) -> float:
        """``gap`` in % of the bound's magnitude (for ``mean``: the plan's trace is within this % of any plan's)."""
        return 100.0 * self.gap / abs(self.bound)

    @property
    def gain_ratio(self) -> float:
        """Gain achieved / best possible gain, ``(before - achieved) / (before - bound)``: a lower bound on the
        share of the best plan's improvement this plan reaches (1 = provably optimal)."""
        best = self.before - self.bound
        return 1.0 if best <= 0 else (self.before - self.achieved) / best


def counts_of(model: RepeatModel, readings: list[tuple[str, str]]) -> FloatArray:
    """Extra readings per pair of ``model`` from (camera, node) readings."""
    index = {pair: i for i, pair in enumerate(model.pairs)}
    counts = np.zeros(len(model.pairs))
    for pair in readings:
        counts[index[pair]] += 1
    return counts


def plan_bound(system: PairSystem, counts: FloatArray, objective: str = "mean", rtol: float = 1e-4,
               max_iter: int = 3000) -> RepeatBound:
    """Bound a plan of extra readings ``counts`` (P,) against every plan of the same size."""
    budget = int(round(float(np.sum(counts))))
    before = evaluate(system, np.zeros(system.n_pairs), objective, gradient=False).value
    achieved = evaluate(system, counts, objective, gradient=False).value
    relax = solve_relaxation(system, budget, objective, start=counts, rtol=rtol, max_iter=max_iter)
    return RepeatBound(objective, budget, before, achieved, min(relax.bound, achieved), relax.value, relax.iterations)


@dataclass(frozen=True)
class Feasibility:
    """Can ``budget`` extra readings reach the summed node trace of "every reading measured 3x"?

    ``target`` T3: the summed node trace of ``(3 H_onepass)^-1`` (exactly a third of ``trace_one_pass``
    for a prior-free survey). ``bound``: certified lower bound on the trace of every plan of ``budget``
    extra readings; ``status``: ``infeasible`` (``bound > target``: a proof), ``feasible`` (greedy
    reached the target within the budget: a plan), else ``undecided``. ``certified_min_budget``: every
    plan with fewer extra readings misses the target (proven by the relaxation at
    ``certified_min_budget - 1``); ``relaxed_reach_budget``: the smallest budget whose relaxation gets
    to the target (the relaxation cannot exclude it); ``greedy_budget``: extra readings greedy needed
    (None: not run, or not reached within ``greedy_cap``). ``free_bound``: certified lower bound on the
    trace of ANY allocation of ``n_readings + budget`` readings over the pairs (the first pass not
    kept); above ``target`` it proves the goal infeasible even without the first pass.
    """

    n_readings: int
    budget: int
    trace_one_pass: float
    target: float
    bound: float
    free_bound: float
    status: str
    certified_min_budget: int
    relaxed_reach_budget: int
    greedy_budget: int | None
    greedy_cap: int

    def ratio(self, extra: int | None) -> float | None:
        """Total readings / one pass with ``extra`` extra readings."""
        return None if extra is None else (self.n_readings + extra) / self.n_readings


def _decide(system: PairSystem, budget: int, target: float, start: FloatArray, max_iter: int) -> Relaxation:
    return solve_relaxation(system, budget, "mean", start=start, rtol=1e-6, max_iter=max_iter, stop_below=target)


def certified_budgets(system: PairSystem, target: float, max_iter: int = 500) -> tuple[int, int]:
    """Bisection over integer budgets: (smallest budget not excluded by the relaxation's certificate,
    smallest budget at which the relaxation reaches ``target``); the first is <= the second."""
    total = float(system.base.sum())
    f0 = evaluate(system, np.zeros(system.n_pairs), "mean", gradient=False).value
    if f0 <= target:
        return 0, 0
    lo = 0  # proven: every plan of lo extra readings misses the target
    hi = int(np.ceil(2.0 * total))  # 2 w0 extra = every reading 3x: reaches the target exactly
    reach = hi
    start = system.base
    while hi - lo > 1:
        mid = (lo + hi) // 2
        r = _decide(system, mid, target, start, max_iter)
        start = r.weights  # warm start the next budget (rescaled onto it)
        if r.bound > target:
            lo = mid
        else:
            hi = mid
            if r.value <= target:
                reach = min(reach, mid)
    if reach > hi:  # the relaxation's own point at the frontier, searched upward from hi
        lo_r, hi_r = hi - 1, reach
        while hi_r - lo_r > 1:
            mid = (lo_r + hi_r) // 2
            if _decide(system, mid, target, start, max_iter).value <= target:
                hi_r = mid
            else:
                lo_r = mid
        reach = hi_r
    return lo + 1, reach


def repeat_feasibility(survey: Survey, result: Result, fraction: float = 0.3, greedy: bool = True,
                       max_iter: int = 500) -> Feasibility:
    """Goal "reach the trace of every reading 3x with (1 + fraction) x the readings of one pass", per survey.

    Budget ``floor(fraction * n)`` extra readings, n the survey's readings. Greedy (objective ``mean``,
    at most 2n extra readings, which "every reading 3x" needs) is run when ``greedy``.
    """
    if not 0 <= fraction:
        raise FglocError(f"fraction: must be >= 0 ({fraction})")
    model = RepeatModel(survey, result)
    system = PairSystem.from_model(model)
    n = model.n_readings
    budget = int(np.floor(fraction * n + 1e-9))
    zero = np.zeros(system.n_pairs)
    trace1 = evaluate(system, zero, "mean", gradient=False).value
    target = evaluate(system, 2.0 * system.base, "mean", gradient=False).value  # base + 2 base = 3x
    relax = solve_relaxation(system, budget, "mean", start=system.base, rtol=1e-6, max_iter=max_iter)
    free = solve_relaxation(PairSystem(system.jc, system.jn, system.node, zero, system.n_nodes, system.cam_prior),
                            n + budget, "mean", start=system.base, rtol=1e-6, max_iter=max_iter, stop_below=target)
    certified, reach = certified_budgets(system, target, max_iter)
    cap = 2 * n
    greedy_budget = None
    if greedy:
        plan = plan_repeats(survey, result, cap, "mean", stop_trace=target)
        greedy_budget = len(plan.readings) if plan.trace_after <= target else None
    if relax.bound > target:
        status = "infeasible"
    elif greedy_budget is not None and greedy_budget <= budget:
        status = "feasible"
    else:
        status = "undecided"
    return Feasibility(n, budget, trace1, target, relax.bound, free.bound, status, certified, reach,
                       greedy_budget, cap)
