"""Monte Carlo: the self-calibrating head model on coded (off-centre) readings. Seeded; not a test.

Each run draws the heads from the population the prior describes
(:func:`fgloc.sim.head_errors.sample_head_errors`) and a coded-survey-like set of readings of
one fixed scene straight from the head model (:func:`fgloc.sim.coded_head.off_centre_survey`:
views on a grid of encoder angles, every reading up to ``--half-width-deg`` off its view's
centre, independent N(0, ``--sigma-deg``) noise per axis). The same readings are solved
``--head-model full`` twice on the reference graph:

* ``view``: with each reading's view angles (the view model,
  :func:`fgloc.core.head_model.head_view_pan_tilt`);
* ``centred``: without them, as if every reading were centred (``head_pan_tilt``: what
  ``full`` did on a coded survey before view angles were recorded).

Per model: node RMS over the runs against the extended Cramer-Rao bound (the view model's
Bayesian bound at the truth, per run, pooled as an RMS), node ANEES, the joint NEES of all
nodes under their joint covariance, the joint NEES of each run's head parameters (all cameras,
7 dof each) and each head parameter's 95 % coverage. Runs where ``full`` refuses (a parameter
the survey cannot determine) are counted, not hidden.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/coded_head_monte_carlo.py --runs 100

Prints a JSON summary (the numbers in docs/head-calibration.md, "Coded (off-centre) readings").
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from head_monte_carlo import SCENES, head_z, joint_nees, node_errors, scene  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from fgloc.core.errors import FglocError  # noqa: E402
from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS  # noqa: E402
from fgloc.core.model import NodeMode, Survey  # noqa: E402
from fgloc.init.start import InitialEstimate  # noqa: E402
from fgloc.sim.coded_head import centred_view, off_centre_survey  # noqa: E402
from fgloc.sim.head_errors import sample_head_errors  # noqa: E402
from fgloc.solve.head_problem import build_self_calibration_problem, node_rms_bound  # noqa: E402
from fgloc.solve.self_calibration import HeadModel, solve_with_head_model  # noqa: E402

Z95 = 1.959964
MODELS = ("view", "centred")


def view_crb(survey: Survey, heads: dict[str, np.ndarray]) -> float:
    """Node RMS bound of the full head model with its prior at the truth, off-centre readings
    predicted from their views (the survey's view angles)."""
    truth = survey.truth
    assert truth is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes=dict(truth.nodes))
    active = {c: tuple(range(HEAD_DIM)) for c in survey.camera_ids}
    return node_rms_bound(build_self_calibration_problem(survey, start, active, heads))


def one_run(args: tuple[str, int, float, tuple[float, float]]) -> dict:
    name, seed, sigma, half = args
    base = scene(name)
    heads = sample_head_errors(base.camera_ids, np.random.default_rng(2000 + seed))
    coded = off_centre_survey(base, heads, np.random.default_rng(1000 + seed), sigma, half)
    out: dict = {"seed": seed, "crb": view_crb(coded, heads),
                 "views": sum(len({o.view_angles for o in coded.observations if o.camera == c})
                              for c in coded.camera_ids)}
    for key, survey in (("view", coded), ("centred", centred_view(coded))):
        try:
            result, report = solve_with_head_model(survey, HeadModel.FULL, fast_path=False)
        except FglocError as exc:  # reported and counted, not hidden
            out[key] = {"failed": str(exc)}
            continue
        err = {c: e.values - heads[c] for c, e in report.cameras.items()}
        head_nees = sum(float(err[c] @ np.linalg.solve(e.covariance, err[c])) for c, e in report.cameras.items())
        out[key] = {"nodes": node_errors(result, survey) + joint_nees(result, report, survey),
                    "head_nees": head_nees, "head_dof": HEAD_DIM * len(report.cameras),
                    "z": head_z(report, heads), "flagged": len(result.flagged)}
    return out


def summarize(runs: list[dict], key: str, dim: int, cameras: list[str]) -> dict:
    ok = [r for r in runs if "failed" not in r[key]]
    if not ok:
        return {"runs": 0}
    nodes = np.array([r[key]["nodes"] for r in ok])  # (runs, 5): se, nees, n, joint nees, joint dof
    hn = np.array([r[key]["head_nees"] for r in ok])
    hd = np.array([r[key]["head_dof"] for r in ok])
    crb = np.array([r["crb"] for r in ok])
    z = np.array([[r[key]["z"][c] for c in cameras] for r in ok])  # (runs, cams, 7)
    inside = np.abs(z) < Z95
    rms = float(np.sqrt(nodes[:, 0].sum() / nodes[:, 2].sum()))
    return {
        "runs": len(ok), "failed": len(runs) - len(ok),
        "rms": rms, "crb_extended": float(np.sqrt(np.mean(crb**2))), "rms_over_crb": rms / float(np.sqrt(np.mean(crb**2))),
        "anees_nodes": float(nodes[:, 1].sum() / (dim * nodes[:, 2].sum())),
        "anees_joint_nodes": float(nodes[:, 3].sum() / nodes[:, 4].sum()),
        "joint_nodes_bounds_95": [float(v) for v in chi2.ppf([0.025, 0.975], nodes[:, 4].sum()) / nodes[:, 4].sum()],
        "runs_joint_nodes_outside_95": float(np.mean((nodes[:, 3] < chi2.ppf(0.025, nodes[:, 4]))
                                                     | (nodes[:, 3] > chi2.ppf(0.975, nodes[:, 4])))),
        "anees_head": float(hn.sum() / hd.sum()),
        "head_bounds_95": [float(v) for v in chi2.ppf([0.025, 0.975], hd.sum()) / hd.sum()],
        "runs_head_nees_outside_95": float(np.mean((hn < chi2.ppf(0.025, hd)) | (hn > chi2.ppf(0.975, hd)))),
        "head_nees_median": float(np.median(hn)),
        "coverage_95": {c: dict(zip(HEAD_PARAMETERS, np.round(inside[:, i].mean(axis=0), 3).tolist()))
                        for i, c in enumerate(cameras)},
        "coverage_95_pooled": float(inside.mean()),
        "flagged_mean": float(np.mean([r[key]["flagged"] for r in ok])),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--scene", choices=SCENES, default="paper")
    ap.add_argument("--sigma-deg", type=float, default=0.03, help="reading noise per axis (default 0.03 degree)")
    ap.add_argument("--half-width-deg", type=float, nargs=2, default=(13.0, 9.0), metavar=("PAN", "TILT"),
                    help="largest off-centre offset: half the views' grid spacing (default 13 9)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    half = (math.radians(a.half_width_deg[0]), math.radians(a.half_width_deg[1]))
    jobs = [(a.scene, s, math.radians(a.sigma_deg), half) for s in range(a.runs)]
    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(a.workers) as pool:
            runs = list(pool.map(one_run, jobs, chunksize=4))
    else:
        runs = [one_run(j) for j in jobs]
    base = scene(a.scene)
    dim = 2 if base.mode is NodeMode.PLANAR else 3
    summary: dict = {"runs": len(runs), "scene": a.scene, "sigma_deg": a.sigma_deg,
                     "half_width_deg": list(a.half_width_deg), "views_mean": float(np.mean([r["views"] for r in runs])),
                     "head_dof_per_run": HEAD_DIM * len(base.camera_ids)}
    for key in MODELS:
        summary[key] = summarize(runs, key, dim, base.camera_ids)
        summary[key]["failures"] = sorted({r[key]["failed"] for r in runs if "failed" in r[key]})
    text = json.dumps(summary, indent=2)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
