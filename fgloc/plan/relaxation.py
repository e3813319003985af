"""Convex-relaxation bound on the log-det placement objective (Joshi & Boyd, 2009).

Relax the choice to weights ``0 <= z_c <= 1`` with ``sum z = K`` and at most one
unit per site; the node information ``M(z) = D(z) + sum_c z_c (C_c - V_c V_c^T)``
is affine in z, so ``f(z) = log det M(z)`` is concave and for any feasible z
(Frank–Wolfe duality)::

    max over integer plans  <=  max over the relaxation  <=  f(z) + max_s grad f(z) . (s - z)

The linear maximization picks, per site, its best candidate and then the K sites
with the largest gradients. Frank–Wolfe starts from the greedy plan and keeps the
smallest bound seen. Node-cloud gauge, nats, same constant as
:func:`fgloc.plan.fisher.cloud_evaluate`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.plan.fisher import CandidateInfo, _inv2, cloud_evaluate


def logdet_gradient(info: CandidateInfo, weights: dict[int, float]) -> tuple[float, FloatArray]:
    """``log det M(z)`` and its gradient ``tr(M^-1 F_c)`` for every candidate c."""
    ids = [c for c, z in weights.items() if z > 0]
    z = np.array([weights[c] for c in ids], float)
    ev = cloud_evaluate(info, weights)
    n = info.local.shape[1]
    d = info.prior * np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    if ids:
        d += np.einsum("c,cnij->nij", z, info.local[ids])
    d_inv, _ = _inv2(d)
    y = np.concatenate([info.coupling[ids].transpose(1, 2, 0, 3).reshape(n, 2, 6 * len(ids)), info.cloud], axis=2)
    q_inv = np.concatenate([np.repeat(-1.0 / z, 6) if ids else np.zeros(0), np.zeros(4)])
    r = np.einsum("nij,njk->nik", d_inv, y)
    k = np.diag(q_inv) + np.einsum("nai,naj->ij", y, r)
    k_inv = np.linalg.inv(0.5 * (k + k.T))
    term_local = np.einsum("nij,cnji->c", ev.covariances, info.local)
    dv = np.einsum("nij,cnjk->cnik", d_inv, info.coupling)
    term_v = np.einsum("cnik,cnik->c", info.coupling, dv)
    e = np.einsum("nar,cnas->crs", r, info.coupling)
    term_e = np.einsum("crs,rq,cqs->c", e, k_inv, e)
    return ev.logdet, term_local - (term_v - term_e)


def _vertex(grad: FloatArray, site_ids: tuple[str, ...], k: int) -> FloatArray:
    """The polytope vertex maximizing ``grad . s``: the best candidate of each of the K best sites."""
    best: dict[str, int] = {}
    for c, sid in enumerate(site_ids):
        if sid not in best or grad[c] > grad[best[sid]]:
            best[sid] = c
    top = sorted(best.values(), key=lambda c: -grad[c])[:k]
    s = np.zeros(len(grad))
    s[top] = 1.0
    return s


@dataclass(frozen=True)
class RelaxationBound:
    """``bound`` >= log det of any plan of K cameras; ``achieved``: the given plan's; ``empty``: no camera."""

    bound: float
    achieved: float
    empty: float
    iterations: int

    @property
    def gap_nats(self) -> float:
        """How far the plan can be from optimal: det ratio at most exp(gap)."""
        return self.bound - self.achieved

    @property
    def gain_ratio(self) -> float:
        """Share of the largest possible information gain (over no camera) the plan reaches (a lower bound)."""
        return (self.achieved - self.empty) / (self.bound - self.empty)


def placement_bound(info: CandidateInfo, site_ids: tuple[str, ...], chosen: list[int], iterations: int = 20) -> RelaxationBound:
    """Frank–Wolfe from the plan ``chosen``; returns the smallest duality bound seen."""
    k = len(chosen)
    z = np.zeros(len(site_ids))
    z[chosen] = 1.0
    achieved = bound = np.inf
    for t in range(iterations + 1):
        f, grad = logdet_gradient(info, {c: float(v) for c, v in enumerate(z) if v > 1e-12})
        if t == 0:
            achieved = f
        s = _vertex(grad, site_ids, k)
        bound = min(bound, f + float(grad @ (s - z)))
        z = z + 2.0 / (t + 3.0) * (s - z)
    empty = cloud_evaluate(info, {}).logdet
    return RelaxationBound(float(bound), float(achieved), float(empty), iterations)
