"""Reproduction report: the paper's simulated experiment, baseline vs joint solve vs CRLB.

For every camera-height setting, seed and subset size k the simulator draws a
re-measured survey (``PaperScenario.subset_schedule``: T subsets of k nodes,
each read afresh by both cameras, T chosen so every node lies in about
``coverage`` subsets, i.e. the same measurement budget for every k). On that
one survey we run

* the paper's subset-averaging Newton baseline on each subset's own readings
  (:mod:`fgloc.baselines.subset_newton`),
* the joint factor-graph solve on all the same readings (:mod:`fgloc.solve.joint`),
* the Cramér-Rao bound of those readings (:mod:`fgloc.evaluate.crlb`), shown as the
  error distribution of an efficient estimator (per-node Gaussian draws).

Errors are Euclidean node errors on the paper's 100 m scale (baseline = 100 m).
matplotlib is imported lazily, only to draw the figures (``pip install fgloc[report]``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgloc.baselines.subset_newton import SubsetNewtonOptions, SubsetNewtonResult, solve_subset_newton
from fgloc.core.errors import FglocError
from fgloc.core.model import Result, Survey
from fgloc.core.subsets import subsets_for_coverage
from fgloc.evaluate.crlb import cramer_rao_bound
from fgloc.evaluate.report_figures import (
    figure_error_cdf,
    figure_joint_ellipses,
    figure_subset_scatter,
)
from fgloc.evaluate.score import PAPER_BASELINE_METRES
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey

logger = logging.getLogger(__name__)

PAPER_REFERENCE = (
    'R. Farrell, R. Garcia, D. Lucarelli, A. Terzis, I-J. Wang, "Target localization in camera '
    'wireless networks", Pervasive and Mobile Computing 5 (2009) 165-181'
)


@dataclass(frozen=True)
class ReportConfig:
    """The experiment grid. Heights are (h0, h1) in baselines; ``coverage`` is the
    number of subsets each node lies in (so T = coverage * n_nodes / k)."""

    n_nodes: int = 100
    sigma_deg: float = 0.1
    subset_sizes: tuple[int, ...] = (5, 10, 20, 50)
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
    heights: tuple[tuple[float, float], ...] = ((0.1, 0.1), (0.3, 0.3))
    coverage: float = 5.0
    crlb_draws: int = 200

    @classmethod
    def quick(cls) -> ReportConfig:
        """Small settings for tests: a few seconds."""
        return cls(n_nodes=40, subset_sizes=(5, 10), seeds=(0,), heights=((0.1, 0.1),), coverage=3.0, crlb_draws=50)


@dataclass
class RunRecord:
    """One (heights, seed, k) run; errors in baselines, NaN where unlocalized."""

    heights: tuple[float, float]
    seed: int
    k: int
    n_subsets: int
    baseline_errors: np.ndarray
    joint_errors: np.ndarray
    crlb_errors: np.ndarray  # efficient-estimator draws, (draws, N)
    crlb_rms: float
    failures: dict[str, int]
    baseline_seconds: float
    joint_seconds: float
    survey: Survey | None = None
    baseline: SubsetNewtonResult | None = None
    joint: Result | None = None


@dataclass
class ReportData:
    config: ReportConfig
    runs: list[RunRecord] = field(default_factory=list)
    seconds: float = 0.0


def _errors(survey: Survey, result: Result) -> np.ndarray:
    X = survey.truth_node_array()
    out = np.full(len(survey.node_ids), np.nan)
    for j, nid in enumerate(survey.node_ids):
        if nid in result.nodes:
            out[j] = np.linalg.norm(result.nodes[nid].position[:2] - X[j, :2])
    return out


def run_experiment(
    config: ReportConfig, keep_first: bool = True, progress: Callable[[int, int], None] | None = None
) -> ReportData:
    """Run every (heights, seed, k) of ``config``. Keeps full solutions for the first seed.

    ``progress(done, total)`` is called after each (heights, seed, k) run."""
    t0 = time.perf_counter()
    data = ReportData(config=config)
    total = len(config.heights) * len(config.seeds) * len(config.subset_sizes)
    for heights in config.heights:
        for seed in config.seeds:
            for k in config.subset_sizes:
                if k > config.n_nodes:
                    raise FglocError(f"report: subset size {k} exceeds {config.n_nodes} nodes")
                T = subsets_for_coverage(config.n_nodes, k, config.coverage)
                survey = paper_scenario(
                    PaperScenario(
                        n_nodes=config.n_nodes,
                        sigma=float(np.deg2rad(config.sigma_deg)),
                        heights=heights,
                        seed=seed,
                        subset_schedule=(k, T),
                    )
                )
                tb = time.perf_counter()
                base = solve_subset_newton(survey, SubsetNewtonOptions())
                tb = time.perf_counter() - tb
                tj = time.perf_counter()
                joint = solve_survey(survey)
                tj = time.perf_counter() - tj
                bound = cramer_rao_bound(survey)
                covs = np.array([bound[n] for n in survey.node_ids])
                rng = np.random.default_rng(10_000 + seed)
                L = np.linalg.cholesky(covs)
                draws = np.einsum("nij,dnj->dni", L, rng.normal(size=(config.crlb_draws, len(covs), 2)))
                keep = keep_first and seed == config.seeds[0]
                data.runs.append(
                    RunRecord(
                        heights=heights,
                        seed=seed,
                        k=k,
                        n_subsets=T,
                        baseline_errors=_errors(survey, base.result),
                        joint_errors=_errors(survey, joint),
                        crlb_errors=np.linalg.norm(draws, axis=2),
                        crlb_rms=float(np.sqrt(np.mean(np.trace(covs, axis1=1, axis2=2)))),
                        failures=base.failures,
                        baseline_seconds=tb,
                        joint_seconds=tj,
                        survey=survey if keep else None,
                        baseline=base if keep else None,
                        joint=joint if keep else None,
                    )
                )
                logger.debug(f"heights {heights}, seed {seed}, k {k}: baseline {tb:.2f} s, joint {tj:.2f} s")
                if progress is not None:
                    progress(len(data.runs), total)
    data.seconds = time.perf_counter() - t0
    return data


# ----------------------------------------------------------------------- tables


def _m(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{x * PAPER_BASELINE_METRES:.3f}"


def _stats(err: np.ndarray) -> tuple[float, float, float]:
    e = err[np.isfinite(err)]
    if e.size == 0:
        return float("nan"), float("nan"), float("nan")
    return float(np.median(e)), float(np.percentile(e, 95)), float(np.max(e))


def table1(data: ReportData, heights: tuple[float, float]) -> str:
    """Table 1, side by side, for one camera-height setting (errors in m at 100 m)."""
    lines = [
        "| k | T | paper 50% / 95% / max | baseline 50% / 95% / max | baseline failed subsets | baseline unlocalized nodes "
        "| baseline time (s/run) | joint 50% / 95% / max | joint time (s/run) | CRLB 50% / 95% | joint RMS / CRLB RMS |",
        "|---:|---:|---|---|---|---:|---:|---|---:|---|---:|",
    ]
    for k in data.config.subset_sizes:
        runs = [r for r in data.runs if r.heights == heights and r.k == k]
        b = np.concatenate([r.baseline_errors for r in runs])
        j = np.concatenate([r.joint_errors for r in runs])
        c = np.concatenate([r.crlb_errors.ravel() for r in runs])
        c_max = float(np.median([np.median(r.crlb_errors.max(axis=1)) for r in runs]))
        fails: dict[str, int] = {}
        for r in runs:
            for kind, v in r.failures.items():
                fails[kind] = fails.get(kind, 0) + v
        n_fail = sum(fails.values())
        detail = ", ".join(f"{kind} {v}" for kind, v in fails.items() if v)
        total = sum(r.n_subsets for r in runs)
        unloc = int(sum(np.isnan(r.baseline_errors).sum() for r in runs))
        j_rms = float(np.sqrt(np.nanmean(j**2)))
        c_rms = float(np.sqrt(np.mean([r.crlb_rms**2 for r in runs])))
        bs, js, cs = _stats(b), _stats(j), _stats(c)
        lines.append(
            f"| {k} | {runs[0].n_subsets} | not available | {_m(bs[0])} / {_m(bs[1])} / {_m(bs[2])} "
            f"| {n_fail}/{total}" + (f" ({detail})" if detail else "") + f" | {unloc} "
            f"| {np.mean([r.baseline_seconds for r in runs]):.2f} | {_m(js[0])} / {_m(js[1])} / {_m(js[2])} "
            f"| {np.mean([r.joint_seconds for r in runs]):.2f} | {_m(cs[0])} / {_m(cs[1])} (max ≈ {_m(c_max)}) "
            f"| {j_rms / c_rms:.2f} |"
        )
    return "\n".join(lines)


def per_seed_medians(data: ReportData) -> str:
    """Median node error per run: baseline vs joint on the same readings."""
    lines = [
        "| heights | k | seed | baseline median (m) | joint median (m) | baseline / joint |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in data.runs:
        b, j = np.nanmedian(r.baseline_errors), np.nanmedian(r.joint_errors)
        lines.append(f"| {r.heights[0]:g}, {r.heights[1]:g} | {r.k} | {r.seed} | {_m(b)} | {_m(j)} | {b / j:.2f} |")
    return "\n".join(lines)


def joint_efficiency(data: ReportData, heights: tuple[float, float]) -> tuple[float, float, int]:
    """Joint RMS error / CRLB RMS pooled over every run at ``heights``, its standard
    error, and the number of runs.

    Node errors within one run are strongly correlated (they share the camera pose
    errors), so the ratio is estimated from per-run mean squared error ratios and its
    standard error from their scatter across runs (delta method for the square root).
    """
    runs = [r for r in data.runs if r.heights == heights]
    ratios = np.array([np.nanmean(r.joint_errors**2) / r.crlb_rms**2 for r in runs])
    mean = float(np.mean(ratios))
    se = float(np.std(ratios, ddof=1) / np.sqrt(len(ratios))) if len(ratios) > 1 else float("nan")
    return float(np.sqrt(mean)), se / (2.0 * np.sqrt(mean)), len(runs)


@dataclass(frozen=True)
class Acceptance:
    baseline_never_better: bool  # pooled median over seeds, every (heights, k)
    min_pooled_ratio: float
    runs_baseline_better: int  # single runs where the baseline's median beat the joint's
    n_runs: int
    min_median_ratio: float  # over single runs
    worst_joint_crlb_ratio: float
    trend_ok: bool
    failures_small_k: int
    failures_large_k: int


def acceptance(data: ReportData) -> Acceptance:
    """The issue's acceptance checks, computed from the runs."""
    ratios = [np.nanmedian(r.baseline_errors) / np.nanmedian(r.joint_errors) for r in data.runs]
    pooled = []
    for h in data.config.heights:
        for k in data.config.subset_sizes:
            runs = [r for r in data.runs if r.heights == h and r.k == k]
            b = np.nanmedian(np.concatenate([r.baseline_errors for r in runs]))
            pooled.append(float(b / np.nanmedian(np.concatenate([r.joint_errors for r in runs]))))
    jc = []
    trend = True
    ks = data.config.subset_sizes
    for h in data.config.heights:
        meds = []
        for k in ks:
            runs = [r for r in data.runs if r.heights == h and r.k == k]
            meds.append(float(np.nanmedian(np.concatenate([r.baseline_errors for r in runs]))))
        trend &= all(a >= b for a, b in zip(meds, meds[1:]))
        jc.append(joint_efficiency(data, h)[0])
    small = sum(sum(r.failures.values()) for r in data.runs if r.k == ks[0])
    large = sum(sum(r.failures.values()) for r in data.runs if r.k == ks[-1])
    return Acceptance(
        baseline_never_better=bool(min(pooled) >= 1.0),
        min_pooled_ratio=float(min(pooled)),
        runs_baseline_better=int(sum(r < 1.0 for r in ratios)),
        n_runs=len(ratios),
        min_median_ratio=float(min(ratios)),
        worst_joint_crlb_ratio=float(max(jc, key=lambda x: abs(x - 1.0))),
        trend_ok=bool(trend),
        failures_small_k=small,
        failures_large_k=large,
    )


# ----------------------------------------------------------------------- figures


def _discussion(data: ReportData, acc: Acceptance) -> str:
    ks = data.config.subset_sizes
    h0 = data.config.heights[0]

    def med(k: int, which: str, h=h0) -> float:
        runs = [r for r in data.runs if r.heights == h and r.k == k]
        return float(np.nanmedian(np.concatenate([getattr(r, which) for r in runs])))

    steep = " → ".join(f"{_m(med(k, 'baseline_errors'))}" for k in ks)
    joint = " → ".join(f"{_m(med(k, 'joint_errors'))}" for k in ks)
    return f"""\
**Paper's numbers.** The paper is {PAPER_REFERENCE}. Its abstract reports that two cameras
localize motes in a 100 m × 100 m area "with a few cm error". We could not obtain the text of
its Table 1 (our search reached only the abstract), so the "paper" column says *not available*:
no published number is quoted or guessed here.

**Trend.** At heights {h0[0]:g}, {h0[1]:g} baselines the baseline's median error over k = {', '.join(map(str, ks))}
is {steep} m: {'it falls steeply from the smallest k and flattens toward the largest' if acc.trend_ok else 'it does NOT fall monotonically in every height setting here'}
(the trend the issue attributes to the paper; we could not check it against the paper's table).
Small subsets fail more: {acc.failures_small_k} failed subsets at k = {ks[0]} against {acc.failures_large_k} at k = {ks[-1]}
(all heights and seeds). A subset of k nodes has 4k readings for 8 + 2k unknowns: at k = 5 only 2
redundant equations, so the camera rotations are barely determined; from a level-camera guess the
Newton iteration sometimes cannot settle (counted as failures), and the subsets that do converge
give heavy-tailed node solutions (nearly singular subsets are off by metres to tens of metres), so a
mean of about {data.config.coverage:g} of them is pulled by the worst one. Larger subsets pin the
cameras better, each subset's solution approaches the joint one, and the gain flattens.

**Baseline vs joint on the same readings.** The joint solve uses every reading at once
({joint} m median over the same k schedules). Pooled over the seeds, the baseline's median error was
{'never lower than' if acc.baseline_never_better else 'NOT always above'} the joint solve's for any height and k (smallest
ratio {acc.min_pooled_ratio:.2f}). In single runs it was lower in {acc.runs_baseline_better} of {acc.n_runs}
(smallest ratio {acc.min_median_ratio:.2f}): with large subsets the baseline is nearly efficient, and one
run's median is dominated by that run's shared camera-pose errors, so single runs scatter around a
ratio a little above 1; the joint solve is better on average, not in every realization. The joint
solve is within {100 * abs(acc.worst_joint_crlb_ratio - 1):.1f}% of the Cramér-Rao bound in RMS error
(worst ratio {acc.worst_joint_crlb_ratio:.3f}; the acceptance asks for 10%). The baseline's gap to the
joint solve is the price of estimating the cameras T times from small, separate pieces of data and
averaging node positions, instead of combining the information of all readings in one estimate.

**The paper's "few cm".** Here even the bound (an efficient estimator with these readings) has a
median error of several cm (see the CRLB column), so "a few cm" needs a setup we do not know:
higher cameras, more readings per node, or less noise than σ = {data.config.sigma_deg:g}°.

**Why absolute numbers may differ from the paper.** (1) Camera heights: error grows quickly
as cameras get lower (grazing rays); the paper's heights are not known to us, so we show
{len(data.config.heights)} settings. (2) Re-measurement budget: here each node lies in about
{data.config.coverage:g} subsets and is read afresh in each; the paper's T is not known to us.
(3) Initial guess: ours is level cameras with a 5° yaw grid search from the pans (see
docs/baseline.md); the paper's guess is not known to us, and failures at small k depend on it.
(4) Camera bases here have up to 3° random roll/pitch.
"""


def write_report(data: ReportData, out_dir: Path) -> Path:
    """Write report.md and the PNGs into ``out_dir``; returns the report path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    figure_error_cdf(data, out_dir / "fig6_error_cdf.png")
    first = [r for r in data.runs if r.survey is not None and r.heights == data.config.heights[0]]
    shown = {}
    for r in first:
        name = f"fig4_subset_scatter_k{r.k}.png"
        figure_subset_scatter(r, out_dir / name)
        shown[r.k] = name
    figure_joint_ellipses(first[-1], out_dir / "fig7_joint_ellipses.png")
    acc = acceptance(data)
    cfg = data.config
    parts = [
        "# Reproduction report: subset-averaging Newton (the paper) vs joint factor-graph solve",
        "",
        f"Experiment: {cfg.n_nodes} nodes uniform in the unit square, two cameras above (0, 0) and (1, 0),"
        f" σ = {cfg.sigma_deg:g}° on pan and tilt, subset sizes k = {', '.join(map(str, cfg.subset_sizes))},"
        f" seeds {', '.join(map(str, cfg.seeds))}, each node in about {cfg.coverage:g} subsets (T = coverage·N/k),"
        f" every subset re-measured. Errors in metres for a 100 m baseline. Total run time {data.seconds:.1f} s.",
        "",
        "Regenerate: `fgloc report -o report-dir/` (add `--quick` for the small test settings).",
        "",
        "## Acceptance summary",
        "",
        f"- baseline never better than joint in median error over the seeds (every height and k):"
        f" **{acc.baseline_never_better}** (smallest baseline/joint ratio of pooled medians {acc.min_pooled_ratio:.2f});"
        f" in single runs the baseline's median was lower in {acc.runs_baseline_better} of {acc.n_runs}"
        f" (smallest single-run ratio {acc.min_median_ratio:.2f})",
        f"- joint RMS error / CRLB RMS, worst over height settings: **{acc.worst_joint_crlb_ratio:.3f}**"
        " (pooled over seeds and k; per height: "
        + "; ".join(
            f"{h[0]:g}, {h[1]:g}: {e:.3f} ± {se:.3f} over {n} runs"
            for h in cfg.heights
            for e, se, n in [joint_efficiency(data, h)]
        )
        + ")",
        f"- baseline median falls monotonically with k in every height setting: **{acc.trend_ok}**",
        f"- failed subsets at k = {cfg.subset_sizes[0]}: {acc.failures_small_k}; at k = {cfg.subset_sizes[-1]}: {acc.failures_large_k}",
        "",
        "## Table 1, side by side",
        "",
        "Errors: 50th percentile / 95th percentile / max over all nodes of all seeds. *CRLB*: the error"
        " distribution an efficient estimator would attain (Gaussian draws from each node's bound; max ="
        " median over draws of the per-draw maximum). *Paper*: not available (see discussion).",
    ]
    for h in cfg.heights:
        parts += ["", f"### camera heights {h[0]:g}, {h[1]:g} baselines ({h[0] * 100:g} m, {h[1] * 100:g} m)", "",
                  table1(data, h)]
    parts += [
        "",
        "## Figures",
        "",
        "Error distributions (Figure 6 style; solid: baseline, dashed: joint, dotted: CRLB):",
        "",
        "![error CDF](fig6_error_cdf.png)",
        "",
    ]
    for k, name in shown.items():
        parts += [f"Subset solutions, mean and 95% ellipses, with the joint estimate (k = {k}):", "", f"![k={k}]({name})", ""]
    parts += ["Joint solve over the whole field with its 95% covariance ellipses:", "", "![joint](fig7_joint_ellipses.png)", ""]
    parts += ["## Discussion", "", _discussion(data, acc), "## Per-run medians", "", per_seed_medians(data), ""]
    path = out_dir / "report.md"
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text("\n".join(parts), encoding="utf-8")
    tmp.replace(path)
    return path
