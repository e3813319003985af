"""The head calibration and the drift check in Rerun: per camera, each head error with its 1-sigma.

Input is what the files hold, so ``fgloc solve``, ``fgloc view`` and ``fgloc head-check``
log the same thing: a result.json ``head_calibration`` block
(:meth:`fgloc.solve.self_calibration.HeadCalibrationReport.to_json`: radians, unit-less
scales, survey units) and a ``head_check.json`` report (:mod:`fgloc.survey.head_check`).
Display units: degrees for the angles, percent for the encoder scales, baseline units
for the lever arm. Entity paths (``<id>`` a camera id):

==========================================  ==============================================
``cameras/<id>/head/summary``               markdown table: parameter, estimate, 1-sigma,
                                            unit, estimated or pinned (static)
``cameras/<id>/head/angles_deg``            bar chart: tilt index, collimation, trunnion
                                            (degrees) at x = 0, 1, 2; ``..._sigma`` their
                                            1-sigma beside them at x + 0.4 (static)
``cameras/<id>/head/scales_percent``        bar chart: pan scale, tilt scale (%), and sigma
``cameras/<id>/head/lever_arm_baseline``    bar chart: lever y, lever z (baseline units)
``cameras/<id>/head/drift/<series>``        drift check on the ``head_check`` timeline (one
                                            step per re-read reading): ``tilt_index_change_deg``,
                                            its ``..._sigma_deg``, ``pan_offset_deg``,
                                            ``chi2``, ``log_lr`` (the SPRT statistic), ``threshold``, ``drifted`` (0/1)
``cameras/<id>/head/drift/log``             one text line per reading: mote, estimate, flag
``cameras/<id>/head/updated/...``           the calibration after the drift check (as above)
==========================================  ==============================================
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from fgloc.core.head_model import HEAD_PARAMETERS

#: (entity name, parameter names, factor from model units to display units, unit label)
HEAD_GROUPS_DISPLAY: tuple[tuple[str, tuple[str, ...], float, str], ...] = (
    ("angles_deg", ("tilt_index", "collimation", "trunnion"), 180.0 / math.pi, "°"),
    ("scales_percent", ("pan_scale", "tilt_scale"), 100.0, "%"),
    ("lever_arm_baseline", ("lever_y", "lever_z"), 1.0, "baseline"),
)
#: the drift series logged per reading, with the report field each comes from
DRIFT_SERIES: tuple[tuple[str, str], ...] = (
    ("tilt_index_change_deg", "tilt_index_change_deg"), ("tilt_index_change_sigma_deg", "tilt_index_change_std_deg"),
    ("pan_offset_deg", "pan_offset_deg"), ("pan_offset_sigma_deg", "pan_offset_std_deg"),
    ("chi2", "chi2"), ("log_lr", "log_lr"), ("threshold", "threshold"),
)
TIMELINE = "head_check"
ESTIMATE_BAR = (230, 120, 40, 255)  #: bar colour of the estimates
SIGMA_BAR = (150, 150, 150, 255)  #: bar colour of their 1-sigma


def head_entity(camera: str) -> str:
    """Root entity of a camera's head calibration."""
    return f"cameras/{camera}/head"


def display_rows(camera: Mapping[str, Any]) -> list[tuple[str, float, float, str, bool]]:
    """``(name, value, sigma, unit, estimated)`` in display units, in HEAD_PARAMETERS order."""
    values, std = camera["values"], camera["std"]
    estimated = set(camera.get("estimated", []))
    rows = []
    for _, names, factor, unit in HEAD_GROUPS_DISPLAY:
        for name in names:
            i = HEAD_PARAMETERS.index(name)
            rows.append((name, factor * float(values[i]), factor * float(std[i]), unit, name in estimated))
    order = {n: k for k, n in enumerate(HEAD_PARAMETERS)}
    return sorted(rows, key=lambda r: order[r[0]])


def head_markdown(camera_id: str, camera: Mapping[str, Any], title: str = "head errors") -> str:
    """A camera's calibration as a markdown table."""
    lines = [f"### {camera_id}: {title}", "", "| parameter | estimate | 1σ | unit | |", "|---|---:|---:|---|---|"]
    for name, value, sigma, unit, est in display_rows(camera):
        lines.append(f"| {name} | {value:+.5g} | {sigma:.3g} | {unit} | {'estimated' if est else 'pinned (ideal)'} |")
    return "\n".join(lines)


def log_head_calibration(rec: rr.RecordingStream, block: Mapping[str, Any], title: str = "head errors",
                         sub: str = "") -> None:
    """Log a ``head_calibration`` block (static): per camera the table and the bar charts, under
    ``cameras/<id>/head`` (or ``cameras/<id>/head/<sub>``)."""
    for cid, camera in block["cameras"].items():
        base = head_entity(cid) + (f"/{sub}" if sub else "")
        rec.log(f"{base}/summary", rr.TextDocument(head_markdown(cid, camera, title), media_type=rr.MediaType.MARKDOWN),
                static=True)
        rows = {r[0]: r for r in display_rows(camera)}
        for group, names, _, _ in HEAD_GROUPS_DISPLAY:  # estimate at x = k, its 1-sigma beside it at k + 0.4
            k = np.arange(len(names), dtype=float)
            rec.log(f"{base}/{group}", rr.BarChart(np.array([rows[n][1] for n in names]), abscissa=k,
                                                   widths=np.full(len(names), 0.4), color=ESTIMATE_BAR), static=True)
            rec.log(f"{base}/{group}_sigma", rr.BarChart(np.array([rows[n][2] for n in names]), abscissa=k + 0.4,
                                                         widths=np.full(len(names), 0.4), color=SIGMA_BAR),
                    static=True)


def log_drift_check(rec: rr.RecordingStream, report: Mapping[str, Any]) -> None:
    """Log a ``head_check.json`` report: the running drift test per camera on the ``head_check``
    timeline (step k = after the k-th reading), and the updated calibration (static)."""
    updated = {}
    for cid, camera in report["cameras"].items():
        base = f"{head_entity(cid)}/drift"
        steps = camera.get("steps", [])
        for k, step in enumerate(steps, start=1):
            rec.set_time(TIMELINE, sequence=k)
            for series, key in DRIFT_SERIES:
                rec.log(f"{base}/{series}", rr.Scalars([float(step[key])]))
            rec.log(f"{base}/drifted", rr.Scalars([1.0 if step["drifted"] else 0.0]))
            rec.log(f"{base}/log", rr.TextLog(
                f"{step['mote']}: tilt index change {step['tilt_index_change_deg']:+.4f}±"
                f"{step['tilt_index_change_std_deg']:.4f}°, log LR {step['log_lr']:.1f}: "
                f"{'DRIFT' if step['drifted'] else 'no drift'}", level="WARN" if step["drifted"] else "INFO"))
        if "updated" in camera:
            updated[cid] = camera["updated"]["head_calibration"]
    rec.reset_time()
    if updated:
        log_head_calibration(rec, {"cameras": updated}, title="head errors after the drift check", sub="updated")


def write_head_check_rrd(path: str | os.PathLike[str], report: Mapping[str, Any],
                         head_calibration: Mapping[str, Any] | None = None) -> Path:
    """An .rrd of a drift check (and the calibration it was checked against), one tab per camera."""
    import rerun.blueprint as rrb

    from fgloc.viz.blueprint import head_views
    from fgloc.viz.recording import close_recording, open_recording

    path = Path(path)
    blueprint = rrb.Blueprint(rrb.Tabs(*head_views(list(report["cameras"]), drift=True)),
                              rrb.TimePanel(state="expanded"), collapse_panels=True)
    rec = open_recording(path, blueprint=blueprint)
    try:
        if head_calibration:
            log_head_calibration(rec, head_calibration, title="head errors checked against")
        log_drift_check(rec, report)
    finally:
        close_recording(rec)
    return path
