"""Figures of the reproduction report (matplotlib, imported only when drawing).

Error CDFs (paper Fig. 6), subset-solution scatter (Fig. 4) and the joint solve's
95 % ellipses (Fig. 7). Errors in metres at the paper's 100 m baseline.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.evaluate.score import CHI2_95, PAPER_BASELINE_METRES

if TYPE_CHECKING:
    from fgloc.evaluate.report import ReportData, RunRecord

def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise FglocError("report: matplotlib is not installed: pip install fgloc[report]") from None
    return plt


def require_matplotlib() -> None:
    """Fail early, before the experiment runs, if the plots cannot be drawn."""
    _pyplot()


def _ellipse(ax, center: np.ndarray, cov: np.ndarray, scale: float = 1.0, **kw) -> None:
    vals, vecs = np.linalg.eigh(cov)
    r = np.sqrt(CHI2_95[2] * np.maximum(vals, 0.0)) * scale
    t = np.linspace(0, 2 * np.pi, 100)
    pts = center[:, None] + vecs @ (r[:, None] * np.vstack([np.cos(t), np.sin(t)]))
    ax.plot(pts[0], pts[1], **kw)


def figure_error_cdf(data: ReportData, path: Path) -> None:
    """Figure 6 style: CDF of node errors for every method and k, one panel per height."""
    plt = _pyplot()
    hs = data.config.heights
    fig, axes = plt.subplots(1, len(hs), figsize=(6.5 * len(hs), 4.8), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, h in zip(axes[0], hs):
        for i, k in enumerate(data.config.subset_sizes):
            runs = [r for r in data.runs if r.heights == h and r.k == k]
            for errs, style, name in (
                (np.concatenate([r.baseline_errors for r in runs]), "-", "baseline"),
                (np.concatenate([r.joint_errors for r in runs]), "--", "joint"),
                (np.concatenate([r.crlb_errors.ravel() for r in runs]), ":", "CRLB"),
            ):
                e = np.sort(errs[np.isfinite(errs)]) * PAPER_BASELINE_METRES
                ax.plot(e, np.arange(1, e.size + 1) / e.size, style, color=colors[i % len(colors)],
                        label=f"{name}, k={k}")
        ax.set_xscale("log")
        ax.set_xlabel("node error (m, 100 m baseline)")
        ax.set_ylabel("fraction of nodes")
        ax.set_title(f"camera heights {h[0]:g}, {h[1]:g} baselines")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_subset_scatter(run: RunRecord, path: Path, n_panels: int = 6) -> None:
    """Figure 4/7 style: subset solutions of a few nodes, their mean and 95% ellipse
    (of the scatter, and of the mean), the joint estimate with its 95% ellipse, truth."""
    plt = _pyplot()
    assert run.survey is not None and run.baseline is not None and run.joint is not None
    sol = run.baseline.solutions
    X = run.survey.truth_node_array()
    counts = np.bincount(sol.node_index, minlength=len(X))
    nodes = np.argsort(-counts, kind="stable")[:n_panels]
    cols = 3
    rows = int(np.ceil(len(nodes) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.9 * rows), squeeze=False)
    s = PAPER_BASELINE_METRES
    for ax, j in zip(axes.ravel(), nodes):
        nid = run.survey.node_ids[j]
        pts = sol.position[sol.node_index == j]
        ax.plot(pts[:, 0] * s, pts[:, 1] * s, ".", color="0.5", label="subset solutions")
        if nid in run.baseline.result.nodes:
            est = run.baseline.result.nodes[nid]
            ax.plot(est.position[0] * s, est.position[1] * s, "bs", label="baseline mean")
            if len(pts) >= 3:
                _ellipse(ax, est.position[:2] * s, np.cov(pts.T) * s * s, color="0.5", lw=1, label="95% of solutions")
            _ellipse(ax, est.position[:2] * s, est.covariance * s * s, color="b", lw=1.5, label="95% of mean")
        je = run.joint.nodes[nid]
        ax.plot(je.position[0] * s, je.position[1] * s, "r^", label="joint")
        _ellipse(ax, je.position[:2] * s, je.covariance * s * s, color="r", lw=1.5, label="joint 95%")
        ax.plot(X[j, 0] * s, X[j, 1] * s, "k+", ms=12, mew=2, label="truth")
        ax.set_title(f"{nid}: {len(pts)} subset solutions", fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    for ax in axes.ravel()[len(nodes):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=6)
    fig.suptitle(f"subset-averaging baseline, k={run.k}, T={run.n_subsets}, heights {run.heights}, seed {run.seed}")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def figure_joint_ellipses(run: RunRecord, path: Path) -> None:
    """The whole field: joint estimates with 95% covariance ellipses (magnified), truth, cameras."""
    plt = _pyplot()
    assert run.survey is not None and run.joint is not None
    X = run.survey.truth_node_array()
    s = PAPER_BASELINE_METRES
    covs = np.array([n.covariance for n in run.joint.nodes.values()])
    typical = np.sqrt(np.median(np.trace(covs, axis1=1, axis2=2)))
    mag = float(10 ** np.floor(np.log10(0.02 / max(typical, 1e-12))))
    fig, ax = plt.subplots(figsize=(7.5, 7.0))
    ax.plot(X[:, 0] * s, X[:, 1] * s, "k+", label="truth")
    for nid, est in run.joint.nodes.items():
        _ellipse(ax, est.position[:2] * s, est.covariance * s * s, scale=mag, color="r", lw=0.8)
    for cid, cam in run.joint.cameras.items():
        ax.plot(cam.position[0] * s, cam.position[1] * s, "bv", ms=10)
        ax.annotate(cid, (cam.position[0] * s, cam.position[1] * s), textcoords="offset points", xytext=(5, -12))
    ax.plot([], [], "r-", label=f"joint 95% ellipses ×{mag:g}")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"joint solve, k={run.k} schedule (all {len(run.survey.observations)} readings), heights {run.heights}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------- report
