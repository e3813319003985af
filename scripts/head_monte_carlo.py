"""Monte Carlo of the self-calibrating head model (issue 17 goals). Seeded; not a test.

Two experiments on one fixed scene geometry:

``population`` (default): each run draws its heads from the population the prior
describes (:func:`fgloc.sim.head_errors.sample_head_errors`: zero-mean Gaussian,
one sigma = the typical sizes = ``DEFAULT_PRIOR_SIGMAS``) *and* redraws the reading
noise. Then the posterior covariances are exactly what a Bayesian consistency check
tests: node ANEES and each head parameter's 95 % coverage. Per run: the ideal, the
full and the auto solve with head errors, the ideal and the auto solve on the same
readings without head errors.

``fixed``: one draw of heads (seed 1), each run redraws only the noise; the full
solve only: the frequentist numbers at a fixed truth, meaningful where the data
dominate the prior (``--scene 3d4``: 3d, four cameras).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/head_monte_carlo.py --runs 500 --out build/head_mc.json
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/head_monte_carlo.py --experiment fixed --scene 3d4 --runs 400
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/head_monte_carlo.py --pan-range-deg 170 --fast-check --runs 400

``--pan-range-deg``: the heads turn only +-that far; readings whose true mechanical pan lies
beyond are dropped (from the clean and the head-error survey alike). ``--fast-check``: also
solve ``full`` (and ``auto``, population) on the node-eliminated fast path and record how far
its result lies from the reference graph's.

Prints a JSON summary (the numbers in docs/head-calibration.md).
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.stats import chi2, t  # noqa: E402

from fgloc.core.errors import FglocError  # noqa: E402
from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS  # noqa: E402
from fgloc.core.model import NodeMode, Result, Survey  # noqa: E402
from fgloc.evaluate.crlb import cramer_rao_bound  # noqa: E402
from fgloc.evaluate.joint_nees import inverse_hessian_block  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.head_errors import inject_head_errors, limit_pan_range, sample_head_errors  # noqa: E402
from fgloc.sim.scenes import PaperScenario, RandomScene, observe, paper_scenario, random_scene  # noqa: E402
from fgloc.solve.head_problem import node_rms_bound  # noqa: E402
from fgloc.solve.self_calibration import (  # noqa: E402
    HeadCalibrationReport,
    HeadModel,
    build_self_calibration_problem,
    solve_with_head_model,
)

SCENES = ("paper", "paper-facing", "three", "3d4")
Z95 = 1.959964


def scene(name: str, height: float = 0.3) -> Survey:
    """paper: the paper's planar two-camera scene; paper-facing: the same with cam0's base turned 180 degrees
    about the vertical (its pans then span about +-75 degrees instead of crossing the +-180 degree seam);
    three: planar, 3 cameras; 3d4: 3d, 4 cameras (100 nodes)."""
    if name == "paper":
        return paper_scenario(PaperScenario(heights=(height, height), seed=3))
    if name == "paper-facing":
        s = paper_scenario(PaperScenario(heights=(height, height), seed=3))
        assert s.truth is not None
        cam0 = s.truth.cameras["cam0"]
        turned = replace(cam0, rotation=np.diag([-1.0, -1.0, 1.0]) @ cam0.rotation)
        s = replace(s, truth=replace(s.truth, cameras={**s.truth.cameras, "cam0": turned}))
        return redraw(s, 3)
    n_cam, mode = (3, NodeMode.PLANAR) if name == "three" else (4, NodeMode.THREE_D)
    return random_scene(RandomScene(n_cameras=n_cam, n_nodes=100, mode=mode, visibility=1.0, ceiling_share=0.0,
                                    height_range=(0.3, 0.6), seed=3))


def redraw(survey: Survey, seed: int) -> Survey:
    truth = survey.truth
    assert truth is not None
    cams = [truth.cameras[c] for c in survey.camera_ids]
    nodes = np.array([truth.nodes[n] for n in survey.node_ids])
    obs = observe(survey.camera_ids, cams, survey.node_ids, nodes, survey.sigma, np.random.default_rng(seed))
    return replace(survey, observations=obs)


def _dim(survey: Survey) -> int:
    return 2 if survey.mode is NodeMode.PLANAR else 3


def extended_crb(survey: Survey, heads: dict[str, np.ndarray]) -> float:
    """RMS bound of the full head model with its priors (Bayesian), linearized at the truth."""
    truth = survey.truth
    assert truth is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes=dict(truth.nodes))
    active = {c: tuple(range(HEAD_DIM)) for c in survey.camera_ids}
    problem = build_self_calibration_problem(survey, start, active, heads)
    return node_rms_bound(problem)


def node_errors(result: Result, survey: Survey) -> tuple[float, float, int]:
    """(sum of squared node errors, sum of per-node NEES, nodes) over the localized nodes."""
    truth = survey.truth
    assert truth is not None
    d_ = _dim(survey)
    se, ne = 0.0, 0.0
    for nid, est in result.nodes.items():
        d = est.position[:d_] - truth.nodes[nid][:d_]
        se += float(d @ d)
        ne += float(d @ np.linalg.solve(est.covariance, d))
    return se, ne, len(result.nodes)


def joint_covariance(result: Result, report: HeadCalibrationReport, survey: Survey) -> tuple[np.ndarray, list[str]]:
    """Joint covariance of all node positions: the inverse Hessian of the solved model (the head
    parameters it estimated, the readings it kept) linearized at the result; and the node order."""
    active = {c: tuple(HEAD_PARAMETERS.index(n) for n in e.estimated) for c, e in report.cameras.items()}
    heads = {c: e.values for c, e in report.cameras.items()}
    start = InitialEstimate(cameras=dict(result.cameras), nodes={n: e.position for n, e in result.nodes.items()})
    exclude = frozenset(f.index for f in result.flagged)
    problem = build_self_calibration_problem(survey, start, active, heads, exclude=exclude)
    problem.prepare(problem.initial)
    order = list(problem.node_keys)
    keys = [problem.node_keys[n] for n in order]
    return inverse_hessian_block(problem.graph, problem.initial, keys, _dim(survey)), order


def joint_nees(result: Result, report: HeadCalibrationReport, survey: Survey,
               extended: tuple[Result, HeadCalibrationReport] | None = None) -> tuple[float, int]:
    """NEES of all node positions together under their joint covariance (chi-square, d*N dof).

    When auto kept the ideal head, the covariance is as auto reports it: the ``extended``
    (full) solve's joint covariance plus ``D D'``, ``D`` the offset of the ideal estimates
    from the extended ones.
    """
    truth = survey.truth
    assert truth is not None
    d_ = _dim(survey)
    consider = report.model is HeadModel.AUTO and not any(e.estimated for e in report.cameras.values())
    if consider:
        assert extended is not None
        cov, order = joint_covariance(*extended, survey)
        D = np.concatenate([result.nodes[n].position[:d_] - extended[0].nodes[n].position[:d_] for n in order])
        cov = cov + np.outer(D, D)
    else:
        cov, order = joint_covariance(result, report, survey)
    err = np.concatenate([result.nodes[n].position[:d_] - truth.nodes[n][:d_] for n in order])
    return float(err @ np.linalg.solve(cov, err)), len(err)


def head_z(report: HeadCalibrationReport, heads: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """(estimate - truth) / std per camera and parameter (nan where not estimated)."""
    out = {}
    for c, e in report.cameras.items():
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(e.std > 0, (e.values - heads[c]) / e.std, np.nan)
        out[c] = [float(v) for v in z]
    return out


def fast_vs_reference(fast: tuple[Result, HeadCalibrationReport], ref: tuple[Result, HeadCalibrationReport],
                      survey: Survey, ref_joint: float) -> dict:
    """How far the fast path's result lies from the reference graph's: the largest node position
    difference (in units of the reference node's largest marginal std), the largest head-value
    difference (in units of the reference std), the joint NEES of each and the decisions."""
    d_ = _dim(survey)
    dn = 0.0
    for nid, e in ref[0].nodes.items():
        f = fast[0].nodes.get(nid)
        if f is None:
            return {"missing_node": nid}
        std = float(np.sqrt(np.max(np.linalg.eigvalsh(e.covariance[:d_, :d_]))))
        dn = max(dn, float(np.linalg.norm(f.position[:d_] - e.position[:d_])) / std)
    dh = 0.0
    for c, e in ref[1].cameras.items():
        fe = fast[1].cameras[c]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(e.std > 0, np.abs(fe.values - e.values) / e.std, 0.0)
        dh = max(dh, float(np.max(z)))
    fast_joint = joint_nees(*fast, survey)[0] if fast[1].model is HeadModel.FULL or any(
        e.estimated for e in fast[1].cameras.values()) else float("nan")
    return {"node_diff_over_std": dn, "head_diff_over_std": dh, "joint_nees_fast": fast_joint,
            "joint_nees_ref": ref_joint, "flagged_fast": len(fast[0].flagged), "flagged_ref": len(ref[0].flagged),
            "estimated_same": all(fast[1].cameras[c].estimated == e.estimated for c, e in ref[1].cameras.items())}


def one_run(args: tuple[str, str, int, float | None, bool]) -> dict:
    try:
        return _one_run(*args)
    except FglocError as exc:  # reported and counted, not hidden
        return {"seed": args[2], "failed": str(exc)}


def _one_run(experiment: str, name: str, seed: int, pan_range: float | None = None, fast: bool = False) -> dict:
    base = scene(name)
    rng_seed = 1 if experiment == "fixed" else 2000 + seed
    heads = sample_head_errors(base.camera_ids, np.random.default_rng(rng_seed))
    clean = redraw(base, 1000 + seed)
    out: dict = {"seed": seed, "heads": {c: v.tolist() for c, v in heads.items()}}
    if pan_range is not None:  # the readings the true heads could take, with and without head errors
        clean, dropped = limit_pan_range(clean, pan_range, heads)
        out["dropped"] = len(dropped)
    dirty = inject_head_errors(clean, heads)
    full, rep = solve_with_head_model(dirty, HeadModel.FULL, fast_path=False)
    out["full"] = node_errors(full, dirty) + joint_nees(full, rep, dirty)
    out["full_z"] = head_z(rep, heads)
    if fast:
        out["fast_full"] = fast_vs_reference(solve_with_head_model(dirty, HeadModel.FULL, fast_path=True),
                                             (full, rep), dirty, out["full"][3])
    if experiment == "fixed":  # the frequentist check of the full model only
        return out
    ideal, irep = solve_with_head_model(dirty, HeadModel.IDEAL)
    out["ideal"] = node_errors(ideal, dirty) + joint_nees(ideal, irep, dirty)
    auto, arep = solve_with_head_model(dirty, HeadModel.AUTO, fast_path=False)
    out["auto"] = node_errors(auto, dirty) + joint_nees(auto, arep, dirty, (full, rep))
    out["auto_cameras"] = sum(bool(c.estimated) for c in arep.cameras.values())
    out["auto_lr"] = [arep.lr_statistic, arep.lr_threshold]
    if arep.score is not None:
        out["auto_score"] = [arep.score.statistic, arep.score.threshold, arep.score.p_value]
    if fast:
        out["fast_auto"] = fast_vs_reference(solve_with_head_model(dirty, HeadModel.AUTO, fast_path=True),
                                             (auto, arep), dirty, out["auto"][3])
    if experiment == "population":
        cideal, cirep = solve_with_head_model(clean, HeadModel.IDEAL)
        out["clean_ideal"] = node_errors(cideal, clean) + joint_nees(cideal, cirep, clean)
        cauto, crep = solve_with_head_model(clean, HeadModel.AUTO, fast_path=False)
        cfull, cfrep = solve_with_head_model(clean, HeadModel.FULL, fast_path=False)
        out["clean_auto"] = node_errors(cauto, clean) + joint_nees(cauto, crep, clean, (cfull, cfrep))
        out["clean_auto_ideal"] = all(not c.estimated for c in crep.cameras.values())
        out["clean_full"] = node_errors(cfull, clean) + joint_nees(cfull, cfrep, clean)
    return out


def summarize(runs: list[dict], keys: tuple[str, ...], dim: int) -> dict:
    n_runs = len(runs)
    out: dict = {}
    for key in keys:
        se = np.array([r[key][0] for r in runs])
        ne = np.array([r[key][1] for r in runs])
        n = np.array([r[key][2] for r in runs])
        jn = np.array([r[key][3] for r in runs])
        jd = np.array([r[key][4] for r in runs])
        per_run = ne / (dim * n)
        half = t.ppf(0.975, n_runs - 1) * per_run.std(ddof=1) / np.sqrt(n_runs)
        out[key] = {
            "rms": float(np.sqrt(se.sum() / n.sum())),
            # Mean per-node NEES per dof, and the 95 % interval of that mean from the spread of
            # the runs (nodes of one run share the head and pose errors; runs are independent).
            "anees_nodes": float(ne.sum() / (dim * n.sum())),
            "anees_nodes_ci95_from_runs": [float(per_run.mean() - half), float(per_run.mean() + half)],
            # Joint NEES of all nodes of a run under their joint covariance: chi-square(d*N) per run.
            "anees_joint": float(jn.sum() / jd.sum()),
            "runs_joint_nees_outside_95": float(np.mean(
                (jn < chi2.ppf(0.025, jd)) | (jn > chi2.ppf(0.975, jd)))),
        }
    dof_nodes = int(dim * sum(r["full"][2] for r in runs))
    dof_joint = int(sum(r["full"][4] for r in runs))
    out["bounds_95"] = {
        "nodes_pooled_chi2": [float(v) for v in chi2.ppf([0.025, 0.975], dof_nodes) / dof_nodes],
        "nodes_pooled_dof": dof_nodes,
        "joint_chi2": [float(v) for v in chi2.ppf([0.025, 0.975], dof_joint) / dof_joint],
        "joint_dof": dof_joint,
        "per_run_joint_chi2": [float(v) for v in chi2.ppf([0.025, 0.975], runs[0]["full"][4]) / runs[0]["full"][4]],
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--experiment", choices=("population", "fixed"), default="population")
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--scene", choices=SCENES, default="paper")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--pan-range-deg", type=float, default=None,
                    help="heads turn only +-this far; readings beyond are dropped (default: unlimited)")
    ap.add_argument("--fast-check", action="store_true",
                    help="also solve on the node-eliminated fast path and compare with the reference graph")
    a = ap.parse_args()
    base = scene(a.scene)
    pan_range = None if a.pan_range_deg is None else float(np.deg2rad(a.pan_range_deg))
    jobs = [(a.experiment, a.scene, s, pan_range, a.fast_check) for s in range(a.runs)]
    with ProcessPoolExecutor(a.workers) as pool:
        all_runs = list(pool.map(one_run, jobs, chunksize=4))
    runs = [r for r in all_runs if "failed" not in r]
    dim = _dim(base)
    if pan_range is not None:  # the bounds of the readings a head with that range takes
        base = limit_pan_range(base, pan_range)[0]
    crb_i = float(np.sqrt(np.mean([np.trace(c) for c in cramer_rao_bound(base).values()])))
    zero = {c: np.zeros(HEAD_DIM) for c in base.camera_ids}
    crb_e = extended_crb(base, zero)
    keys = ("ideal", "full", "auto", "clean_ideal", "clean_auto", "clean_full") if a.experiment == "population" else ("full",)
    summary: dict = {"experiment": a.experiment, "runs": len(runs), "scene": a.scene, "crb_ideal": crb_i,
                     "pan_range_deg": a.pan_range_deg,
                     "crb_extended": crb_e, "failed": [r for r in all_runs if "failed" in r]}
    summary.update(summarize(runs, keys, dim))
    for key in keys:
        summary[key]["rms_over_crb_ideal"] = summary[key]["rms"] / crb_i
        summary[key]["rms_over_crb_extended"] = summary[key]["rms"] / crb_e
    z = np.array([[r["full_z"][c] for c in base.camera_ids] for r in runs])  # (runs, cams, 7)
    inside = np.abs(z) < Z95
    summary["coverage_95_full"] = {c: dict(zip(HEAD_PARAMETERS, np.round(inside[:, i].mean(axis=0), 4).tolist()))
                                   for i, c in enumerate(base.camera_ids)}
    summary["coverage_95_full_pooled"] = float(inside.mean())
    summary["coverage_binomial_sd"] = float(np.sqrt(0.95 * 0.05 / len(runs)))
    if a.experiment == "population":
        summary["auto_cameras_estimated_mean"] = float(np.mean([r["auto_cameras"] for r in runs]))
        summary["auto_ideal_kept_share"] = float(np.mean([r["auto_cameras"] == 0 for r in runs]))
        summary["clean_auto_picks_ideal"] = float(np.mean([r["clean_auto_ideal"] for r in runs]))
        summary["clean_auto_rms_ratio"] = summary["clean_auto"]["rms"] / summary["clean_ideal"]["rms"]
        summary["clean_full_rms_ratio"] = summary["clean_full"]["rms"] / summary["clean_ideal"]["rms"]
        kept = [r for r in runs if r["auto_cameras"] == 0]
        if kept:
            summary["auto_kept_runs"] = {"runs": len(kept), "auto": summarize(kept, ("auto", "full"), dim)}
    if pan_range is not None:
        summary["dropped_readings_mean"] = float(np.mean([r["dropped"] for r in runs]))
    for key in ("fast_full", "fast_auto"):
        fr = [r[key] for r in runs if key in r]
        if fr:
            same = [("missing_node" not in f and f["node_diff_over_std"] < 1e-3 and f["head_diff_over_std"] < 1e-3
                     and f["estimated_same"] and f["flagged_fast"] == f["flagged_ref"]) for f in fr]
            summary[key] = {
                "runs": len(fr), "same_within_1e-3_std": int(sum(same)),
                "max_node_diff_over_std": max(f.get("node_diff_over_std", np.inf) for f in fr),
                "max_head_diff_over_std": max(f.get("head_diff_over_std", np.inf) for f in fr),
                "differing_seeds": [r["seed"] for r, ok in zip((r for r in runs if key in r), same) if not ok],
            }
    if a.out:
        os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
        with open(a.out, "w") as f:
            json.dump({"summary": summary, "runs": all_runs}, f, indent=1)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
