"""The solve as it went: total error per LM iteration, the estimates of every
iteration (``iteration`` timeline), and the subset-Newton baseline's subset solutions."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rerun as rr

from fgloc.core.geometry import FloatArray
from fgloc.core.model import NodeMode, Survey
from fgloc.viz.style import (
    COVARIANCE_COLOR,
    ESTIMATE_COLOR,
    ITERATE_COLOR,
    NODE_RADIUS,
    SUBSET_RADIUS,
    node_palette,
    time_kwargs,
)


def log_error_history(rec: rr.RecordingStream, errors: Sequence[float]) -> None:
    """Total graph error per iteration on the ``iteration`` timeline (one column send each
    for ``optimizer/error`` and ``optimizer/log10_error``, which the blueprint plots)."""
    error_values = np.asarray(errors, dtype=float)
    index = [rr.TimeColumn("iteration", sequence=np.arange(len(error_values)))]
    rec.log("optimizer/error", rr.SeriesLines(colors=ESTIMATE_COLOR, widths=2.0, names="total error"), static=True)
    rec.send_columns("optimizer/error", indexes=index, columns=rr.Scalars.columns(scalars=error_values))
    rec.log("optimizer/log10_error", rr.SeriesLines(colors=COVARIANCE_COLOR, widths=2.0, names="log10 total error"),
            static=True)
    with np.errstate(divide="ignore"):
        rec.send_columns("optimizer/log10_error", indexes=index,
                         columns=rr.Scalars.columns(scalars=np.log10(np.maximum(error_values, 1e-300))))


@dataclass
class IterationSnapshot:
    """Estimates after one accepted LM step (iteration 0 = the initial estimate)."""

    iteration: int
    error: float
    camera_positions: FloatArray  # (C, 3), NaN for cameras not in the problem
    node_positions: FloatArray  # (N, 3), NaN for nodes not in the problem


@dataclass
class IterationRecorder:
    """``on_iteration`` callback for :func:`fgloc.solve.joint.solve_survey` that keeps
    the estimates of every iteration as arrays.

    Keys follow the joint solver: ``C(i)`` for camera i and ``L(j)`` for node j
    (indices into ``survey.camera_ids`` / ``survey.node_ids``). Planar nodes
    (Point2) are placed on z = 0.
    """

    survey: Survey
    snapshots: list[IterationSnapshot] = field(default_factory=list)

    def __call__(self, iteration: int, values: Any, error: float) -> None:  # values: gtsam.Values
        import gtsam  # the solver already imported it; keeps this module light otherwise

        C, L = gtsam.symbol_shorthand.C, gtsam.symbol_shorthand.L
        cams = np.full((len(self.survey.camera_ids), 3), np.nan)
        for i in range(len(self.survey.camera_ids)):
            if values.exists(C(i)):
                cams[i] = values.atPose3(C(i)).translation()
        nodes = np.full((len(self.survey.node_ids), 3), np.nan)
        planar = self.survey.mode is NodeMode.PLANAR
        for j in range(len(self.survey.node_ids)):
            if values.exists(L(j)):
                if planar:
                    nodes[j, :2] = values.atPoint2(L(j))
                    nodes[j, 2] = 0.0
                else:
                    nodes[j] = values.atPoint3(L(j))
        self.snapshots.append(IterationSnapshot(int(iteration), float(error), cams, nodes))

    def log(self, rec: rr.RecordingStream, errors: bool = True) -> None:
        """Iterates on the ``iteration`` timeline: ``world/solve/nodes`` and ``world/solve/cameras``
        (one call each per iteration) and, when ``errors``, ``optimizer/error``."""
        if not self.snapshots:
            return
        if errors:
            log_error_history(rec, [s.error for s in self.snapshots])
        for s in self.snapshots:
            rec.set_time("iteration", sequence=s.iteration)
            ok = np.isfinite(s.node_positions).all(axis=1)
            rec.log("world/solve/nodes", rr.Points3D(s.node_positions[ok], colors=ITERATE_COLOR,
                                                     radii=rr.Radius.ui_points(2.0)))
            okc = np.isfinite(s.camera_positions).all(axis=1)
            rec.log("world/solve/cameras", rr.Points3D(s.camera_positions[okc], colors=ITERATE_COLOR,
                                                       radii=rr.Radius.ui_points(4.0)))
        rec.reset_time()


def _as_points3(points: FloatArray) -> FloatArray:
    """(K, 3) points; (K, 2) planar points are placed on z = 0."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError(f"points must be (K, 2) or (K, 3), got {p.shape}")
    return np.column_stack([p, np.zeros(len(p))]) if p.shape[1] == 2 else p


def log_subset_solutions(
    rec: rr.RecordingStream,
    node_ids: Sequence[str],
    positions: FloatArray,
    node_index: np.ndarray,
    mean_positions: FloatArray | None = None,
    static: bool = True,
) -> None:
    """The subset-Newton baseline: every subset solution (K, 3), or (K, 2) on z = 0, as one point cloud,
    coloured by its node (``node_index`` (K,) into ``node_ids``) — the paper's
    Figure 4 — and the averaged positions (N, 3) labelled with the node ids."""
    positions = _as_points3(positions)
    node_index = np.asarray(node_index, dtype=np.int64).reshape(-1)
    if positions.shape[0] != node_index.shape[0]:
        raise ValueError(f"{positions.shape[0]} subset positions but {node_index.shape[0]} node indices")
    palette = node_palette(len(node_ids))
    ok = np.isfinite(positions).all(axis=1)
    rec.log("world/subset_newton/subsets",
            rr.Points3D(positions[ok], colors=palette[node_index[ok]], radii=SUBSET_RADIUS), **time_kwargs(static))
    if mean_positions is not None:
        mean = _as_points3(mean_positions)
        okm = np.isfinite(mean).all(axis=1)
        rec.log("world/subset_newton/mean",
                rr.Points3D(mean[okm], colors=palette[okm], radii=NODE_RADIUS,
                            labels=[node_ids[int(i)] for i in np.flatnonzero(okm)], show_labels=False),
                **time_kwargs(static))
