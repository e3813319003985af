"""Monte Carlo of the lever arm per zoom (docs/head-calibration.md, "Lever arm per zoom"). Seeded; not a test.

One fixed geometry: planar, 3 cameras, 100 nodes (heights 0.3-0.6, scene seed 3), every
camera reads every node twice, once at zoom 0 and once at zoom 0.5; heads turn +-170 degrees
(``--pan-range-deg``, an EVI-D70's range: readings beyond are dropped, so none sits at the
+-180 degree seam where the pan-scale reading jumps, docs/head-calibration.md). Each run draws the heads
from the population the prior describes (the typical sizes; each zoom's lever arm drawn on
its own, one sigma ``--lever`` per component, also the prior's) and fresh reading noise, and
solves ``--head-model full`` twice on the same readings:

* **per zoom**: the survey's zooms given, so each camera has one lever arm per zoom (9 parameters);
* **one lever arm**: the zooms left out (a version-1 survey), so one lever arm per camera (7).

Reports node RMS against the extended model's Cramér-Rao bound (Bayesian, its prior included,
linearized at the truth), per-node ANEES (mean over runs of each run's mean, with the 95 %
interval of that mean from the run-to-run spread: a run's nodes share its head errors), the joint NEES of each camera's four lever-arm
components (4 dof) and the 95 % coverage of each lever-arm component.

    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python scripts/head_zoom_monte_carlo.py --runs 200
    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python scripts/head_zoom_monte_carlo.py --runs 200 --lever 0.005

Prints a JSON summary.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS  # noqa: E402
from fgloc.core.model import Result, Survey  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.head_errors import inject_head_errors, sample_head_errors, sample_zoom_levers  # noqa: E402
from fgloc.sim.scenes import RandomScene, observe, random_scene  # noqa: E402
from fgloc.solve.head_problem import node_rms_bound  # noqa: E402
from fgloc.solve.joint import SolverOptions  # noqa: E402
from fgloc.solve.self_calibration import HeadModel, build_self_calibration_problem, solve_with_head_model  # noqa: E402

ZOOMS = (0.0, 0.5)
Z95 = 1.959964


def geometry() -> Survey:
    return random_scene(RandomScene(n_cameras=3, n_nodes=100, visibility=1.0, ceiling_share=0.0,
                                    height_range=(0.3, 0.6), repeats=2, seed=3))


def draw(base: Survey, seed: int, sigmas: np.ndarray, pan_range: float | None = None,
         ) -> tuple[Survey, dict[str, np.ndarray], dict]:
    """Fresh noise (every pair read once per zoom) and heads drawn from the population; with
    ``pan_range`` (rad) the readings whose true mechanical pan lies beyond it are dropped."""
    truth = base.truth
    assert truth is not None
    rng = np.random.default_rng(seed)
    obs = observe(base.camera_ids, [truth.cameras[c] for c in base.camera_ids], base.node_ids,
                  np.array([truth.nodes[n] for n in base.node_ids]), base.sigma, rng, repeats=2)
    seen: dict[tuple[str, str], int] = {}
    zoomed = []
    for o in obs:
        k = seen.get((o.camera, o.node), 0)
        seen[(o.camera, o.node)] = k + 1
        zoomed.append(replace(o, zoom=ZOOMS[k % 2]))
    survey = replace(base, observations=zoomed)
    heads = sample_head_errors(base.camera_ids, rng, sigmas)
    levers = sample_zoom_levers(base.camera_ids, [ZOOMS[1]], rng, float(sigmas[5]))
    truth_ext = {c: np.concatenate([heads[c], levers[c][ZOOMS[1]]]) for c in base.camera_ids}
    return inject_head_errors(survey, heads, pan_range, zoom_levers=levers), truth_ext, levers


def extended_crb(survey: Survey, truth_ext: dict[str, np.ndarray], sigmas: np.ndarray) -> float:
    """RMS bound of the per-zoom head model with its prior, linearized at the truth."""
    truth = survey.truth
    assert truth is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes=dict(truth.nodes))
    problem = build_self_calibration_problem(survey, start, {c: tuple(range(9)) for c in survey.camera_ids},
                                             truth_ext, SolverOptions(), prior_sigmas=sigmas)
    return node_rms_bound(problem)


def node_stats(result: Result, survey: Survey) -> tuple[float, float, int]:
    truth = survey.truth
    assert truth is not None
    se = ne = 0.0
    for nid, est in result.nodes.items():
        d = est.position[:2] - truth.nodes[nid][:2]
        se += float(d @ d)
        ne += float(d @ np.linalg.solve(est.covariance, d))
    return se, ne, len(result.nodes)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--lever", type=float, default=float(DEFAULT_PRIOR_SIGMAS[5]),
                    help="one sigma of each lever-arm component (population and prior), baseline units")
    ap.add_argument("--pan-range-deg", type=float, default=170.0, help="0: unlimited pan")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    sigmas = DEFAULT_PRIOR_SIGMAS.copy()
    sigmas[5:7] = args.lever
    base = geometry()
    acc: dict[str, dict] = {k: {"se": 0.0, "ne": 0.0, "n": 0, "lever_nees": 0.0, "lever_dof": 0, "inside": 0,
                                "count": 0, "anees_runs": [], "lever_nees_cams": []} for k in ("per_zoom", "one_lever")}
    pan_range = np.deg2rad(args.pan_range_deg) if args.pan_range_deg > 0 else None
    crb2, failed = [], 0
    for run in range(args.runs):
        survey, truth_ext, _ = draw(base, 1000 + run, sigmas, pan_range)
        flat = replace(survey, observations=[replace(o, zoom=None) for o in survey.observations])
        try:
            fits = {"per_zoom": solve_with_head_model(survey, HeadModel.FULL, prior_sigmas=sigmas),
                    "one_lever": solve_with_head_model(flat, HeadModel.FULL, prior_sigmas=sigmas)}
        except Exception as exc:  # noqa: BLE001 - a Monte Carlo run that fails is counted, not fatal
            failed += 1
            print(f"run {run}: {exc}")
            continue
        crb2.append(extended_crb(survey, truth_ext, sigmas) ** 2)
        for name, (result, report) in fits.items():
            a = acc[name]
            se, ne, n = node_stats(result, survey)
            a["se"] += se
            a["ne"] += ne
            a["n"] += n
            a["anees_runs"].append(ne / (2 * n))
            for cid, est in report.cameras.items():
                cov = est.covariance
                assert cov is not None
                if name == "per_zoom":
                    e = (est.values - truth_ext[cid])[5:9]
                    c = cov[5:9, 5:9]
                    a["lever_nees_cams"].append(float(e @ np.linalg.solve(c, e)))
                    a["lever_nees"] += a["lever_nees_cams"][-1]
                    a["lever_dof"] += 4
                    a["inside"] += int(np.sum(np.abs(e) < Z95 * np.sqrt(np.diag(c))))
                    a["count"] += 4
                else:  # the one lever arm against each zoom's true lever arm
                    for lever in (truth_ext[cid][5:7], truth_ext[cid][7:9]):
                        e = est.values[5:7] - lever
                        a["lever_nees"] += float(e @ np.linalg.solve(cov[5:7, 5:7], e))
                        a["lever_dof"] += 2
                        a["inside"] += int(np.sum(np.abs(e) < Z95 * np.sqrt(np.diag(cov)[5:7])))
                        a["count"] += 2
        if (run + 1) % 20 == 0:
            print(f"{run + 1} runs", flush=True)
    crb = float(np.sqrt(np.mean(crb2)))
    summary: dict = {"runs": args.runs, "failed": failed, "lever_sigma": args.lever, "zooms": list(ZOOMS),
                     "pan_range_deg": args.pan_range_deg, "readings_last_run": len(survey.observations),
                     "crb_extended": crb}
    for name, a in acc.items():
        rms = float(np.sqrt(a["se"] / max(a["n"], 1)))
        lo, hi = chi2.ppf([0.025, 0.975], max(a["lever_dof"], 1)) / max(a["lever_dof"], 1)
        runs = np.array(a["anees_runs"])
        half = 1.96 * float(np.std(runs, ddof=1)) / np.sqrt(len(runs)) if len(runs) > 1 else float("nan")
        summary[name] = {"rms": rms, "rms_over_crb": rms / crb, "anees_per_node": float(np.mean(runs)),
                         "anees_per_node_ci95": [float(np.mean(runs)) - half, float(np.mean(runs)) + half],
                         "lever_anees": a["lever_nees"] / max(a["lever_dof"], 1),
                         "lever_anees_bounds_95": [float(lo), float(hi)],
                         "lever_coverage_95": a["inside"] / max(a["count"], 1)}
        if a["lever_nees_cams"]:  # per camera and run, 4 dof: median 3.36, 1 % above 13.28 if right
            cams = np.array(a["lever_nees_cams"])
            summary[name] |= {"lever_nees_median": float(np.median(cams)),
                              "lever_nees_share_above_chi2_99": float(np.mean(cams > chi2.ppf(0.99, 4))),
                              "lever_nees_largest": sorted(cams.tolist())[-5:]}
    text = json.dumps(summary, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
