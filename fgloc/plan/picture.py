"""A picture of a placement plan (matplotlib, the ``report`` extra): PNG, metres."""

from __future__ import annotations

import os

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.plan.placement import PlacementPlan

#: chi-square 95% quantile, 2 degrees of freedom.
CHI2_95_2D = 5.991464547107979


def plan_picture(plan: PlacementPlan, path: str | os.PathLike[str], polygon: np.ndarray | None = None,
                 exaggerate: float | None = None) -> float:
    """Draw candidates, chosen cameras (gauge pair in red), nodes and their predicted 95% ellipses.

    Ellipses are scaled by ``exaggerate`` (default: so the median one is 2% of the field) and the factor
    is printed in the title; returns it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Ellipse
    except ImportError:
        raise FglocError("picture: matplotlib is not installed (pip install 'fgloc[report]')") from None
    p = plan.problem
    cov = plan.covariances
    span = float(np.ptp(p.nodes_xy, axis=0).max())
    vals, vecs = np.linalg.eigh(np.where(np.isfinite(cov), cov, 0.0))
    semi = np.sqrt(np.maximum(vals, 0.0) * CHI2_95_2D)
    if exaggerate is None:
        exaggerate = 0.02 * span / max(float(np.median(semi[:, 1])), 1e-12)
    fig, ax = plt.subplots(figsize=(7, 7))
    if polygon is not None:
        closed = np.vstack([polygon, polygon[:1]])
        ax.plot(closed[:, 0], closed[:, 1], color="0.5", lw=1)
    ax.scatter(p.xy[:, 0], p.xy[:, 1], s=8, color="0.75", marker="s", label="candidate sites")
    for j, (xy, w, v) in enumerate(zip(p.nodes_xy, semi, vecs)):
        ang = float(np.degrees(np.arctan2(v[1, 1], v[0, 1])))
        ax.add_patch(Ellipse(tuple(xy), 2 * exaggerate * w[1], 2 * exaggerate * w[0], angle=ang,
                             fill=False, lw=0.6, color="tab:blue"))
    ax.scatter(p.nodes_xy[:, 0], p.nodes_xy[:, 1], s=2, color="tab:blue", label="nodes")
    for i, c in enumerate(plan.chosen):
        colour = "tab:red" if i < 2 else "k"
        ax.scatter([p.xy[c][0]], [p.xy[c][1]], s=80, marker="^", color=colour)
        ax.annotate(f"cam{i} {p.heights[c]:g} m", p.xy[c], textcoords="offset points", xytext=(5, 5), fontsize=8)
    pe = plan.predicted
    ax.set_title(f"{plan.objective}: median {pe.median * 100:.1f} cm, 95% {pe.p95 * 100:.1f} cm, worst "
                 f"{pe.worst * 100:.1f} cm\n95% ellipses x{exaggerate:.0f}; gauge pair in red", fontsize=9)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return exaggerate
