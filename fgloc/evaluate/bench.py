"""The benchmark suite: every method on every scene, side by side in one run.

Each (scene, method) runs in its own subprocess (``python -m fgloc.evaluate.bench
--worker ...``) so that its peak memory (``ru_maxrss``, which includes the
interpreter and the imported libraries) belongs to that method alone. Inside
the worker the method runs ``repeats`` times on the same survey and every
stage reports its median. Ratios compare medians measured in the same run.

Output (``fgloc bench``): a Markdown table (stdout) and, with ``--json``, the raw numbers.
The growth of each stage with the number of nodes n is fitted as a log-log
slope over the scenes with the same number of cameras (1 = linear).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

logger = logging.getLogger(__name__)

STAGES = ("build", "initialize", "optimize", "marginals")  # plus "other" for fgloc (flagging, assembly)
FULL_CASES = [(100, 2), (100, 8), (1000, 2), (1000, 8), (10000, 2), (10000, 8), (100000, 8)]
#: The plain C++ pipeline every other row is compared with (solve time excluding the shared start).
BASELINE = "gtsam_cpp"
#: Largest scene per method (more nodes: skipped, minutes per run or no point).
MAX_NODES = {"fgloc_reference": 10000, "gtsam_cpp": 10000, "scipy": 1000}
QUICK_CASES = [(40, 2), (80, 2), (60, 4)]


@dataclass
class CaseResult:
    """Medians of one method on one scene."""

    n_nodes: int
    n_cameras: int
    method: str
    n_observations: int
    repeats: int
    available: bool
    note: str
    stage_median_s: dict[str, float] = field(default_factory=dict)
    total_median_s: float = float("nan")
    #: Median wall time without the closed-form start (``initialize``), the shared part.
    solve_median_s: float = float("nan")
    iterations: int = 0
    final_cost: float = float("nan")
    peak_rss_mb: float = float("nan")
    max_position_diff_vs_fgloc: float = float("nan")


def _worker(n_nodes: int, n_cameras: int, method: str, repeats: int, seed: int) -> dict:
    from fgloc.evaluate.bench_methods import RUNNERS
    from fgloc.sim.bench_scenes import BenchScene, scene_survey

    survey = scene_survey(BenchScene(n_nodes, n_cameras, seed=seed))
    runs = [RUNNERS[method](survey)]
    # Peak memory of one solve (imports, survey and that solve): read before the
    # timing repeats, which only add allocator fragmentation.
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    runs += [RUNNERS[method](survey) for _ in range(repeats - 1)]
    last = runs[-1]
    stages = {k: float(np.median([r.stage_seconds[k] for r in runs])) for k in last.stage_seconds}
    totals = [r.total_seconds for r in runs]
    solves = [r.total_seconds - r.stage_seconds.get("initialize", 0.0) for r in runs]
    return {
        "n_observations": len(survey.observations),
        "available": last.available,
        "note": last.note,
        "stage_median_s": stages,
        "total_median_s": float(np.median(totals)) if last.available else float("nan"),
        "solve_median_s": float(np.median(solves)) if last.available else float("nan"),
        "iterations": last.iterations,
        "final_cost": last.final_cost,
        "positions": np.nan_to_num(last.positions, nan=1e300).tolist(),
        "peak_rss_mb": peak_mb,
    }


def _incremental_worker(n_nodes: int, n_cameras: int, new_nodes: int, batch_nodes: int, active_nodes: int, seed: int) -> dict:
    """iSAM2: bootstrap on all but ``new_nodes`` nodes, then time adding them one node (all its readings) at a time.

    ``active_nodes`` <= 0 keeps every node an iSAM2 variable (no marginalization)."""
    from fgloc.sim.bench_scenes import BenchScene, scene_survey
    from fgloc.solve.incremental import IncrementalLocalizer, IncrementalParams

    survey = scene_survey(BenchScene(n_nodes, n_cameras, seed=seed))
    by_node: dict[str, list] = {}
    for o in survey.observations:
        by_node.setdefault(o.node, []).append(o)
    loc = IncrementalLocalizer(
        survey.camera_ids,
        survey.gauge,
        survey.sigma,
        IncrementalParams(batch_nodes=batch_nodes, active_nodes=active_nodes if active_nodes > 0 else None),
    )
    t0 = time.perf_counter()
    loc.add_observations([o for nid in survey.node_ids[:-new_nodes] for o in by_node[nid]])
    bootstrap = time.perf_counter() - t0
    per_node = []
    for nid in survey.node_ids[-new_nodes:]:
        t0 = time.perf_counter()
        loc.add_observations(by_node[nid])
        per_node.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    loc.estimate(covariances=False)
    t_est = time.perf_counter() - t0
    t0 = time.perf_counter()
    loc.estimate(covariances=True)
    t_cov = time.perf_counter() - t0
    u = np.array(per_node)
    return {
        "n_nodes": n_nodes,
        "n_cameras": n_cameras,
        "batch_nodes": batch_nodes,
        "active_nodes": active_nodes if active_nodes > 0 else None,
        "new_nodes": new_nodes,
        "bootstrap_s": bootstrap,
        "update_median_s": float(np.median(u)),
        "update_p95_s": float(np.percentile(u, 95)),
        "update_max_s": float(u.max()),
        "update_mean_s": float(u.mean()),
        "estimate_s": t_est,
        "estimate_with_covariances_s": t_cov,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def run_incremental(
    n_nodes: int, n_cameras: int, new_nodes: int, batch_nodes: int, active_nodes: int | None, seed: int = 0
) -> dict:
    """One iSAM2 timing case in a fresh subprocess (``active_nodes`` None: every node stays a variable)."""
    spec = f"{n_nodes},{n_cameras},{new_nodes},{batch_nodes},{active_nodes or 0},{seed}"
    cmd = [sys.executable, "-m", "fgloc.evaluate.bench", "--incremental-worker", spec]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"incremental benchmark worker failed: {' '.join(cmd)}\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def incremental_markdown(rows: list[dict]) -> str:
    """The iSAM2 timings as a Markdown table."""
    lines = [
        "| nodes x cams | nodes kept in iSAM2 | nodes per update | per new node: median | mean | p95 | max | estimate() | with all covariances | bootstrap |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['n_nodes']} x {r['n_cameras']} | {r['active_nodes'] or 'all'} | {r['batch_nodes']} | "
            f"{_fmt_s(r['update_median_s'])} | "
            f"{_fmt_s(r['update_mean_s'])} | {_fmt_s(r['update_p95_s'])} | {_fmt_s(r['update_max_s'])} | "
            f"{_fmt_s(r['estimate_s'])} | {_fmt_s(r['estimate_with_covariances_s'])} | {_fmt_s(r['bootstrap_s'])} |"
        )
    return "\n".join(lines)


def run_case(n_nodes: int, n_cameras: int, method: str, repeats: int, seed: int = 0) -> tuple[CaseResult, np.ndarray]:
    """Run one (scene, method) in a fresh subprocess; returns medians and final node positions."""
    cmd = [sys.executable, "-m", "fgloc.evaluate.bench", "--worker", f"{n_nodes},{n_cameras},{method},{repeats},{seed}"]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"benchmark worker failed: {' '.join(cmd)}\n{out.stderr[-2000:]}")
    data = json.loads(out.stdout.strip().splitlines()[-1])
    positions = np.array(data.pop("positions"))
    positions[positions > 1e299] = np.nan
    return CaseResult(n_nodes=n_nodes, n_cameras=n_cameras, method=method, repeats=repeats, **data), positions


def repeats_for(method: str, n_nodes: int, quick: bool) -> int:
    """Repeats per case: fewer for slow cases (scipy takes tens of seconds at 1,000 x 8)."""
    if quick:
        return 2 if method != "scipy" else 1
    if method == "scipy":
        return 3 if n_nodes <= 100 else 1
    return 7 if n_nodes <= 100 else (5 if n_nodes <= 1000 else (3 if n_nodes <= 10000 else 1))


def loglog_slopes(results: list[CaseResult], method: str = "fgloc") -> dict[str, dict[str, float]]:
    """Slope of log(stage median) against log(n) per camera count (1.0 = linear growth)."""
    slopes: dict[str, dict[str, float]] = {}
    for n_cam in sorted({r.n_cameras for r in results}):
        rows = sorted((r for r in results if r.method == method and r.n_cameras == n_cam and r.available), key=lambda r: r.n_nodes)
        if len({r.n_nodes for r in rows}) < 2:
            continue
        per: dict[str, float] = {}
        for stage in STAGES + ("total",):
            xs, ys = [], []
            for r in rows:
                v = r.total_median_s if stage == "total" else r.stage_median_s.get(stage, np.nan)
                if np.isfinite(v) and v > 0:
                    xs.append(np.log(r.n_nodes))
                    ys.append(np.log(v))
            if len(xs) >= 2:
                per[stage] = float(np.polyfit(xs, ys, 1)[0])
        slopes[f"{n_cam} cameras"] = per
    return slopes


def _fmt_s(v: float) -> str:
    if not np.isfinite(v):
        return "-"
    return f"{v * 1e3:.1f} ms" if v < 1.0 else f"{v:.2f} s"


def markdown(results: list[CaseResult], slopes: dict[str, dict[str, float]], skipped: list[str]) -> str:
    """The benchmark as Markdown tables."""
    lines = [
        "| scene (nodes x cams) | obs | method | start | build | optimize (iters) | per iter | marginals | other "
        f"| solve excl. start | vs {BASELINE} | final cost | peak RSS |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    base = {(r.n_nodes, r.n_cameras): r for r in results if r.method == BASELINE and r.available}
    for r in results:
        if not r.available:
            lines.append(f"| {r.n_nodes} x {r.n_cameras} | {r.n_observations} | {r.method} | {r.note} |||||||||| ")
            continue
        s = r.stage_median_s
        ref = base.get((r.n_nodes, r.n_cameras))
        ratio = r.solve_median_s / ref.solve_median_s if ref else float("nan")
        lines.append(
            f"| {r.n_nodes} x {r.n_cameras} | {r.n_observations} | {r.method} | {_fmt_s(s.get('initialize', np.nan))} | "
            f"{_fmt_s(s.get('build', np.nan))} | {_fmt_s(s.get('optimize', np.nan))} ({r.iterations}) | "
            f"{_fmt_s(s.get('optimize', np.nan) / max(r.iterations, 1))} | "
            f"{_fmt_s(s.get('marginals', np.nan))} | {_fmt_s(s.get('other', np.nan))} | {_fmt_s(r.solve_median_s)} | "
            f"{ratio:.2f}x | {r.final_cost:.6f} | "
            f"{r.peak_rss_mb:.0f} MB |"
        )
    for skip in skipped:
        lines.append(f"\nSkipped: {skip}")
    lines += ["", "Growth with n (log-log slope of the fgloc stage medians; 1.0 = linear):", ""]
    lines += ["| cameras | " + " | ".join(STAGES) + " | total |", "|---" * (len(STAGES) + 2) + "|"]
    for cams, per in slopes.items():
        lines.append(f"| {cams} | " + " | ".join(f"{per.get(k, np.nan):.2f}" for k in STAGES + ("total",)) + " |")
    return "\n".join(lines)


def suite_steps(cases: list[tuple[int, int]], methods: list[str]) -> int:
    """How many (case, method) steps :func:`run_suite` reports (skipped ones included)."""
    return len(cases) * len(methods)


def run_suite(
    cases: list[tuple[int, int]],
    methods: list[str],
    quick: bool,
    scipy_max_nodes: int,
    progress: Callable[[int, int], None] | None = None,
    steps_total: int | None = None,
) -> dict:
    """Every method on every case; returns the JSON-ready report.

    ``progress(done, total)`` is called after each (case, method), skipped ones included;
    ``total`` is ``steps_total`` when given (a caller with more steps to come), else
    :func:`suite_steps`."""
    results: list[CaseResult] = []
    skipped: list[str] = []
    total = steps_total if steps_total is not None else suite_steps(cases, methods)
    done = 0
    for n, c in cases:
        ref_positions = None
        for method in methods:
            done += 1
            limit = scipy_max_nodes if method == "scipy" else MAX_NODES.get(method)
            if limit is not None and n > limit:
                skipped.append(f"{method} at {n} x {c} (above {limit} nodes; minutes per run)")
            elif method == "subset_newton" and c != 2:
                pass
            else:
                res, pos = run_case(n, c, method, repeats_for(method, n, quick))
                if method == "fgloc":
                    ref_positions = pos
                elif ref_positions is not None and res.available:
                    res.max_position_diff_vs_fgloc = float(np.nanmax(np.abs(pos - ref_positions)))
                results.append(res)
                logger.info(f"{n} x {c} {method}: total {_fmt_s(res.total_median_s)}")
            if progress is not None:
                progress(done, total)
    slopes = loglog_slopes(results)
    return {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()},
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "quick": quick,
        "results": [asdict(r) for r in results],
        "slopes": slopes,
        "skipped": skipped,
        "markdown": markdown(results, slopes, skipped),
    }


def run_benchmark(
    cases: list[tuple[int, int]],
    methods: list[str],
    quick: bool,
    scipy_max_nodes: int,
    incremental_cases: list[tuple[int, int]],
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """The whole benchmark: :func:`run_suite`, then the iSAM2 timings of ``incremental_cases``
    (the default node window against every node kept, side by side), in the report's
    ``incremental`` rows and Markdown. ``progress(done, total)`` after every step."""
    from fgloc.solve.incremental import IncrementalParams

    windows = (IncrementalParams().active_nodes, None)
    total = suite_steps(cases, methods) + len(incremental_cases) * len(windows)
    report = run_suite(cases, methods, quick, scipy_max_nodes, progress=progress, steps_total=total)
    done = suite_steps(cases, methods)
    inc_rows = []
    for n, c in incremental_cases:
        for active in windows:
            row = run_incremental(n, c, new_nodes=20 if quick else 100, batch_nodes=1, active_nodes=active)
            inc_rows.append(row)
            done += 1
            logger.info(f"iSAM2 {n} x {c} active {active or 'all'} done")
            if progress is not None:
                progress(done, total)
    report["incremental"] = inc_rows
    if inc_rows:
        report["markdown"] += "\n\niSAM2 (IncrementalLocalizer), new nodes added one at a time after a batch bootstrap:\n\n"
        report["markdown"] += incremental_markdown(inc_rows)
    return report


def json_safe(obj: Any) -> Any:
    """NaN / inf become null (strict JSON): the report as ``--json`` writes it."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [json_safe(v) for v in obj]
    return obj


def parse_cases(text: str) -> list[tuple[int, int]]:
    """``100x2,1000x8`` as [(100, 2), (1000, 8)]."""
    from fgloc.core.errors import FglocError

    cases = []
    for item in text.split(","):
        try:
            n, c = item.lower().split("x")
            cases.append((int(n), int(c)))
        except ValueError:
            raise FglocError(f"--cases: expected NODESxCAMERAS like 100x2, got {item!r}") from None
    return cases


def worker_main(argv: list[str] | None = None) -> int:
    """``python -m fgloc.evaluate.bench --worker N,C,METHOD,REPEATS,SEED`` (or
    ``--incremental-worker N,C,NEW,BATCH,ACTIVE,SEED``): one measurement in this fresh
    process, written to stdout as one JSON line for the parent (:func:`run_case`)."""
    p = argparse.ArgumentParser(prog="python -m fgloc.evaluate.bench", description="one benchmark worker")
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--worker")
    group.add_argument("--incremental-worker")
    args = p.parse_args(argv)
    if args.incremental_worker:
        n, c, k, b, a, seed = (int(v) for v in args.incremental_worker.split(","))
        data = _incremental_worker(n, c, k, b, a, seed)
    else:
        n, c, method, repeats, seed = args.worker.split(",")
        data = _worker(int(n), int(c), method, int(repeats), int(seed))
    sys.stdout.write(json.dumps(data) + "\n")  # the protocol with the parent, not a message
    return 0


if __name__ == "__main__":
    sys.exit(worker_main())
