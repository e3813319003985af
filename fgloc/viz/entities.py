"""A solved survey in the ``world`` entity tree: ground grid, unit baseline,
cameras (pose, frustum, position uncertainty), nodes (estimates, confidence regions,
truth, errors) and measured rays; :func:`log_result` logs all of it.

Positions in the gauge frame (baseline = 1, z up); see :mod:`fgloc.viz` for the entity paths.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from fgloc.core.confidence import confidence_ellipsoids
from fgloc.core.geometry import FloatArray
from fgloc.core.model import CameraPose, NodeMode, Result, Survey
from fgloc.viz.arrays import NodeArrays, frustum_strips, node_arrays, ray_segments
from fgloc.viz.iterations import log_error_history
from fgloc.viz.style import (
    BASELINE_COLOR,
    COVARIANCE_COLOR,
    ERROR_COLOR,
    ERROR_RADIUS,
    ESTIMATE_COLOR,
    GROUND_COLOR,
    LINE_RADIUS,
    NODE_RADIUS,
    OUTLIER_COLOR,
    RAY_ALPHA,
    THIN_LINE_RADIUS,
    TRUTH_COLOR,
    TRUTH_RADIUS,
    VizOptions,
    camera_color,
    time_kwargs,
)
from fgloc.viz.worst_nodes import log_worst_nodes, worst_nodes


def log_ground(rec: rr.RecordingStream, positions: FloatArray, spacing: float = 0.1) -> None:
    """Grid lines on z = 0 covering ``positions`` (and the unit baseline) with a margin."""
    pts = np.vstack([np.asarray(positions, float).reshape(-1, 3), [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo = np.floor(pts[:, :2].min(axis=0) / spacing - 1) * spacing
    hi = np.ceil(pts[:, :2].max(axis=0) / spacing + 1) * spacing
    xs = np.arange(lo[0], hi[0] + spacing / 2, spacing)
    ys = np.arange(lo[1], hi[1] + spacing / 2, spacing)
    strips = np.zeros((len(xs) + len(ys), 2, 3))
    strips[: len(xs), :, 0] = xs[:, None]
    strips[: len(xs), 0, 1], strips[: len(xs), 1, 1] = lo[1], hi[1]
    strips[len(xs):, :, 1] = ys[:, None]
    strips[len(xs):, 0, 0], strips[len(xs):, 1, 0] = lo[0], hi[0]
    rec.log("world/ground", rr.LineStrips3D(list(strips), colors=GROUND_COLOR, radii=THIN_LINE_RADIUS), static=True)


def log_baseline(rec: rr.RecordingStream, result: Result, survey: Survey | None = None, static: bool = True) -> None:
    """The unit baseline: planar gauge (0,0,0)-(1,0,0); 3d gauge between the two gauge cameras."""
    if result.mode is NodeMode.PLANAR:
        segment = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    elif survey is not None and {survey.gauge.origin, survey.gauge.baseline} <= set(result.cameras):
        segment = np.array([result.cameras[survey.gauge.origin].position, result.cameras[survey.gauge.baseline].position])
    else:
        return
    rec.log(
        "world/baseline",
        rr.LineStrips3D([segment], colors=BASELINE_COLOR, radii=LINE_RADIUS, labels=["baseline = 1"]),
        **time_kwargs(static),
    )


def log_cameras(
    rec: rr.RecordingStream,
    cameras: dict[str, CameraPose],
    camera_ids: Sequence[str] | None = None,
    *,
    covariances: dict[str, FloatArray] | None = None,
    options: VizOptions = VizOptions(),
    static: bool = True,
) -> None:
    """Each camera base as a transform, a labelled point, a frustum along base +x, and
    (when ``covariances`` holds its 6x6 [omega, v] body-frame covariance) its
    position confidence ellipsoid in the base frame plus the rotation sigma in its label."""
    ids = list(camera_ids) if camera_ids is not None else list(cameras)
    d = options.frustum_depth
    for i, cid in enumerate(ids):
        if cid not in cameras:
            continue
        pose = cameras[cid]
        path = f"world/cameras/{cid}"
        rec.log(path, rr.Transform3D(translation=pose.position, mat3x3=pose.rotation), **time_kwargs(static))
        label = cid
        cov = None if covariances is None else covariances.get(cid)
        if cov is not None:
            cov = np.asarray(cov, dtype=float)
            rot_sigma_deg = np.degrees(np.sqrt(np.linalg.eigvalsh(cov[:3, :3]).max()))
            label = f"{cid} (rot sigma {rot_sigma_deg:.3f}°)"
            ell = confidence_ellipsoids(cov[None, 3:, 3:], options.confidence)
            rec.log(
                f"{path}/position_covariance",
                rr.Ellipsoids3D(
                    centers=np.zeros((1, 3)), half_sizes=ell.half_sizes, quaternions=ell.quaternions,
                    colors=camera_color(i), line_radii=THIN_LINE_RADIUS, fill_mode="majorwireframe",
                ),
                **time_kwargs(static),
            )
        rec.log(
            path,
            rr.Points3D(np.zeros((1, 3)), colors=camera_color(i), radii=rr.Radius.ui_points(6.0), labels=[label]),
            **time_kwargs(static),
        )
        rec.log(f"{path}/frustum", rr.LineStrips3D(frustum_strips(d), colors=camera_color(i), radii=LINE_RADIUS),
                **time_kwargs(static))


def log_nodes(
    rec: rr.RecordingStream,
    result: Result,
    survey: Survey | None = None,
    *,
    options: VizOptions = VizOptions(),
    static: bool = True,
) -> NodeArrays:
    """Estimates (labelled points), their confidence ellipses/ellipsoids, and — when the
    survey has truth — true positions and estimate -> truth error segments."""
    nodes = node_arrays(result, survey)
    kw = time_kwargs(static)
    rec.log(
        "world/nodes/estimate",
        rr.Points3D(nodes.positions, labels=nodes.ids, colors=ESTIMATE_COLOR, radii=NODE_RADIUS,
                    show_labels=options.show_node_labels),
        **kw,
    )
    if options.labelled_worst_nodes > 0:
        worst = worst_nodes(result, survey, options.labelled_worst_nodes, options.confidence)
        rec.log("world/nodes/worst",
                rr.Points3D([result.nodes[w.node].position for w in worst], labels=[w.node for w in worst],
                            colors=ESTIMATE_COLOR, radii=NODE_RADIUS, show_labels=True), **kw)
    ell = confidence_ellipsoids(nodes.covariances, options.confidence)
    ok = np.isfinite(ell.half_sizes).all(axis=1)
    rec.log(
        "world/nodes/covariance",
        rr.Ellipsoids3D(
            centers=nodes.positions[ok], half_sizes=ell.half_sizes[ok], quaternions=ell.quaternions[ok],
            colors=COVARIANCE_COLOR, line_radii=LINE_RADIUS, fill_mode="majorwireframe",
            labels=[f"{nodes.ids[i]} {100 * options.confidence:g}%" for i in np.flatnonzero(ok)],
            show_labels=False,
        ),
        **kw,
    )
    if survey is not None and survey.truth is not None:
        with_truth = [j for j, n in enumerate(nodes.ids) if n in survey.truth.nodes]
        ids = [nodes.ids[j] for j in with_truth]
        truth = np.array([survey.truth.nodes[n] for n in ids], dtype=float).reshape(-1, 3)
        estimate = nodes.positions[with_truth]
        rec.log("world/nodes/truth", rr.Points3D(truth, colors=TRUTH_COLOR, radii=TRUTH_RADIUS), **kw)
        rec.log(
            "world/nodes/error",
            rr.LineStrips3D(np.stack([estimate, truth], axis=1), colors=ERROR_COLOR, radii=ERROR_RADIUS),
            **kw,
        )
    return nodes


def log_rays(rec: rr.RecordingStream, survey: Survey, result: Result, options: VizOptions = VizOptions(),
             static: bool = True) -> None:
    """One batched LineStrips3D per camera: every measured bearing, flagged outliers in red."""
    segments, obs_index, cam_index = ray_segments(survey, result, options.ray_overshoot)
    flagged = {f.index for f in result.flagged}
    is_flagged = np.array([i in flagged for i in obs_index.tolist()], dtype=bool)
    for i, cid in enumerate(survey.camera_ids):
        sel = cam_index == i
        if not sel.any():
            continue
        colors = np.tile(np.array(camera_color(i, RAY_ALPHA), dtype=np.uint8), (int(sel.sum()), 1))
        colors[is_flagged[sel]] = OUTLIER_COLOR
        radii = np.where(is_flagged[sel], ERROR_RADIUS, THIN_LINE_RADIUS).astype(np.float32)
        rec.log(f"world/rays/{cid}", rr.LineStrips3D(segments[sel], colors=colors, radii=radii),
                **time_kwargs(static))


def log_result(
    rec: rr.RecordingStream,
    result: Result,
    survey: Survey | None = None,
    *,
    camera_covariances: dict[str, FloatArray] | None = None,
    options: VizOptions = VizOptions(),
    static: bool = True,
) -> None:
    """Everything about a solved survey: ground, baseline, cameras, nodes, uncertainty,
    truth and errors, rays (when the survey is given), worst-nodes table, and the
    optimizer's error history (``result.stats.error_history`` on ``iteration``)."""
    nodes = node_arrays(result, survey)
    if static:
        cam_pos = np.array([c.position for c in result.cameras.values()]).reshape(-1, 3)
        log_ground(rec, np.vstack([nodes.positions, cam_pos * np.array([1.0, 1.0, 0.0])]))
    log_baseline(rec, result, survey, static)
    log_cameras(rec, result.cameras, survey.camera_ids if survey is not None else None,
                covariances=camera_covariances, options=options, static=static)
    log_nodes(rec, result, survey, options=options, static=static)
    if survey is not None:
        log_rays(rec, survey, result, options, static)
    log_worst_nodes(rec, result, survey, options, static)
    if static and result.stats is not None and result.stats.error_history:
        log_error_history(rec, result.stats.error_history)
