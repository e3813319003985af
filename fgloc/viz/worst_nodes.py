"""The worst nodes: by true error when there is truth, else by the size of their
confidence region; as rows, as a markdown table, and logged at ``report/worst_nodes``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun as rr

from fgloc.core.confidence import DEFAULT_CONFIDENCE, confidence_ellipsoids
from fgloc.core.model import Result, Survey
from fgloc.viz.arrays import node_arrays
from fgloc.viz.style import VizOptions, time_kwargs


@dataclass(frozen=True)
class WorstNode:
    """One row of the worst-nodes table (lengths in gauge units)."""

    node: str
    error: float  # |estimate - truth|, NaN without truth
    nees: float  # e^T C^-1 e, NaN without truth
    major_half_axis: float  # of the confidence region


def worst_nodes(result: Result, survey: Survey | None = None, count: int = 10,
                confidence: float = DEFAULT_CONFIDENCE) -> list[WorstNode]:
    """The ``count`` worst nodes: by true error when the survey has truth, else by the
    major half axis of their confidence region."""
    nodes = node_arrays(result, survey)
    if not nodes.ids:
        return []
    ell = confidence_ellipsoids(nodes.covariances, confidence)
    major = np.full(len(nodes.ids), np.nan)
    finite = np.isfinite(ell.half_sizes).all(axis=1)
    major[finite] = ell.half_sizes[finite].max(axis=1)
    error = np.full(len(nodes.ids), np.nan)
    nees = np.full(len(nodes.ids), np.nan)
    if survey is not None and survey.truth is not None:
        d = result.mode.position_dim
        for j, n in enumerate(nodes.ids):
            if n in survey.truth.nodes:
                e = nodes.positions[j] - np.asarray(survey.truth.nodes[n], float)
                error[j] = float(np.linalg.norm(e))
                try:
                    nees[j] = float(e[:d] @ np.linalg.solve(nodes.covariances[j], e[:d]))
                except np.linalg.LinAlgError:
                    pass
    key = error if np.isfinite(error).any() else major
    order = np.argsort(np.where(np.isfinite(key), -key, np.inf), kind="stable")[:count]
    return [WorstNode(nodes.ids[j], float(error[j]), float(nees[j]), float(major[j])) for j in order]


def worst_nodes_markdown(rows: list[WorstNode], confidence: float = DEFAULT_CONFIDENCE) -> str:
    """The worst-nodes table as markdown (lengths in gauge units x 1000, i.e. mm per metre of baseline)."""
    if not rows:
        return "No localized nodes."
    by_truth = np.isfinite(rows[0].error)
    head = "Worst nodes by true error" if by_truth else f"Least certain nodes (largest {100 * confidence:g}% axis)"
    lines = [f"### {head}", "",
             f"Lengths in 1/1000 of the baseline. Orange: estimate, green: truth, magenta: error, "
             f"cyan: {100 * confidence:g}% region (true scale: see the close-up), red rays: flagged outliers.", "",
             f"| node | error | NEES | {100 * confidence:g}% major axis |", "|---|---:|---:|---:|"]
    for r in rows:
        err = f"{1000 * r.error:.2f}" if np.isfinite(r.error) else "-"
        nees = f"{r.nees:.1f}" if np.isfinite(r.nees) else "-"
        lines.append(f"| {r.node} | {err} | {nees} | {1000 * r.major_half_axis:.2f} |")
    return "\n".join(lines)


def log_worst_nodes(rec: rr.RecordingStream, result: Result, survey: Survey | None = None,
                    options: VizOptions = VizOptions(), static: bool = True) -> list[WorstNode]:
    """The worst-nodes table as a markdown TextDocument at ``report/worst_nodes``."""
    rows = worst_nodes(result, survey, options.worst_nodes, options.confidence)
    rec.log("report/worst_nodes", rr.TextDocument(worst_nodes_markdown(rows, options.confidence),
                                                  media_type=rr.MediaType.MARKDOWN), **time_kwargs(static))
    return rows
