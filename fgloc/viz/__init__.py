"""Rerun visualization of surveys, estimates, uncertainty and the solve (rerun-sdk 0.41).

The only fgloc package that imports ``rerun`` (``import fgloc`` does not import it). Everything is logged to an
explicit :class:`rerun.RecordingStream` (no global state), either saved to an
``.rrd`` file or shown in a viewer this package starts on 127.0.0.1 only.

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
``cameras/<id>/head/...``       head calibration (each error with its 1-sigma) and the
                                drift check (``head_check`` timeline), :mod:`~fgloc.viz.head_view`
==============================  ==================================================

Final results are logged *static* (visible whatever the time cursor), so
scrubbing the ``iteration`` timeline moves only the ``world/solve`` iterates.
A live survey (:class:`SurveyLogger`) logs results on the ``survey`` timeline
instead; do not mix both on one recording.

Every archetype is logged once per entity and time step with whole arrays:
a log call costs ~190 us, so per-item calls would be orders of magnitude slower
(``shared/reference/rerun-checks.md``).

Modules, each one idea: :mod:`~fgloc.viz.style` (colours, sizes, options),
:mod:`~fgloc.viz.arrays` (a result as drawable arrays, no Rerun),
:mod:`~fgloc.viz.entities` (the ``world`` tree), :mod:`~fgloc.viz.worst_nodes`,
:mod:`~fgloc.viz.iterations` (LM iterates, error history, subset solutions),
:mod:`~fgloc.viz.survey_logger` (live surveys), :mod:`~fgloc.viz.blueprint`,
:mod:`~fgloc.viz.recording` (open/close/write_rrd), :mod:`~fgloc.viz.viewer`
(native and headless viewer).
"""

from __future__ import annotations

from fgloc.viz.arrays import (
    NodeArrays,
    frustum_strips,
    node_arrays,
    ray_segments,
)
from fgloc.viz.blueprint import (
    default_blueprint,
)
from fgloc.viz.entities import (
    log_baseline,
    log_cameras,
    log_ground,
    log_nodes,
    log_rays,
    log_result,
)
from fgloc.viz.head_view import (
    log_drift_check,
    log_head_calibration,
    write_head_check_rrd,
)
from fgloc.viz.iterations import (
    IterationRecorder,
    IterationSnapshot,
    log_error_history,
    log_subset_solutions,
)
from fgloc.viz.recording import (
    APPLICATION_ID,
    camera_covariances_or_none,
    close_recording,
    open_recording,
    write_rrd,
)
from fgloc.viz.style import (
    BASELINE_COLOR,
    CAMERA_COLORS,
    COVARIANCE_COLOR,
    ERROR_COLOR,
    ERROR_RADIUS,
    ESTIMATE_COLOR,
    GROUND_COLOR,
    ITERATE_COLOR,
    LINE_RADIUS,
    NODE_RADIUS,
    OUTLIER_COLOR,
    RAY_ALPHA,
    SUBSET_RADIUS,
    THIN_LINE_RADIUS,
    TRUTH_COLOR,
    TRUTH_RADIUS,
    VizOptions,
    camera_color,
    node_palette,
)
from fgloc.viz.survey_logger import (
    SurveyLogger,
)
from fgloc.viz.viewer import (
    RenderReport,
    has_display,
    render_headless,
    view_rrd,
    viewer_binary,
)
from fgloc.viz.worst_nodes import (
    WorstNode,
    log_worst_nodes,
    worst_nodes,
    worst_nodes_markdown,
)

__all__ = [
    "APPLICATION_ID",
    "BASELINE_COLOR",
    "CAMERA_COLORS",
    "COVARIANCE_COLOR",
    "ERROR_COLOR",
    "ERROR_RADIUS",
    "ESTIMATE_COLOR",
    "GROUND_COLOR",
    "ITERATE_COLOR",
    "IterationRecorder",
    "IterationSnapshot",
    "LINE_RADIUS",
    "NODE_RADIUS",
    "NodeArrays",
    "OUTLIER_COLOR",
    "RAY_ALPHA",
    "RenderReport",
    "SUBSET_RADIUS",
    "SurveyLogger",
    "THIN_LINE_RADIUS",
    "TRUTH_COLOR",
    "TRUTH_RADIUS",
    "VizOptions",
    "WorstNode",
    "camera_color",
    "camera_covariances_or_none",
    "close_recording",
    "default_blueprint",
    "frustum_strips",
    "has_display",
    "log_baseline",
    "log_cameras",
    "log_drift_check",
    "log_head_calibration",
    "log_error_history",
    "log_ground",
    "log_nodes",
    "log_rays",
    "log_result",
    "log_subset_solutions",
    "log_worst_nodes",
    "node_arrays",
    "node_palette",
    "open_recording",
    "ray_segments",
    "render_headless",
    "view_rrd",
    "viewer_binary",
    "worst_nodes",
    "worst_nodes_markdown",
    "write_head_check_rrd",
    "write_rrd",
]
