"""Rerun visualization of surveys, estimates, uncertainty and the solve (rerun-sdk 0.41).

The only fgloc module that imports ``rerun``. Everything is logged to an
explicit :class:`rerun.RecordingStream` (no global state), either saved to an
``.rrd`` file or shown in a viewer this module starts on 127.0.0.1 only.

World frame: the gauge frame of ``docs/file-format.md`` (right-handed,
z up, baseline = 1, nodes of planar surveys on z = 0). Entity paths:

==============================  ==================================================
``world/ground``                grid lines on z = 0 (0.1 spacing) around the nodes
``world/baseline``              the unit baseline between the gauge cameras' feet
``world/cameras/<id>``          base pose (Transform3D, base -> world) + labelled point
``world/cameras/<id>/frustum``  small wireframe frustum along pan = tilt = 0 (base +x)
``world/cameras/<id>/position_covariance``  95% ellipsoid of the base position,
                                in the base frame (GTSAM's body-frame tangent)
``world/nodes/estimate``        estimated node positions, labelled with ids (on hover)
``world/nodes/worst``           the few worst nodes again, with visible labels
``world/nodes/covariance``      95% ellipses (planar) / ellipsoids (3d)
``world/nodes/truth``           true positions (simulated surveys only)
``world/nodes/error``           segments estimate -> truth
``world/rays/<camera>``         measured bearing of every observation by the camera;
                                flagged (outlier) observations in red
``world/subset_newton/subsets`` every subset solution of the paper's baseline,
                                coloured by node (the paper's Figure 4)
``world/subset_newton/mean``    the baseline's averaged positions
``world/solve/nodes``           node estimates per LM iteration (``iteration`` timeline)
``world/solve/cameras``         camera positions per LM iteration
``optimizer/error``             total graph error per iteration (``iteration`` timeline)
``report/worst_nodes``          markdown table of the worst nodes
``survey/log``                  one text line per live observation (``survey`` timeline)
==============================  ==================================================

Final results are logged *static* (visible whatever the time cursor), so
scrubbing the ``iteration`` timeline moves only the ``world/solve`` iterates.
A live survey (:class:`SurveyLogger`) logs results on the ``survey`` timeline
instead; do not mix both on one recording.

Every archetype is logged once per entity and time step with whole arrays:
a log call costs ~190 us, so per-item calls would be orders of magnitude slower
(``shared/reference/rerun-checks.md``).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from fgloc.core.confidence import DEFAULT_CONFIDENCE, confidence_ellipsoids
from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, pan_tilt_bearing
from fgloc.core.model import CameraPose, NodeMode, Observation, Result, Survey

APPLICATION_ID = "fgloc"

# Colours (RGBA). Nodes orange, truth green, errors magenta, 95% regions cyan, outliers red.
ESTIMATE_COLOR = (255, 160, 0, 255)
TRUTH_COLOR = (60, 220, 90, 255)
ERROR_COLOR = (255, 60, 220, 255)
COVARIANCE_COLOR = (0, 210, 255, 255)
OUTLIER_COLOR = (255, 0, 0, 255)
ITERATE_COLOR = (200, 200, 200, 255)
GROUND_COLOR = (90, 90, 90, 255)
BASELINE_COLOR = (255, 255, 255, 255)
CAMERA_COLORS = [(80, 150, 255), (255, 230, 60), (200, 120, 255), (255, 120, 90), (120, 255, 220)]
RAY_ALPHA = 28

# Sizes in UI points (negative radii in Rerun), so they read the same at any zoom.
NODE_RADIUS = rr.Radius.ui_points(4.0)
TRUTH_RADIUS = rr.Radius.ui_points(3.0)
SUBSET_RADIUS = rr.Radius.ui_points(1.5)
LINE_RADIUS = rr.Radius.ui_points(1.0)
THIN_LINE_RADIUS = rr.Radius.ui_points(0.5)
ERROR_RADIUS = rr.Radius.ui_points(1.5)


@dataclass(frozen=True)
class VizOptions:
    """How to draw: confidence of the ellipses, size of camera frusta, table length.

    ``frustum_depth`` is in gauge units (baseline = 1); ``ray_overshoot`` is how
    far rays run past the estimated node, as a fraction of the range. Node labels
    are shown on hover unless ``show_node_labels``; the ``labelled_worst_nodes``
    worst nodes are always labelled (``world/nodes/worst``).
    """

    confidence: float = DEFAULT_CONFIDENCE
    frustum_depth: float = 0.05
    ray_overshoot: float = 0.1
    worst_nodes: int = 10
    show_node_labels: bool = False
    labelled_worst_nodes: int = 5


# --------------------------------------------------------------------------- helpers


def camera_color(index: int, alpha: int = 255) -> tuple[int, int, int, int]:
    """A distinct colour per camera index."""
    r, g, b = CAMERA_COLORS[index % len(CAMERA_COLORS)]
    return (r, g, b, alpha)


def node_palette(n: int) -> np.ndarray:
    """``n`` well separated RGBA colours (uint8, (n, 4)) from golden-ratio hues."""
    h = (np.arange(n) * 0.618033988749895) % 1.0
    s, v = 0.75, 1.0
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    rgb = np.stack([r, g, b], axis=1) * 255.0
    return np.concatenate([rgb, np.full((n, 1), 255.0)], axis=1).astype(np.uint8)


@dataclass(frozen=True)
class NodeArrays:
    """A result's localized nodes as arrays (ids sorted like the survey when given)."""

    ids: list[str]
    positions: FloatArray  # (N, 3) gauge frame
    covariances: FloatArray  # (N, d, d)


def node_arrays(result: Result, survey: Survey | None = None) -> NodeArrays:
    """Localized nodes of ``result`` as arrays, in survey order when a survey is given."""
    order = [n for n in survey.node_ids if n in result.nodes] if survey is not None else list(result.nodes)
    d = result.mode.position_dim
    if not order:
        return NodeArrays([], np.zeros((0, 3)), np.zeros((0, d, d)))
    positions = np.array([result.nodes[n].position for n in order], dtype=float).reshape(-1, 3)
    covariances = np.array([result.nodes[n].covariance for n in order], dtype=float).reshape(-1, d, d)
    return NodeArrays(order, positions, covariances)


def _time_kwargs(static: bool) -> dict[str, bool]:
    return {"static": True} if static else {}


# --------------------------------------------------------------------------- recording


def open_recording(
    path: str | os.PathLike[str] | None = None,
    *,
    recording_id: str | None = None,
    blueprint: rrb.Blueprint | None = None,
) -> rr.RecordingStream:
    """A new recording stream; saved to ``path`` (with ``blueprint`` as default) when given.

    The world frame is declared right-handed, z up. Call :func:`close_recording`
    when done so the file gets its footer.
    """
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
    if path is not None:
        try:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            rec.save(str(path), default_blueprint=blueprint)
        except (OSError, RuntimeError) as exc:  # rerun reports an unwritable file as RuntimeError
            reason = str(exc).split(" (os error")[0].split(", path:")[0]
            raise FglocError(f"{path}: cannot write the Rerun recording ({reason})") from None
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and close the stream (writes the .rrd footer)."""
    rec.flush()
    rec.disconnect()


# --------------------------------------------------------------------------- scene


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
    rec.log("world/ground", rr.LineStrips3D(strips, colors=GROUND_COLOR, radii=THIN_LINE_RADIUS), static=True)


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
        **_time_kwargs(static),
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
        rec.log(path, rr.Transform3D(translation=pose.position, mat3x3=pose.rotation), **_time_kwargs(static))
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
                **_time_kwargs(static),
            )
        rec.log(
            path,
            rr.Points3D(np.zeros((1, 3)), colors=camera_color(i), radii=rr.Radius.ui_points(6.0), labels=[label]),
            **_time_kwargs(static),
        )
        rec.log(f"{path}/frustum", rr.LineStrips3D(frustum_strips(d), colors=camera_color(i), radii=LINE_RADIUS),
                **_time_kwargs(static))


def frustum_strips(depth: float, half_width: float = 0.6, half_height: float = 0.4) -> np.ndarray:
    """Wireframe of a frustum in the base frame looking along +x (pan = tilt = 0), z up:
    four edges from the apex plus the far rectangle at x = ``depth`` (strips (5, *, 3))."""
    w, h = half_width * depth, half_height * depth
    corners = np.array([[depth, w, h], [depth, -w, h], [depth, -w, -h], [depth, w, -h]])
    edges = [np.stack([np.zeros(3), c]) for c in corners]
    return [*edges, np.vstack([corners, corners[:1]])]


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
    kw = _time_kwargs(static)
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
            labels=[f"{n} {100 * options.confidence:g}%" for n, good in zip(nodes.ids, ok) if good],
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


def ray_segments(survey: Survey, result: Result, overshoot: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured bearings as world segments (M, 2, 3), with each segment's observation
    index and camera index into ``survey.camera_ids``.

    A ray starts at the estimated camera centre and follows ``R b(pan, tilt)``;
    its length is the range to the estimated node times ``1 + overshoot`` (or to
    the farthest estimated node when that node was not localized).
    Observations by unlocalized cameras are skipped.
    """
    table = survey.observation_table
    cam_ok = np.array([c in result.cameras for c in survey.camera_ids], dtype=bool)
    keep = np.flatnonzero(cam_ok[table.camera_index]) if len(table) else np.zeros(0, dtype=int)
    if keep.size == 0:
        return np.zeros((0, 2, 3)), np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    centres = np.array([result.cameras[c].position if ok else np.zeros(3) for c, ok in zip(survey.camera_ids, cam_ok)])
    rotations = np.array([result.cameras[c].rotation if ok else np.eye(3) for c, ok in zip(survey.camera_ids, cam_ok)])
    node_pos = np.array([result.nodes[n].position if n in result.nodes else np.full(3, np.nan) for n in survey.node_ids])
    ci, ni = table.camera_index[keep], table.node_index[keep]
    b_world = np.einsum("mij,mj->mi", rotations[ci], pan_tilt_bearing(table.pan[keep], table.tilt[keep]))
    start = centres[ci]
    rng = np.linalg.norm(node_pos[ni] - start, axis=1)
    finite = np.isfinite(node_pos).all(axis=1)
    fallback = np.linalg.norm(node_pos[finite][None, :, :] - centres[:, None, :], axis=2).max() if finite.any() else 1.0
    rng = np.where(np.isfinite(rng), rng, fallback) * (1.0 + overshoot)
    segments = np.stack([start, start + rng[:, None] * b_world], axis=1)
    return segments, keep, ci


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
                **_time_kwargs(static))


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
                                                  media_type=rr.MediaType.MARKDOWN), **_time_kwargs(static))
    return rows


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


def log_error_history(rec: rr.RecordingStream, errors: Sequence[float]) -> None:
    """Total graph error per iteration on the ``iteration`` timeline (one column send each
    for ``optimizer/error`` and ``optimizer/log10_error``, which the blueprint plots)."""
    errors = np.asarray(errors, dtype=float)
    index = [rr.TimeColumn("iteration", sequence=np.arange(len(errors)))]
    rec.log("optimizer/error", rr.SeriesLines(colors=ESTIMATE_COLOR, widths=2.0, names="total error"), static=True)
    rec.send_columns("optimizer/error", indexes=index, columns=rr.Scalars.columns(scalars=errors))
    rec.log("optimizer/log10_error", rr.SeriesLines(colors=COVARIANCE_COLOR, widths=2.0, names="log10 total error"),
            static=True)
    with np.errstate(divide="ignore"):
        rec.send_columns("optimizer/log10_error", indexes=index,
                         columns=rr.Scalars.columns(scalars=np.log10(np.maximum(errors, 1e-300))))


# --------------------------------------------------------------------------- the solve


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

    def __call__(self, iteration: int, values: object, error: float) -> None:
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


# --------------------------------------------------------------------------- baseline


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
            rr.Points3D(positions[ok], colors=palette[node_index[ok]], radii=SUBSET_RADIUS), **_time_kwargs(static))
    if mean_positions is not None:
        mean = _as_points3(mean_positions)
        okm = np.isfinite(mean).all(axis=1)
        rec.log("world/subset_newton/mean",
                rr.Points3D(mean[okm], colors=palette[okm], radii=NODE_RADIUS,
                            labels=[n for n, good in zip(node_ids, okm) if good], show_labels=False),
                **_time_kwargs(static))


# --------------------------------------------------------------------------- live survey


class SurveyLogger:
    """Logs a live survey on the ``survey`` timeline (step = observation count).

    ``log_observation`` adds one text line and, when the camera pose is known,
    the new ray at ``world/survey/latest_ray``; ``log_estimates`` logs the
    current result on the same entity paths as :func:`log_result`, at the
    current step, so a person can scrub the survey.
    """

    def __init__(self, rec: rr.RecordingStream, survey: Survey | None = None,
                 options: VizOptions = VizOptions()) -> None:
        self.rec = rec
        self.survey = survey
        self.options = options

    def log_observation(self, step: int, observation: Observation, camera: CameraPose | None = None,
                        length: float = 1.5) -> None:
        """One observation at ``step``; ``length`` is the drawn ray length (gauge units)."""
        self.rec.set_time("survey", sequence=step)
        self.rec.log("survey/log", rr.TextLog(
            f"{observation.camera} sees {observation.node}: pan {np.degrees(observation.pan):.4f} deg, "
            f"tilt {np.degrees(observation.tilt):.4f} deg"))
        if camera is not None:
            b = np.asarray(camera.rotation, float) @ pan_tilt_bearing(observation.pan, observation.tilt)
            c = np.asarray(camera.position, float)
            self.rec.log("world/survey/latest_ray",
                         rr.LineStrips3D([np.stack([c, c + length * b])], colors=ERROR_COLOR, radii=LINE_RADIUS,
                                         labels=[f"{observation.camera} -> {observation.node}"]))

    def log_estimates(self, step: int, result: Result, survey: Survey | None = None) -> None:
        """The current estimates (cameras, nodes, ellipses, truth, rays, table) at ``step``."""
        self.rec.set_time("survey", sequence=step)
        log_result(self.rec, result, survey if survey is not None else self.survey, options=self.options,
                   static=False)


# --------------------------------------------------------------------------- blueprint


def default_blueprint(result: Result | None = None, survey: Survey | None = None,
                      options: VizOptions = VizOptions()) -> rrb.Blueprint:
    """3D scene large on the left; on the right a close-up of the worst node (true scale),
    the optimizer error over iterations and the worst-nodes table."""
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
                rrb.TextDocumentView(origin="report/worst_nodes", name="worst nodes"),
                row_shares=[2, 1, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="collapsed"),
        collapse_panels=True,
    )


# --------------------------------------------------------------------------- one-shot


def camera_covariances_or_none(survey: Survey | None, result: Result) -> dict[str, FloatArray] | None:
    """Camera pose covariances for drawing, or None when there is no survey or they are undefined."""
    if survey is None or not result.cameras:
        return None
    from fgloc.solve.camera_uncertainty import camera_covariances

    try:
        return camera_covariances(survey, result)
    except FglocError:
        return None


def write_rrd(
    path: str | os.PathLike[str],
    result: Result,
    survey: Survey | None = None,
    *,
    recorder: IterationRecorder | None = None,
    subsets: tuple[Sequence[str], FloatArray, np.ndarray, FloatArray | None] | None = None,
    camera_covariances: dict[str, FloatArray] | None = None,
    options: VizOptions = VizOptions(),
    recording_id: str | None = None,
) -> Path:
    """Write a complete .rrd of a result (and optionally its survey, iterates and the
    subset-Newton baseline as ``(node_ids, positions, node_index, mean)``) with the
    default blueprint. Returns the path."""
    path = Path(path)
    rec = open_recording(path, recording_id=recording_id, blueprint=default_blueprint(result, survey, options))
    try:
        log_result(rec, result, survey, camera_covariances=camera_covariances, options=options)
        if recorder is not None:
            has_history = result.stats is not None and bool(result.stats.error_history)
            recorder.log(rec, errors=not has_history)
        if subsets is not None:
            log_subset_solutions(rec, *subsets)
    finally:
        close_recording(rec)
    return path


# --------------------------------------------------------------------------- viewer


def viewer_binary() -> Path:
    """The real Rerun viewer binary shipped with rerun-sdk (not the Python wrapper, so
    that killing it does not orphan the viewer)."""
    import rerun_cli

    return Path(rerun_cli.__file__).parent / "rerun"


def has_display() -> bool:
    """Whether a native viewer window can be shown (X11/Wayland display, or macOS/Windows)."""
    if os.name != "posix" or Path("/System/Library").exists():
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def view_rrd(path: str | os.PathLike[str], bind: str = "127.0.0.1") -> int:
    """Open an .rrd in the native viewer and wait until it is closed (returns its exit status).

    The viewer's own server listens on ``bind`` (127.0.0.1 unless the user asks
    otherwise) on a free port.
    """
    cmd = [str(viewer_binary()), "--bind", bind, "--port", "auto", str(path)]
    return subprocess.call(cmd)


@dataclass(frozen=True)
class RenderReport:
    """What a headless render saw: the PNG, each view's error reports, the viewer's
    WARN/ERROR log lines (software-rasterizer warnings excluded)."""

    png: Path
    view_reports: dict[str, list[str]]
    problems: list[str]
    listening: list[str]  # addresses the viewer reported listening on


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def render_headless(
    path: str | os.PathLike[str],
    png: str | os.PathLike[str],
    *,
    window_size: str = "1600x900",
    timeline: str | None = "iteration",
    sequence: int | None = None,
    settle_seconds: float = 4.0,
    timeout: float = 120.0,
) -> RenderReport:
    """Render an .rrd with its default blueprint in a headless viewer (software Vulkan,
    Debian: mesa-vulkan-drivers) and save the whole window as a PNG.

    The viewer listens on 127.0.0.1 only, is driven through
    ``rerun.experimental.ViewerClient``, paused at ``sequence`` of ``timeline``
    (default: its last step), and given ``settle_seconds`` for start-up
    notifications to fade. The process is always terminated.
    """
    from rerun.experimental import ViewerClient

    port = _free_loopback_port()
    cmd = [str(viewer_binary()), "--headless", "--renderer", "vulkan", "--bind", "127.0.0.1", "--port", str(port),
           "--window-size", window_size, "--hide-welcome-screen"]
    deadline = time.monotonic() + timeout
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        client = None
        while client is None:
            if proc.poll() is not None:
                raise RuntimeError(f"headless viewer exited with status {proc.returncode} (is Vulkan available?)")
            if time.monotonic() > deadline:
                raise TimeoutError("headless viewer did not start")
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
                client.get_state()
            except Exception:  # not listening yet  # noqa: BLE001 - any viewer failure ends the headless render with a report
                client = None
                time.sleep(0.2)
        client.open(str(Path(path).resolve()))
        while True:
            state = client.get_state()
            if not state.loading:
                break
            if time.monotonic() > deadline:
                raise TimeoutError(f"{path}: viewer did not finish loading")
            time.sleep(0.1)
        if timeline is not None:
            known = {t.name: t for r in state.recordings for t in r.timelines}
            if timeline in known:
                seq = known[timeline].end if sequence is None else sequence
                client.set_time(timeline, sequence=int(seq), play_state="paused")
        time.sleep(settle_seconds)
        client.take_screenshot(max_size=64)  # a first frame retires expired start-up notifications
        time.sleep(0.5)
        client.save_screenshot(str(Path(png).resolve()))
        views = client.get_state().views  # reports describe the frame just painted
        reports = {f"{v.view_class}:{v.name}": [str(r) for r in v.reports] for v in views}
        logs = client.get_logs()
        problems = [f"{e.level} {e.target}: {e.message}" for e in logs
                    if e.level in ("WARN", "ERROR") and "oftware rasterizer" not in e.message]
        listening = [m.group(1) for e in logs if e.message.startswith("Listening for")
                     for m in [re.search(r" on (\S+:\d+)", e.message)] if m]
        try:
            client.run_command("ui.quit")
            proc.wait(timeout=10)
        except Exception:  # noqa: BLE001 - any viewer failure ends the headless render with a report
            pass
        return RenderReport(Path(png), reports, problems, listening)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

