"""The solvers the benchmark compares, each timed per stage on the same survey.

* ``fgloc``: the production pipeline (:func:`fgloc.solve.joint.solve_survey`):
  closed-form start, Levenberg-Marquardt, outlier flagging, every node marginal.
* ``fgloc_reference``: the same through the reference graph (one pan-tilt
  ``CustomFactor`` per reading; ``SolverOptions(eliminate_nodes=False)``).
* ``gtsam_cpp``: the plain C++ pipeline a GTSAM user writes with defaults, from
  the same closed-form start: GTSAM's ``BearingFactor3D`` per reading, nodes as
  ``Point3`` held on z = 0 by a ``PriorFactorPoint3`` (sigmas 1e6, 1e6, gauge
  sigma), the spec's gauge, ``gtsam.LevenbergMarquardtOptimizer`` with default
  parameters (damping, ordering, Cholesky) and relative error tolerance 1e-9,
  ``gtsam.Marginals`` with one ``marginalCovariance`` per node. Noise
  equivalence (first order): a pan error dp moves the unit bearing by
  ``cos(tilt) dp`` along the pan direction ``e_p = (-sin p, cos p, 0)``, a tilt
  error dt by ``dt`` along ``e_t``. So with Unit3 tangent basis B (3x2) of the
  measured bearing, the tangent-plane noise is
  ``Cov = sigma^2 B^T (cos^2 t e_p e_p^T + e_t e_t^T) B``, a per-reading
  ``noiseModel.Gaussian``. The two costs agree to first order in the residual.
* ``numpy_schur``: the "speed limit", a plain vectorized numpy LM with the nodes
  eliminated in closed form (:mod:`fgloc.evaluate.bench_numpy_lm`), same start,
  every node marginal.
* ``scipy``: ``scipy.optimize.least_squares(method="trf")`` on the same
  whitened residuals (pan-tilt readings and the gauge), finite-difference
  Jacobian with ``jac_sparsity``, same start. No marginals.
* ``subset_newton``: the paper's subset-averaging Newton baseline
  (:mod:`fgloc.baselines.subset_newton`), two-camera scenes only.

Every runner returns a :class:`MethodRun`: wall seconds per stage, iterations,
the final cost (GTSAM convention, 0.5 * sum of squared whitened residuals of
the pan-tilt model) and node positions for cross-checks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_bearing, pan_tilt_residual
from fgloc.core.model import Survey
from fgloc.factors.baseline_prior import BaselinePrior
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import SolverOptions, auto_gauge_sigma, initialize, solve_survey

METHODS = ("fgloc", "fgloc_reference", "gtsam_cpp", "numpy_schur", "scipy", "subset_newton")


@dataclass
class MethodRun:
    """One timed run of one method on one survey."""

    method: str
    stage_seconds: dict[str, float]
    iterations: int
    final_cost: float
    positions: FloatArray  # (N, 3) in survey.node_ids order (NaN if not estimated)
    covariance_trace: FloatArray | None = None  # (N,) trace of node marginals, if computed
    available: bool = True
    note: str = ""
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def total_seconds(self) -> float:
        return float(sum(self.stage_seconds.values()))


def pan_tilt_cost(survey: Survey, positions: FloatArray, cameras: dict[str, tuple[FloatArray, FloatArray]]) -> float:
    """0.5 * sum of squared whitened pan-tilt residuals (GTSAM's error without the gauge)."""
    t = survey.observation_table
    rot = np.array([cameras[c][0] for c in survey.camera_ids])[t.camera_index]
    pos = np.array([cameras[c][1] for c in survey.camera_ids])[t.camera_index]
    q = np.einsum("mji,mj->mi", rot, positions[t.node_index] - pos)
    p, tl = bearing_pan_tilt(q)
    e = pan_tilt_residual(t.pan, t.tilt, p, tl) / t.sigma[:, None]
    return float(0.5 * np.sum(e**2))


def _initial(survey: Survey) -> tuple[InitialEstimate, float]:
    t0 = time.perf_counter()
    init = initialize(survey)
    return init, time.perf_counter() - t0


def _run_solve_survey(survey: Survey, method: str, eliminate_nodes: bool) -> MethodRun:
    t0 = time.perf_counter()
    result = solve_survey(survey, SolverOptions(eliminate_nodes=eliminate_nodes))
    wall = time.perf_counter() - t0
    assert result.stats is not None
    stages = {k: float(result.stats.stage_seconds.get(k, 0.0)) for k in ("build", "initialize", "optimize", "marginals")}
    stages["other"] = max(wall - sum(stages.values()), 0.0)
    positions = np.array([result.nodes[n].position if n in result.nodes else [np.nan] * 3 for n in survey.node_ids])
    traces = np.array([np.trace(result.nodes[n].covariance) if n in result.nodes else np.nan for n in survey.node_ids])
    cams = {c: (p.rotation, p.position) for c, p in result.cameras.items()}
    return MethodRun(method, stages, result.stats.iterations, pan_tilt_cost(survey, positions, cams), positions, traces)


def run_fgloc(survey: Survey) -> MethodRun:
    """The production pipeline (:func:`fgloc.solve.joint.solve_survey`), with every node marginal.

    Stages come from the solver's own ``stage_seconds``; ``other`` is the rest of
    the wall time (outlier flagging, result assembly).
    """
    return _run_solve_survey(survey, "fgloc", eliminate_nodes=True)


def run_fgloc_reference(survey: Survey) -> MethodRun:
    """``solve_survey`` through the reference graph (one pan-tilt ``CustomFactor`` per reading)."""
    return _run_solve_survey(survey, "fgloc_reference", eliminate_nodes=False)


def bearing_noise(pan: float, tilt: float, sigma: float, measured: gtsam.Unit3) -> gtsam.noiseModel.Base:
    """Unit3 tangent-plane noise first-order equivalent to N(0, sigma^2) on pan and tilt."""
    e_p = np.array([-np.sin(pan), np.cos(pan), 0.0])
    e_t = np.array([-np.sin(tilt) * np.cos(pan), -np.sin(tilt) * np.sin(pan), np.cos(tilt)])
    basis = measured.basis()
    cov = sigma**2 * basis.T @ (np.cos(tilt) ** 2 * np.outer(e_p, e_p) + np.outer(e_t, e_t)) @ basis
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def run_gtsam_cpp(survey: Survey) -> MethodRun:
    """The plain GTSAM C++ pipeline a GTSAM user writes with the defaults (see module docstring).

    ``BearingFactor3D`` per reading, ``Point3`` nodes held on z = 0 by a prior,
    the spec's gauge (:class:`~fgloc.factors.baseline_prior.BaselinePrior`, sigma as
    fgloc's), ``gtsam.LevenbergMarquardtOptimizer`` with default parameters except
    relative error tolerance 1e-9, ``gtsam.Marginals`` and one ``marginalCovariance``
    per node. Starts from fgloc's closed-form start (timed apart, as ``initialize``).
    """
    init, t_init = _initial(survey)
    stages = {"initialize": t_init}
    t0 = time.perf_counter()
    C, L = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    cam_keys = {c: C(i) for i, c in enumerate(survey.camera_ids) if c in init.cameras}
    node_keys = {n: L(j) for j, n in enumerate(survey.node_ids) if n in init.nodes}
    for c, k in cam_keys.items():
        cam = init.cameras[c]
        values.insert(k, gtsam.Pose3(gtsam.Rot3(cam.rotation), np.asarray(cam.position, float)))
    gauge_sigma = auto_gauge_sigma(survey, init)  # the same gauge as the fgloc pipeline
    on_plane = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e6, 1e6, gauge_sigma]))
    for n, k in node_keys.items():
        p = np.array(init.nodes[n], dtype=float)
        p[2] = 0.0
        values.insert(k, p)
        graph.add(gtsam.PriorFactorPoint3(k, np.zeros(3), on_plane))
    t = survey.observation_table
    dirs = pan_tilt_bearing(t.pan, t.tilt)
    for m in range(len(t)):
        c, n = survey.camera_ids[t.camera_index[m]], survey.node_ids[t.node_index[m]]
        if c not in cam_keys or n not in node_keys:
            continue
        u = gtsam.Unit3(dirs[m])
        noise = bearing_noise(float(t.pan[m]), float(t.tilt[m]), float(t.sigma[m]), u)
        graph.add(gtsam.BearingFactor3D(cam_keys[c], node_keys[n], u, noise))
    for f in BaselinePrior(survey.mode, cam_keys[survey.gauge.origin], cam_keys[survey.gauge.baseline], gauge_sigma).factors():
        graph.add(f)
    stages["build"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-9)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    res = optimizer.optimize()
    stages["optimize"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    marginals = gtsam.Marginals(graph, res)
    traces = {n: float(np.trace(marginals.marginalCovariance(k)[:2, :2])) for n, k in node_keys.items()}
    stages["marginals"] = time.perf_counter() - t0
    positions = np.array([res.atPoint3(node_keys[n]) if n in node_keys else [np.nan] * 3 for n in survey.node_ids])
    cams = {}
    for c, k in cam_keys.items():
        pose = res.atPose3(k)
        cams[c] = (pose.rotation().matrix(), np.asarray(pose.translation(), float))
    return MethodRun(
        "gtsam_cpp",
        stages,
        int(optimizer.iterations()),
        pan_tilt_cost(survey, positions, cams),
        positions,
        np.array([traces.get(n, np.nan) for n in survey.node_ids]),
    )


def run_numpy_schur(survey: Survey) -> MethodRun:
    """The "speed limit": :func:`fgloc.evaluate.bench_numpy_lm.numpy_schur_lm` from the same start, every node marginal.

    Planar surveys only (the benchmark's scenes)."""
    from fgloc.evaluate.bench_numpy_lm import numpy_schur_lm

    init, t_init = _initial(survey)
    stages = {"initialize": t_init}
    t0 = time.perf_counter()
    cams = [c for c in survey.camera_ids if c in init.cameras]
    nodes = [n for n in survey.node_ids if n in init.nodes]
    ci = {c: i for i, c in enumerate(cams)}
    ni = {n: j for j, n in enumerate(nodes)}
    t = survey.observation_table
    cam_of = np.array([ci.get(c, -1) for c in survey.camera_ids])[t.camera_index]
    node_of = np.array([ni.get(n, -1) for n in survey.node_ids])[t.node_index]
    use = (cam_of >= 0) & (node_of >= 0)
    stages["build"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = numpy_schur_lm(
        np.array([init.cameras[c].rotation for c in cams]),
        np.array([init.cameras[c].position for c in cams], dtype=float),
        np.array([init.nodes[n][:2] for n in nodes], dtype=float),
        cam_of[use],
        node_of[use],
        t.pan[use],
        t.tilt[use],
        t.sigma[use],
        (ci[survey.gauge.origin], ci[survey.gauge.baseline]),
        auto_gauge_sigma(survey, init),
    )
    stages["optimize"] = time.perf_counter() - t0  # node marginals included (same pieces)
    positions = np.full((len(survey.node_ids), 3), np.nan)
    traces = np.full(len(survey.node_ids), np.nan)
    assert out.covariances is not None
    for n, j in ni.items():
        positions[survey.node_ids.index(n)] = [out.nodes[j, 0], out.nodes[j, 1], 0.0]
        traces[survey.node_ids.index(n)] = np.trace(out.covariances[j])
    cameras = {c: (out.rotations[i], out.positions[i]) for c, i in ci.items()}
    return MethodRun(
        "numpy_schur", stages, out.iterations, pan_tilt_cost(survey, positions, cameras), positions, traces,
        note="optimize includes every node marginal",
    )


def _rodrigues(w: FloatArray) -> FloatArray:
    """Rotation matrices (K, 3, 3) of rotation vectors (K, 3)."""
    theta = np.linalg.norm(w, axis=1)
    k = np.where(theta[:, None] > 1e-12, w / np.maximum(theta, 1e-300)[:, None], 0.0)
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3)[None] + s * K + (1 - c) * (K @ K)


def run_scipy(survey: Survey, xtol: float = 1e-12) -> MethodRun:
    """``scipy.optimize.least_squares`` (trf, sparse finite-difference Jacobian), same start."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    init, t_init = _initial(survey)
    stages = {"initialize": t_init}
    t0 = time.perf_counter()
    cams = [c for c in survey.camera_ids if c in init.cameras]
    nodes = [n for n in survey.node_ids if n in init.nodes]
    ci = {c: i for i, c in enumerate(cams)}
    ni = {n: j for j, n in enumerate(nodes)}
    t = survey.observation_table
    use = np.array(
        [survey.camera_ids[a] in ci and survey.node_ids[b] in ni for a, b in zip(t.camera_index, t.node_index)]
    )
    oc = np.array([ci[survey.camera_ids[a]] for a in t.camera_index[use]], dtype=np.int64)
    on = np.array([ni[survey.node_ids[b]] for b in t.node_index[use]], dtype=np.int64)
    pan, tilt, sig = t.pan[use], t.tilt[use], t.sigma[use]
    r0 = np.array([init.cameras[c].rotation for c in cams])
    nc, nn, m = len(cams), len(nodes), len(pan)
    g0, g1 = ci[survey.gauge.origin], ci[survey.gauge.baseline]
    gauge_sigma = auto_gauge_sigma(survey, init)

    def unpack(x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        cam = x[: 6 * nc].reshape(nc, 6)
        rot = r0 @ _rodrigues(cam[:, :3])
        pts = np.column_stack([x[6 * nc :].reshape(nn, 2), np.zeros(nn)])
        return rot, cam[:, 3:], pts

    def residuals(x: FloatArray) -> FloatArray:
        rot, pos, pts = unpack(x)
        q = np.einsum("mji,mj->mi", rot[oc], pts[on] - pos[oc])
        p, tl = bearing_pan_tilt(q)
        e = pan_tilt_residual(pan, tilt, p, tl) / sig[:, None]
        gauge = np.concatenate([pos[g0, :2], pos[g1, :2] - [1.0, 0.0]]) / gauge_sigma
        return np.concatenate([e.ravel(), gauge])

    sparsity = lil_matrix((2 * m + 4, 6 * nc + 2 * nn), dtype=np.int8)
    rows = np.arange(2 * m)
    for d in range(6):
        sparsity[rows, 6 * oc.repeat(2) + d] = 1
    for d in range(2):
        sparsity[rows, 6 * nc + 2 * on.repeat(2) + d] = 1
    for r, cam in ((0, g0), (1, g0), (2, g1), (3, g1)):
        sparsity[2 * m + r, 6 * cam + 3 : 6 * cam + 6] = 1
    x0 = np.concatenate(
        [
            np.column_stack([np.zeros((nc, 3)), [init.cameras[c].position for c in cams]]).ravel(),
            np.array([init.nodes[n][:2] for n in nodes]).ravel(),
        ]
    )
    stages["build"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = least_squares(
        residuals, x0, jac_sparsity=sparsity.tocsr(), method="trf", x_scale="jac", xtol=xtol, ftol=1e-12, gtol=1e-12
    )
    stages["optimize"] = time.perf_counter() - t0
    rot, pos, pts = unpack(sol.x)
    positions = np.full((len(survey.node_ids), 3), np.nan)
    for n, j in ni.items():
        positions[survey.node_ids.index(n)] = pts[j]
    cameras = {c: (rot[i], pos[i]) for c, i in ci.items()}
    return MethodRun(
        "scipy",
        stages,
        int(sol.nfev),
        pan_tilt_cost(survey, positions, cameras),
        positions,
        note="iterations = residual evaluations (nfev); no marginals",
    )


def run_subset_newton(survey: Survey) -> MethodRun:
    """The paper's subset-averaging Newton baseline (:mod:`fgloc.baselines.subset_newton`, two cameras).

    Its whole run (grid-search start, per-subset Newton, averaging) is the
    ``optimize`` stage; ``iterations`` is the median Newton iterations per
    subset. It does not minimize the joint cost, so its final cost is higher.
    """
    from fgloc.baselines.subset_newton import SubsetNewtonError, solve_subset_newton

    nan = np.full((len(survey.node_ids), 3), np.nan)
    try:
        t0 = time.perf_counter()
        out = solve_subset_newton(survey)
        wall = time.perf_counter() - t0
    except SubsetNewtonError as exc:
        return MethodRun("subset_newton", {}, 0, float("nan"), nan, available=False, note=f"failed: {exc}")
    res = out.result
    positions = np.array([res.nodes[n].position if n in res.nodes else [np.nan] * 3 for n in survey.node_ids])
    cost = float("nan")
    if set(survey.camera_ids) <= set(res.cameras):
        cams = {c: (p.rotation, p.position) for c, p in res.cameras.items()}
        seen = np.isfinite(positions).all(axis=1)
        if seen.all():
            cost = pan_tilt_cost(survey, positions, cams)
    return MethodRun(
        "subset_newton",
        {"optimize": wall},
        int(np.median(out.iterations)) if len(out.iterations) else 0,
        cost,
        positions,
        note=f"{out.n_failed} of {len(out.subsets)} subsets failed",
    )


RUNNERS = {
    "fgloc": run_fgloc,
    "fgloc_reference": run_fgloc_reference,
    "gtsam_cpp": run_gtsam_cpp,
    "numpy_schur": run_numpy_schur,
    "scipy": run_scipy,
    "subset_newton": run_subset_newton,
}
