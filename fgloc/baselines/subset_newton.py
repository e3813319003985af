"""The paper's baseline: subset-averaging Newton localization (planar, two cameras).

Procedure (Farrell, Garcia, Lucarelli, Terzis, Wang, "Target localization in
camera wireless networks", Pervasive and Mobile Computing 5 (2009) 165-181, as
described in the project brief):

1. Split the nodes into ``T`` random subsets of ``k`` nodes. With a re-measured
   survey (observations tagged with ``subset``, see ``fgloc simulate
   --subset-schedule``) the subsets and their own readings come from the tags;
   otherwise subsets are drawn here and reuse the survey's readings.
2. For each subset solve the system of pan-tilt constraints of the two gauge
   cameras in the planar gauge: unknowns are the heights ``h0, h1`` of the
   origin camera (above (0, 0)) and baseline camera (above (1, 0)), both base
   rotations, and the subset's node positions (x, y) on z = 0: ``8 + 2k``
   unknowns against ``4 k R`` residuals (R readings per camera and node).
3. The solver is a globally convergent Newton method in the style of Numerical
   Recipes' ``newt`` + ``lnsrch``: Newton-Raphson on the whitened residual
   system ``F(x) = (measured - predicted) / sigma`` with an analytic Jacobian,
   and a backtracking line search (quadratic then cubic interpolation,
   sufficient-decrease constant ``ALF = 1e-4``) that guarantees decrease of
   ``f = |F|^2 / 2``. The system is overdetermined (``4kR > 8 + 2k``), so the
   Newton step is the least-squares (Gauss-Newton) step ``J dx = -F`` solved
   by QR; it is a descent direction for f (``grad f . dx = -|Q^T F|^2 < 0``),
   which is all the line search needs. For a square system it is exactly the
   Newton-Raphson step.
4. Rotations are parameterized by local increments ``R <- R Exp(omega)``, so
   the Jacobian of ``q = R^T (x - c)`` is ``[q]_x`` in omega.
5. Each node's estimate is the mean of its solutions over the subsets that
   contain it and succeeded.

Initial guess (documented choice; the paper's exact guess is not available
to us): cameras level (no roll or pitch) with yaws from a coarse 5-degree
grid search over (yaw0, yaw1): for each pair the pan readings triangulate the
nodes in the plane, the tilts imply camera heights, and the pair whose level
model best explains the tilts is the start. It reads only the readings, never
the truth. ``restarts > 1`` also tries the next best grid candidates.

Failures are detected and counted, never averaged in:
``underdetermined`` (fewer residuals than unknowns), ``degenerate`` (the
Jacobian is rank deficient, e.g. collinear nodes), ``no-convergence``
(iteration limit, or the line search stalled away from a stationary point),
``spurious`` (converged, but ``|F|^2`` exceeds the chi-square 99.9% quantile
for ``4kR - (8 + 2k)`` degrees of freedom: a local minimum the noise cannot
explain), ``non-physical`` (a camera at or below the ground, a node farther
than ``max_extent`` baselines, or NaN).

Units: lengths in baselines (planar gauge), angles in radians.

Modules: :mod:`~fgloc.baselines.subset_options` (settings, status words),
:mod:`~fgloc.baselines.subset_system` (unknowns, residuals, Jacobian),
:mod:`~fgloc.baselines.subset_guess` (initial guesses), :mod:`~fgloc.baselines.newton`
(the solver); this module splits the survey into subsets and averages.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from fgloc.baselines.newton import NewtonOutcome, solve_subsets
from fgloc.baselines.subset_guess import level_camera_guesses
from fgloc.baselines.subset_options import FAILURE_KINDS, STATUS_OK, SubsetNewtonError, SubsetNewtonOptions
from fgloc.baselines.subset_system import N_CAMERA_PARAMS, SubsetReadings
from fgloc.core.geometry import (
    FloatArray,
    nearest_rotation,
)
from fgloc.core.model import CameraPose, NodeEstimate, NodeMode, Result, SolveStats, Survey
from fgloc.core.subsets import draw_subsets

__all__ = [
    "FAILURE_KINDS",
    "STATUS_OK",
    "NewtonOutcome",
    "SubsetNewtonError",
    "SubsetNewtonOptions",
    "SubsetNewtonResult",
    "SubsetSolutions",
    "solve_packed",
    "solve_subset_newton",
]


@dataclass(frozen=True)
class SubsetSolutions:
    """Successful per-subset node solutions, one row per (subset, node).

    ``subset_index`` indexes ``SubsetNewtonResult.subsets``; ``node_index``
    indexes ``Survey.node_ids``; ``position`` is (P, 2) on z = 0 (baselines).
    """

    subset_index: np.ndarray
    node_index: np.ndarray
    position: FloatArray


@dataclass
class SubsetNewtonResult:
    """Averaged result plus everything needed to plot Figure 4 (subset point clouds).

    ``result.nodes[...].covariance`` is the sample covariance of that node's
    successful subset solutions divided by their count (the covariance of the
    mean) when the node has >= 3 solutions, else the mean of the subsets'
    Gauss-Newton covariances ``(J^T J)^-1`` divided by the count.
    """

    result: Result
    solutions: SubsetSolutions
    subsets: list[np.ndarray]  # node indices of each subset
    status: list[str]  # per subset: "ok" or a failure kind
    iterations: np.ndarray  # per subset
    failures: dict[str, int]
    seconds: float

    @property
    def n_failed(self) -> int:
        return sum(self.failures.values())


def _subset_readings(survey: Survey, options: SubsetNewtonOptions) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Subsets (node indices) and, per subset, the indices of its observations."""
    t = survey.observation_table
    cams = [survey.camera_ids.index(survey.gauge.origin), survey.camera_ids.index(survey.gauge.baseline)]
    gauge_obs = np.isin(t.camera_index, cams)
    tags = np.array([-1 if o.subset is None else o.subset for o in survey.observations], dtype=np.int64)
    if np.any(tags >= 0):
        subsets, members = [], []
        for tag in np.unique(tags[tags >= 0]):
            idx = np.flatnonzero((tags == tag) & gauge_obs)
            subsets.append(np.unique(t.node_index[idx]))
            members.append(idx)
        return subsets, members
    rng = np.random.default_rng(options.seed)
    subsets = draw_subsets(len(survey.node_ids), options.subset_size, options.n_subsets, rng)
    members = [np.flatnonzero(np.isin(t.node_index, s) & gauge_obs) for s in subsets]
    return subsets, members


def _pack(survey: Survey, subsets: list[np.ndarray], members: list[np.ndarray]) -> SubsetReadings:
    t = survey.observation_table
    k = len(subsets[0])
    M = max(1, max(len(m) for m in members))
    S = len(subsets)
    cam = np.zeros((S, M), dtype=np.int64)
    slot = np.zeros((S, M), dtype=np.int64)
    pan = np.zeros((S, M))
    tilt = np.zeros((S, M))
    sig = np.ones((S, M))
    mask = np.zeros((S, M), dtype=bool)
    baseline_index = survey.camera_ids.index(survey.gauge.baseline)
    for s, (nodes, idx) in enumerate(zip(subsets, members)):
        L = len(idx)
        cam[s, :L] = (t.camera_index[idx] == baseline_index).astype(np.int64)
        slot[s, :L] = np.searchsorted(nodes, t.node_index[idx])
        pan[s, :L], tilt[s, :L], sig[s, :L] = t.pan[idx], t.tilt[idx], t.sigma[idx]
        mask[s, :L] = True
    return SubsetReadings(cam, slot, pan, tilt, sig, mask, k)


def solve_packed(obs: SubsetReadings, options: SubsetNewtonOptions) -> NewtonOutcome:
    """Initial guesses + Newton for one batch of equal-size subsets; best restart wins."""
    best: NewtonOutcome | None = None
    for start in level_camera_guesses(obs, options.yaw_grid_deg, max(1, options.restarts)):
        out = solve_subsets(start, obs, options)
        if best is None:
            best = out
            continue
        ok_new, ok_old = out.status == STATUS_OK, best.status == STATUS_OK
        take = (ok_new & ~ok_old) | ((ok_new == ok_old) & (out.f < best.f))
        for name in ("R", "h", "xy"):
            getattr(best.state, name)[take] = getattr(out.state, name)[take]
        best.f[take], best.status[take] = out.f[take], out.status[take]
        best.f_initial[take] = out.f_initial[take]
        best.iterations[take], best.covariance[take] = out.iterations[take], out.covariance[take]
    assert best is not None
    return best


def solve_subset_newton(survey: Survey, options: SubsetNewtonOptions = SubsetNewtonOptions()) -> SubsetNewtonResult:
    """Run the paper's subset-averaging Newton baseline on a planar survey."""
    t_start = time.perf_counter()
    if survey.mode is not NodeMode.PLANAR:
        raise SubsetNewtonError("subset-newton: nodes: only planar surveys are supported (the paper's case)")
    subsets, members = _subset_readings(survey, options)
    S = len(subsets)
    status = [""] * S
    iterations = np.zeros(S, dtype=np.int64)
    sol_s, sol_n, sol_p = [], [], []
    node_gn_cov: dict[int, list[FloatArray]] = {}
    cam_h, cam_R = [], []
    f_total = 0.0
    f_start = 0.0
    sizes = np.array([len(s) for s in subsets])
    for k in np.unique(sizes):
        rows = np.flatnonzero(sizes == k)
        obs = _pack(survey, [subsets[r] for r in rows], [members[r] for r in rows])
        out = solve_packed(obs, options)
        for i, r in enumerate(rows):
            status[r] = str(out.status[i])
            iterations[r] = out.iterations[i]
            if status[r] != STATUS_OK:
                continue
            f_total += float(out.f[i])
            f_start += float(out.f_initial[i])
            cam_h.append(out.state.h[i])
            cam_R.append(out.state.R[i])
            for j_slot, j in enumerate(subsets[r]):
                sol_s.append(r)
                sol_n.append(int(j))
                sol_p.append(out.state.xy[i, j_slot])
                c = N_CAMERA_PARAMS + 2 * j_slot
                node_gn_cov.setdefault(int(j), []).append(out.covariance[i, c : c + 2, c : c + 2])
    solutions = SubsetSolutions(
        subset_index=np.array(sol_s, dtype=np.int64),
        node_index=np.array(sol_n, dtype=np.int64),
        position=np.array(sol_p, dtype=float).reshape(-1, 2),
    )
    nodes: dict[str, NodeEstimate] = {}
    unlocalized: dict[str, str] = {}
    in_subsets = np.zeros(len(survey.node_ids), dtype=np.int64)
    for s in subsets:
        in_subsets[s] += 1
    for j, nid in enumerate(survey.node_ids):
        pts = solutions.position[solutions.node_index == j]
        if len(pts) == 0:
            unlocalized[nid] = (
                "in no subset" if in_subsets[j] == 0 else f"every subset containing it failed ({in_subsets[j]})"
            )
            continue
        mean = pts.mean(axis=0)
        if len(pts) >= 3:
            cov = np.cov(pts.T, ddof=1) / len(pts)
        else:
            cov = np.mean(node_gn_cov[j], axis=0) / len(pts)
        nodes[nid] = NodeEstimate(position=np.array([mean[0], mean[1], 0.0]), covariance=cov)
    cameras: dict[str, CameraPose] = {}
    if cam_h:
        h = np.mean(cam_h, axis=0)
        Rm = np.mean(cam_R, axis=0)
        cameras[survey.gauge.origin] = CameraPose(np.array([0.0, 0.0, h[0]]), nearest_rotation(Rm[0]))
        cameras[survey.gauge.baseline] = CameraPose(np.array([1.0, 0.0, h[1]]), nearest_rotation(Rm[1]))
    failures = {kind: status.count(kind) for kind in FAILURE_KINDS}
    seconds = time.perf_counter() - t_start
    stats = SolveStats(
        method="subset-newton",
        iterations=int(iterations.sum()),
        initial_error=f_start,  # sum over successful subsets of 0.5 |F|^2 at their starts
        final_error=f_total,
        converged=failures["no-convergence"] == 0,
        stage_seconds={"subsets": seconds},
    )
    result = Result(mode=NodeMode.PLANAR, nodes=nodes, cameras=cameras, unlocalized=unlocalized, stats=stats)
    return SubsetNewtonResult(
        result=result,
        solutions=solutions,
        subsets=subsets,
        status=status,
        iterations=iterations,
        failures=failures,
        seconds=seconds,
    )
