"""Monte Carlo of the calibration-only drift check (issue 17 drift goal). Seeded; not a test.

Each run: the paper's planar two-camera scene (100 nodes, heights 0.3), heads drawn
from the population the prior describes, fresh reading noise; the survey solved
with ``--head-model full`` (or ``auto``). Then camera cam0 re-reads known motes
(:func:`fgloc.solve.head_drift.known_motes_from_survey`), in order of predicted
tilt std (``best``) or at random, ``m`` readings each, with its true head and a
tilt-index drift of 0 or ``--drift-deg``; the SPRT of :class:`DriftMonitor`
(alpha = 1 %) watches. Reported per setting: share of runs flagged within 10
motes, median motes to the flag, false alarms (no drift) within 10 and within
``--long`` motes, and the spread of the GLS z at 10 motes without drift (1 if the
prediction covariance is right).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/head_drift_monte_carlo.py --runs 400 --out build/head_drift.json
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from fgloc.core.head_model import head_pan_tilt  # noqa: E402
from fgloc.sim.head_errors import inject_head_errors, sample_head_errors  # noqa: E402
from fgloc.sim.scenes import PaperScenario, observe, paper_scenario  # noqa: E402
from fgloc.solve.head_drift import DriftMonitor, known_motes_from_survey  # noqa: E402
from fgloc.solve.self_calibration import HeadModel, solve_with_head_model  # noqa: E402

REPEATS = (1, 3, 5)
ORDERS = ("best", "random")


def one_run(args: tuple[int, float, str, int]) -> dict:
    seed, drift_deg, model, long = args
    base = paper_scenario(PaperScenario(heights=(0.3, 0.3), seed=3))
    truth = base.truth
    assert truth is not None
    heads = sample_head_errors(base.camera_ids, np.random.default_rng(2000 + seed))
    cams = [truth.cameras[c] for c in base.camera_ids]
    nodes = np.array([truth.nodes[n] for n in base.node_ids])
    clean = replace(base, observations=observe(base.camera_ids, cams, base.node_ids, nodes, base.sigma,
                                               np.random.default_rng(1000 + seed)))
    survey = inject_head_errors(clean, heads)
    result, report = solve_with_head_model(survey, HeadModel(model))
    known = known_motes_from_survey(survey, result, report, "cam0")
    rng = np.random.default_rng(7000 + seed)
    cam = truth.cameras["cam0"]
    out: dict = {"seed": seed, "pred_tilt_std_all_deg": float(np.rad2deg(np.sqrt(np.mean(
        np.diag(known.tilt_covariance)))))}
    shuffled = [str(x) for x in rng.permutation(list(known.ids))[:long]]
    for order in ORDERS:
        for m in REPEATS:
            motes = known.best(long, survey.sigma, m) if order == "best" else shuffled
            if order == "best":
                sel = [known.index(x) for x in motes[:10]]
                out[f"pred_tilt_std_best10_deg_{m}"] = float(np.rad2deg(np.sqrt(np.mean(
                    np.diag(known.tilt_covariance)[sel]))))
            for drift in (0.0, drift_deg):
                moved = heads["cam0"].copy()
                moved[0] += np.deg2rad(drift)
                monitor = DriftMonitor(known, survey.sigma)
                flagged, z10 = None, None
                for k, mote in enumerate(motes):
                    q = cam.rotation.T @ (truth.nodes[mote] - cam.position)
                    pan, tilt, _, _ = head_pan_tilt(q, moved, jacobians=False)
                    for _ in range(m):
                        check = monitor.add(mote, float(pan + rng.normal(0, survey.sigma)),
                                            float(tilt + rng.normal(0, survey.sigma)))
                    if check.drifted and flagged is None:
                        flagged = k + 1
                    if k + 1 == 10:
                        z10 = float(check.offset[1] / np.sqrt(check.covariance[1, 1]))
                    if flagged is not None and (drift or k + 1 >= long):
                        break
                out[f"{order}_{drift}_{m}"] = {"flagged_at": flagged, "z10": z10}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--drift-deg", type=float, default=0.1)
    ap.add_argument("--model", choices=("full", "auto"), default="full")
    ap.add_argument("--long", type=int, default=30, help="motes read in the no-drift runs (false alarms over more looks)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    jobs = [(s, a.drift_deg, a.model, a.long) for s in range(a.runs)]
    with ProcessPoolExecutor(a.workers) as pool:
        runs = list(pool.map(one_run, jobs, chunksize=4))
    summary: dict = {"runs": a.runs, "drift_deg": a.drift_deg, "model": a.model, "alpha": 0.01,
                     "pred_tilt_std_all_deg_median": float(np.median([r["pred_tilt_std_all_deg"] for r in runs]))}
    for m in REPEATS:
        summary[f"pred_tilt_std_best10_deg_median_{m}"] = float(np.median(
            [r[f"pred_tilt_std_best10_deg_{m}"] for r in runs]))
    for order in ORDERS:
        for m in REPEATS:
            hit = [r[f"{order}_{a.drift_deg}_{m}"]["flagged_at"] for r in runs]
            fa = [r[f"{order}_0.0_{m}"]["flagged_at"] for r in runs]
            z = np.array([r[f"{order}_0.0_{m}"]["z10"] for r in runs if r[f"{order}_0.0_{m}"]["z10"] is not None])
            within = [x for x in hit if x is not None and x <= 10]
            summary[f"{order}, {m} reading(s) per mote"] = {
                "detected_within_10": len(within) / len(runs),
                "median_motes_to_flag": float(np.median(within)) if within else None,
                "false_alarms_within_10_per_100": 100 * float(np.mean([x is not None and x <= 10 for x in fa])),
                f"false_alarms_within_{a.long}_per_100": 100 * float(np.mean([x is not None for x in fa])),
                "no_drift_z10_sd": float(np.std(z)) if len(z) else None,
                "no_drift_z10_mean": float(np.mean(z)) if len(z) else None,
            }
    if a.out:
        os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
        with open(a.out, "w") as f:
            json.dump({"summary": summary, "runs": runs}, f, indent=1)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
