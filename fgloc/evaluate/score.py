"""Score a result against a simulated survey's truth.

Errors are Euclidean distances in the gauge frame (baseline = 1) and, for the
paper's presentation, in metres for a 100 m baseline. Consistency is the
normalized estimation error squared, ``NEES = e^T C^-1 e``, chi-square with 2
(planar) or 3 (3d) degrees of freedom when the covariance is honest: ANEES is
its mean (expect 2 or 3), and a share of about 95% of nodes should fall inside
their 95% ellipse.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.model import NodeMode, Result, Survey

PAPER_BASELINE_METRES = 100.0

#: chi-square 95% quantiles for 2 and 3 degrees of freedom.
CHI2_95 = {2: 5.991464547107979, 3: 7.814727903251178}


@dataclass(frozen=True)
class Score:
    """Summary of per-node errors; lengths in gauge units unless named ``_m``."""

    n_nodes: int
    median: float
    p95: float
    max: float
    rms: float
    median_m: float
    p95_m: float
    max_m: float
    rms_m: float
    anees: float
    inside_95: float  # share of nodes inside their 95% ellipse / ellipsoid
    dof: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def node_errors(survey: Survey, result: Result) -> tuple[list[str], np.ndarray]:
    """Ids of nodes with both truth and an estimate, and their error vectors (K, 3)."""
    if survey.truth is None:
        raise FglocError("survey has no truth to score against")
    ids = [n for n in survey.node_ids if n in result.nodes and n in survey.truth.nodes]
    if not ids:
        raise FglocError("no node has both an estimate and a true position")
    err = np.array([result.nodes[n].position - survey.truth.nodes[n] for n in ids])
    return ids, err


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``e^T C^-1 e`` per node for errors (K, d) and covariances (K, d, d)."""
    return np.einsum("ki,ki->k", errors, np.linalg.solve(covariances, errors[..., None])[..., 0])


def score(survey: Survey, result: Result, baseline_m: float = PAPER_BASELINE_METRES) -> Score:
    """Per-node error statistics and covariance consistency (``baseline_m`` > 0, finite)."""
    if not (np.isfinite(baseline_m) and baseline_m > 0):
        raise FglocError(f"baseline length must be a finite number of metres > 0, got {baseline_m!r}")
    if result.mode is not survey.mode:
        raise FglocError(f"a {result.mode.value} result cannot be scored against a {survey.mode.value} survey")
    ids, err = node_errors(survey, result)
    dof = 2 if result.mode is NodeMode.PLANAR else 3
    dist = np.linalg.norm(err, axis=1)
    cov = np.array([result.nodes[n].covariance for n in ids])
    if np.all(np.isfinite(cov)):
        values = nees(err[:, :dof], cov)
        anees, inside = float(np.mean(values)), float(np.mean(values <= CHI2_95[dof]))
    else:
        anees, inside = float("nan"), float("nan")
    med, p95, mx = (float(v) for v in (np.median(dist), np.percentile(dist, 95), np.max(dist)))
    rms = float(np.sqrt(np.mean(dist**2)))
    return Score(
        n_nodes=len(ids),
        median=med,
        p95=p95,
        max=mx,
        rms=rms,
        median_m=med * baseline_m,
        p95_m=p95 * baseline_m,
        max_m=mx * baseline_m,
        rms_m=rms * baseline_m,
        anees=anees,
        inside_95=inside,
        dof=dof,
    )


def format_score_table(s: Score, baseline_m: float = PAPER_BASELINE_METRES) -> str:
    """A small Markdown table for people."""
    lines = [
        f"| node error ({s.n_nodes} nodes) | normalized | metres at {baseline_m:g} m baseline |",
        "|---|---:|---:|",
        f"| median | {s.median:.3e} | {s.median_m:.3f} |",
        f"| 95th percentile | {s.p95:.3e} | {s.p95_m:.3f} |",
        f"| max | {s.max:.3e} | {s.max_m:.3f} |",
        f"| RMS | {s.rms:.3e} | {s.rms_m:.3f} |",
        "",
        f"ANEES {s.anees:.2f} (expect about {s.dof}); {100 * s.inside_95:.0f}% of nodes inside their 95% "
        f"{'ellipse' if s.dof == 2 else 'ellipsoid'} (expect about 95%)",
    ]
    return "\n".join(lines)
