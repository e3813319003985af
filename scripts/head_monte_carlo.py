"""Monte Carlo of the self-calibrating head model (issue 17 goals). Seeded; not a test.

One fixed scene (the paper's planar two-camera scenario at the given heights, or a
three-camera scene) and one fixed set of head errors of typical size; each run
redraws the reading noise. Per run: the ideal solve, the full and the auto
self-calibration on the readings with head errors, and the ideal and auto solves
on the same readings without head errors; then a drift check on camera cam0.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/head_monte_carlo.py --runs 100 --out build/head_mc.json

Prints a markdown table (the one in docs/head-calibration.md).
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gtsam  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS, HeadCalibration, head_pan_tilt  # noqa: E402
from fgloc.core.model import Survey  # noqa: E402
from fgloc.evaluate.crlb import cramer_rao_bound  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.head_errors import inject_head_errors, typical_head_errors  # noqa: E402
from fgloc.sim.scenes import PaperScenario, RandomScene, observe, paper_scenario, random_scene  # noqa: E402
from fgloc.solve.head_drift import DriftMonitor  # noqa: E402
from fgloc.solve.self_calibration import HeadModel, build_self_calibration_problem, solve_with_head_model  # noqa: E402


def scene(name: str, height: float) -> Survey:
    if name == "paper":
        return paper_scenario(PaperScenario(heights=(height, height), seed=3))
    return random_scene(RandomScene(n_cameras=3, n_nodes=100, visibility=1.0, ceiling_share=0.0,
                                    height_range=(0.3, 0.6), seed=3))


def redraw(survey: Survey, seed: int) -> Survey:
    truth = survey.truth
    assert truth is not None
    cams = [truth.cameras[c] for c in survey.camera_ids]
    nodes = np.array([truth.nodes[n] for n in survey.node_ids])
    obs = observe(survey.camera_ids, cams, survey.node_ids, nodes, survey.sigma, np.random.default_rng(seed))
    return replace(survey, observations=obs)


def extended_crb(survey: Survey, heads: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Node covariances of the full head model (with its priors) linearized at the truth."""
    truth = survey.truth
    assert truth is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes=dict(truth.nodes))
    active = {c: tuple(range(HEAD_DIM)) for c in survey.camera_ids}
    problem = build_self_calibration_problem(survey, start, active, heads)
    problem.prepare(problem.initial)
    marg = gtsam.Marginals(problem.graph.linearize(problem.initial), problem.initial)
    return {n: marg.marginalCovariance(k) for n, k in problem.node_keys.items()}


def errors(result, survey: Survey) -> tuple[float, float]:
    """(sum of squared node errors, sum of per-node NEES) over the localized nodes."""
    truth = survey.truth
    assert truth is not None
    se, ne = 0.0, 0.0
    for nid, est in result.nodes.items():
        d = est.position[:2] - truth.nodes[nid][:2]
        se += float(d @ d)
        ne += float(d @ np.linalg.solve(est.covariance, d))
    return se, ne


def one_run(args: tuple[str, float, int, dict[str, list[float]], float]) -> dict:
    name, height, seed, heads_list, drift_deg = args
    heads = {c: np.asarray(v) for c, v in heads_list.items()}
    clean = redraw(scene(name, height), 1000 + seed)
    dirty = inject_head_errors(clean, heads)
    out: dict = {"seed": seed}
    ideal, _ = solve_with_head_model(dirty, HeadModel.IDEAL)
    out["ideal"] = errors(ideal, dirty) + (len(ideal.nodes),)
    full, rep = solve_with_head_model(dirty, HeadModel.FULL)
    out["full"] = errors(full, dirty) + (len(full.nodes),)
    out["full_flagged"] = len(full.flagged)
    out["full_z"] = {c: list((rep.cameras[c].values - heads[c]) / rep.cameras[c].std) for c in heads}
    auto, arep = solve_with_head_model(dirty, HeadModel.AUTO)
    out["auto"] = errors(auto, dirty) + (len(auto.nodes),)
    out["auto_params"] = sum(len(c.estimated) for c in arep.cameras.values())
    cideal, _ = solve_with_head_model(clean, HeadModel.IDEAL)
    out["clean_ideal"] = errors(cideal, clean) + (len(cideal.nodes),)
    cauto, crep = solve_with_head_model(clean, HeadModel.AUTO)
    out["clean_auto"] = errors(cauto, clean) + (len(cauto.nodes),)
    out["clean_auto_ideal"] = all(not c.estimated for c in crep.cameras.values())
    # Drift: re-read known motes (the survey's estimates) with cam0 after its tilt index moved.
    truth = dirty.truth
    assert truth is not None
    rng = np.random.default_rng(5000 + seed)
    est = rep.cameras["cam0"]
    # The calibration's marginal covariance is not used: its errors are correlated with the
    # pose and mote estimates so that the survey's own readings are predicted far better.
    calib = HeadCalibration(est.values)
    out["drift_at"] = {}
    for drift in (0.0, drift_deg):
        moved = heads["cam0"].copy()
        moved[0] += np.deg2rad(drift)
        for repeats in (1, 3):
            monitor = DriftMonitor(full.cameras["cam0"], calib, dirty.sigma)
            known = [n for n in dirty.node_ids if n in full.nodes]
            order = rng.permutation(len(known))[:10]
            flagged = None
            for k, j in enumerate(order):
                nid = known[j]
                cam = truth.cameras["cam0"]
                q = cam.rotation.T @ (truth.nodes[nid] - cam.position)
                pan, tilt, _, _ = head_pan_tilt(q, moved, jacobians=False)
                for _ in range(repeats):
                    check = monitor.add(nid, full.nodes[nid].position, float(pan + rng.normal(0, dirty.sigma)),
                                        float(tilt + rng.normal(0, dirty.sigma)), full.nodes[nid].covariance)
                if check.drifted and flagged is None:
                    flagged = k + 1
            out["drift_at"][f"{drift}_{repeats}"] = flagged
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--scene", choices=("paper", "three"), default="paper")
    ap.add_argument("--height", type=float, default=0.3)
    ap.add_argument("--drift-deg", type=float, default=0.1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    base = scene(a.scene, a.height)
    heads = typical_head_errors(base.camera_ids, np.random.default_rng(1))
    crb_ideal = cramer_rao_bound(base)
    crb_ext = extended_crb(inject_head_errors(base, heads), heads)
    jobs = [(a.scene, a.height, s, {c: v.tolist() for c, v in heads.items()}, a.drift_deg) for s in range(a.runs)]
    with ProcessPoolExecutor(a.workers) as pool:
        runs = list(pool.map(one_run, jobs))
    crb_i = float(np.sqrt(np.mean([np.trace(c) for c in crb_ideal.values()])))
    crb_e = float(np.sqrt(np.mean([np.trace(c) for c in crb_ext.values()])))
    summary: dict = {"runs": a.runs, "scene": a.scene, "height": a.height, "crb_ideal": crb_i, "crb_extended": crb_e}
    for key in ("ideal", "full", "auto", "clean_ideal", "clean_auto"):
        se = sum(r[key][0] for r in runs)
        ne = sum(r[key][1] for r in runs)
        n = sum(r[key][2] for r in runs)
        summary[key] = {"rms": float(np.sqrt(se / n)), "anees": ne / (2 * n)}  # NEES / dof (planar: 2)
    n_nodes = sum(r["full"][2] for r in runs)
    summary["anees_bounds_95"] = list(chi2.ppf([0.025, 0.975], 2 * n_nodes) / (2 * n_nodes))
    summary["anees_bounds_95_per_run"] = list(chi2.ppf([0.025, 0.975], 2 * a.runs) / (2 * a.runs))
    z = np.array([[r["full_z"][c] for c in base.camera_ids] for r in runs])  # (runs, cams, 7)
    summary["coverage_95"] = {c: dict(zip(HEAD_PARAMETERS, np.mean(np.abs(z[:, i]) < 1.959964, axis=0).tolist()))
                              for i, c in enumerate(base.camera_ids)}
    summary["clean_auto_picks_ideal"] = float(np.mean([r["clean_auto_ideal"] for r in runs]))
    summary["auto_params_mean"] = float(np.mean([r["auto_params"] for r in runs]))
    drift = {}
    for key in runs[0]["drift_at"]:
        at = [r["drift_at"][key] for r in runs]
        drift[key] = {"flagged_within_10": float(np.mean([x is not None for x in at])),
                      "median_motes": float(np.median([x for x in at if x is not None])) if any(
                          x is not None for x in at) else None}
    summary["drift"] = drift
    if a.out:
        os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
        with open(a.out, "w") as f:
            json.dump({"summary": summary, "runs": runs}, f, indent=1)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
