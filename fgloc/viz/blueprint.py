"""The default viewer layout: the scene, a true-scale close-up of the worst node,
the optimizer's error curve and the worst-nodes table."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun.blueprint as rrb

from fgloc.core.model import Result, Survey
from fgloc.viz.arrays import node_arrays
from fgloc.viz.style import VizOptions
from fgloc.viz.worst_nodes import worst_nodes


def head_views(cameras: Sequence[str], drift: bool = False) -> list[rrb.Container]:
    """One tab per camera: its head-error table and bar charts (value and 1-sigma side by side,
    fgloc.viz.head_view), and with ``drift`` the running drift test (``head_check`` timeline)."""
    tabs: list[rrb.Container] = []
    for cid in cameras:
        base = f"cameras/{cid}/head"

        def bars(group: str, name: str, base: str = base) -> rrb.BarChartView:
            return rrb.BarChartView(origin=base, name=name, contents=[f"+ $origin/{group}", f"+ $origin/{group}_sigma"])

        calibration = rrb.Vertical(
            rrb.TextDocumentView(origin=f"{base}/summary", name=f"{cid}: head errors ±1σ"),
            bars("angles_deg", f"{cid}: index, collimation, trunnion (°): estimate | 1σ"),
            bars("scales_percent", f"{cid}: pan, tilt encoder scale (%): estimate | 1σ"),
            row_shares=[2, 1, 1],
        )
        if not drift:
            tabs.append(rrb.Vertical(calibration, name=f"{cid} head"))
            continue
        check = rrb.Vertical(
            rrb.TimeSeriesView(origin=f"{base}/drift", name=f"{cid}: tilt index change ±1σ (°) per reading",
                               contents=["+ $origin/tilt_index_change_deg", "+ $origin/tilt_index_change_sigma_deg"]),
            rrb.TimeSeriesView(origin=f"{base}/drift", name=f"{cid}: drift test chi2, threshold, flag",
                               contents=["+ $origin/chi2", "+ $origin/threshold", "+ $origin/drifted"]),
            rrb.TextLogView(origin=f"{base}/drift/log", name=f"{cid}: drift check log"),
            rrb.TextDocumentView(origin=f"{base}/updated/summary", name=f"{cid}: after the check"),
        )
        tabs.append(rrb.Horizontal(calibration, check, name=f"{cid} head"))
    return tabs


def default_blueprint(result: Result | None = None, survey: Survey | None = None,
                      options: VizOptions = VizOptions(), head_cameras: Sequence[str] = ()) -> rrb.Blueprint:
    """3D scene large on the left; on the right a close-up of the worst node (true scale),
    the optimizer error over iterations and the worst-nodes table (with ``head_cameras``, a
    tab per camera with its head calibration next to it)."""
    overview_eye = None
    zoom_eye = None
    zoom_name = "close-up"
    if result is not None and result.nodes:
        nodes = node_arrays(result, survey)
        pts = np.vstack([nodes.positions] + [c.position[None, :] for c in result.cameras.values()])
        pts = pts[np.isfinite(pts).all(axis=1)]
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        size = float(np.ptp(pts, axis=0).max()) or 1.0
        overview_eye = rrb.EyeControls3D(
            position=centre + size * np.array([0.12, -1.18, 0.9]), look_target=centre, eye_up=[0.0, 0.0, 1.0])
        rows = worst_nodes(result, survey, 1, options.confidence)
        if rows:
            target = np.asarray(result.nodes[rows[0].node].position, float)
            reach = max(3.0 * rows[0].major_half_axis, 2.0 * (rows[0].error if np.isfinite(rows[0].error) else 0.0),
                        1e-6)
            zoom_eye = rrb.EyeControls3D(position=target + reach * np.array([0.0, -0.6, 2.0]), look_target=target,
                                         eye_up=[0.0, 1.0, 0.0])
            zoom_name = f"close-up of {rows[0].node} (true scale, {100 * options.confidence:g}%)"
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="scene", eye_controls=overview_eye),
            rrb.Vertical(
                rrb.Spatial3DView(origin="world", name=zoom_name, eye_controls=zoom_eye,
                                  contents=["+ world/**", "- world/ground/**"]),
                rrb.TimeSeriesView(origin="optimizer/log10_error", name="optimizer: log10 total error per iteration"),
                rrb.Tabs(rrb.TextDocumentView(origin="report/worst_nodes", name="worst nodes"),
                         *head_views(head_cameras)) if head_cameras else
                rrb.TextDocumentView(origin="report/worst_nodes", name="worst nodes"),
                row_shares=[2, 1, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )
