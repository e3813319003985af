"""Calibration-only mode: re-read a few known motes with a rig and flag head drift.

After a survey and its solve (``result.json``, with a ``head_calibration`` block when it
was solved with ``--head-model auto|full``), the motes' positions, each camera's base pose
and head calibration are known. :func:`run_head_check` surveys only the listed motes with
every camera through the ordinary survey code (:func:`fgloc.survey.session.run_survey`:
lock, preflight, the real drivers or the rig's twins, an append-only, resumable
``journal.jsonl`` and ``survey.json`` in the output directory), then feeds each camera's
readings, in journal order, to a :class:`fgloc.solve.head_drift.DriftMonitor` built from
the result (pose, calibration, the motes' positions and covariances, the rig's sigma).

The calibration's own uncertainty is left out of the test by default: it was estimated
together with the camera pose and the motes from the same readings, so its error is
largely absorbed by theirs (what a re-read mote tests is the predicted reading, and a
tilt-index error of the calibration is compensated by the fitted base pitch and motes).
With a prior-dominated calibration (docs/head-calibration.md, "Observability") its
marginal sigma, 0.2-0.5 degree, would hide any drift of that size.
``calibration_uncertainty=True`` adds it (the block's ``std`` as a diagonal covariance,
:class:`~fgloc.solve.head_drift.DriftMonitor`'s own treatment): a conservative test.

The report (``head_check.json`` in the output directory, written atomically) holds per
camera the drift test after every reading (running (pan offset, tilt index change)
estimate, its sigma, chi-square and flag) and the updated calibration
(:meth:`DriftMonitor.updated`): the base rotation turned by the pan offset and the tilt
index moved by its change, in the result's ``head_calibration`` block format.
Angles in the report are degrees (``*_deg``); the calibration block keeps result.json's
units (radians, unit-less scales, survey units).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.head_model import HEAD_DIM, HEAD_PARAMETERS, HeadCalibration, head_pan_tilt
from fgloc.core.model import CameraPose, Result, Survey, Truth
from fgloc.files.json_io import load_json, show_value, write_json_atomic
from fgloc.files.rig_config import RigConfig
from fgloc.files.survey_result import read_result
from fgloc.solve.head_drift import DriftCheck, DriftMonitor, KnownMotes, centred_equivalent_reading
from fgloc.survey.session import OpenedRig, open_hardware, open_simulated, run_survey

logger = logging.getLogger(__name__)

REPORT_NAME = "head_check.json"
REPORT_FORMAT = "fgloc-head-check"


@dataclass(frozen=True)
class CheckStep:
    """The drift test of one camera after one more reading (of ``mote``)."""

    mote: str
    check: DriftCheck


@dataclass
class CameraCheck:
    """One camera's check: every step, the final test and the updated pose and calibration."""

    camera: str
    steps: list[CheckStep] = field(default_factory=list)
    pose: CameraPose | None = None
    calibration: HeadCalibration | None = None
    estimated: tuple[str, ...] = ()

    @property
    def final(self) -> DriftCheck | None:
        return self.steps[-1].check if self.steps else None


@dataclass
class HeadCheckReport:
    """What :func:`run_head_check` found, per camera (rig order)."""

    result_path: str
    motes: list[str]
    cameras: dict[str, CameraCheck]
    survey: Survey | None = None

    @property
    def drifted(self) -> list[str]:
        return [c for c, cc in self.cameras.items() if cc.final is not None and cc.final.drifted]

    def to_json(self) -> dict[str, Any]:
        cams: dict[str, Any] = {}
        for cid, cc in self.cameras.items():
            entry: dict[str, Any] = {"steps": [_check_json(s.check) | {"mote": s.mote} for s in cc.steps]}
            if cc.final is not None:
                entry |= _check_json(cc.final)
            if cc.pose is not None and cc.calibration is not None:
                entry["updated"] = {
                    "rotation": np.asarray(cc.pose.rotation).tolist(),
                    "position": [float(x) for x in cc.pose.position],
                    "head_calibration": _block_camera(cc.calibration, cc.estimated),
                }
            cams[cid] = entry
        return {"format": REPORT_FORMAT, "version": 1, "result": self.result_path, "motes": list(self.motes),
                "parameters": list(HEAD_PARAMETERS), "cameras": cams}

    def summary(self) -> str:
        """One line per camera: tilt index change and pan offset with their 1-sigma, chi-square, flag."""
        lines = []
        for cid, cc in self.cameras.items():
            c = cc.final
            if c is None:
                lines.append(f"{cid}: no readings of the listed motes")
                continue
            sd = np.sqrt(np.diag(c.covariance))
            lines.append(
                f"{cid}: tilt index change {math.degrees(c.offset[1]):+.4f}±{math.degrees(sd[1]):.4f}°, "
                f"pan offset {math.degrees(c.offset[0]):+.4f}±{math.degrees(sd[0]):.4f}° "
                f"({c.n_motes} motes, {c.n_readings} readings): log LR {c.llr:.1f} "
                f"{'>=' if c.drifted else '<'} {c.threshold:.1f}: {'DRIFT' if c.drifted else 'no drift'}")
        return "\n".join(lines)


def _check_json(c: DriftCheck) -> dict[str, Any]:
    sd = np.sqrt(np.diag(np.asarray(c.covariance, dtype=float)))
    return {"n_motes": c.n_motes, "n_readings": c.n_readings,
            "pan_offset_deg": math.degrees(float(c.offset[0])), "pan_offset_std_deg": math.degrees(float(sd[0])),
            "tilt_index_change_deg": math.degrees(float(c.offset[1])),
            "tilt_index_change_std_deg": math.degrees(float(sd[1])),
            "chi2": float(c.chi2), "log_lr": float(c.llr), "threshold": float(c.threshold), "drifted": bool(c.drifted)}


def _block_camera(cal: HeadCalibration, estimated: tuple[str, ...]) -> dict[str, Any]:
    std = np.zeros(HEAD_DIM) if cal.covariance is None else np.sqrt(np.clip(np.diag(cal.covariance), 0.0, None))
    return {"estimated": list(estimated), "values": [float(v) for v in cal.values], "std": [float(s) for s in std]}


def read_head_block(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """A result.json's ``head_calibration`` block, checked (None when the result has none):
    per camera ``values`` and ``std`` of 7 finite numbers (std >= 0) and ``estimated`` names."""
    where = str(path)
    data = load_json(path, FglocError)
    block = data.get("head_calibration") if isinstance(data, dict) else None
    if block is None:
        return None
    cams = block.get("cameras") if isinstance(block, dict) else None
    if not isinstance(cams, dict):
        raise FglocError(f"{where}: head_calibration.cameras: expected an object, got {show_value(cams)}")
    for cid, entry in cams.items():
        _vector(entry, "values", where, cid)
        std = _vector(entry, "std", where, cid)
        if np.any(std < 0):
            raise FglocError(f"{where}: head_calibration.cameras.{cid}.std: must be >= 0, got {show_value(list(std))}")
        estimated = entry.get("estimated", [])
        if not isinstance(estimated, list) or any(n not in HEAD_PARAMETERS for n in estimated):
            raise FglocError(f"{where}: head_calibration.cameras.{cid}.estimated: expected parameter names, "
                             f"got {show_value(estimated)}")
    return block


def read_head_calibrations(path: str | os.PathLike[str], cameras: list[str]) -> dict[str, tuple[HeadCalibration,
                                                                                                   tuple[str, ...]]]:
    """Per camera of ``cameras``: the calibration of a result.json's ``head_calibration`` block
    (values; the ``std`` as a diagonal covariance) and the names it estimated. A camera the
    block does not list, or a result without the block, has the ideal head, known exactly."""
    block = read_head_block(path)
    out: dict[str, tuple[HeadCalibration, tuple[str, ...]]] = {c: (HeadCalibration.ideal(), ()) for c in cameras}
    for cid, entry in (block or {}).get("cameras", {}).items():
        if cid in out:
            std = np.array(entry["std"], dtype=float)
            out[cid] = (HeadCalibration(np.array(entry["values"], dtype=float), np.diag(std**2)),
                        tuple(entry.get("estimated", [])))
    return out


def _vector(entry: Any, name: str, where: str, cid: str) -> FloatArray:
    value = entry.get(name) if isinstance(entry, dict) else None
    if (not isinstance(value, list) or len(value) != HEAD_DIM
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise FglocError(f"{where}: head_calibration.cameras.{cid}.{name}: expected {HEAD_DIM} finite numbers, "
                         f"got {show_value(value)}")
    return np.array(value, dtype=float)


@dataclass
class _CheckScene:
    truth: Truth


@dataclass
class _CheckTwin:
    """What the journal needs of a simulated rig: the truth of the checked motes only."""

    scene: _CheckScene


def _opened_for(rig: RigConfig, check_rig: RigConfig, simulate: bool) -> OpenedRig:
    """The devices: the whole rig's twin (its scene needs every node) or the real hardware."""
    if not simulate:
        return open_hardware(check_rig)
    opened = open_simulated(rig)
    truth: Truth = opened.simulated.scene.truth  # type: ignore[attr-defined]
    subset = Truth(cameras=dict(truth.cameras), nodes={n: truth.nodes[n] for n in check_rig.node_ids})
    return replace(opened, simulated=_CheckTwin(_CheckScene(subset)))


def check_motes(rig: RigConfig, result: Result, motes: list[str], where: str) -> None:
    """Refuse motes the rig does not list or the result did not localize, and cameras it lacks."""
    if not motes:
        raise FglocError("--motes: expected a comma-separated list of node ids, got ''")
    for m in motes:
        if m not in rig.node_ids:
            raise FglocError(f"--motes: {m!r} is not in {rig.path}'s node_ids")
        if m not in result.nodes:
            raise FglocError(f"--motes: {m!r} has no position in {where} (not localized)")
    if len(set(motes)) != len(motes):
        raise FglocError(f"--motes: listed twice: {', '.join(sorted({m for m in motes if motes.count(m) > 1}))}")
    for c in rig.camera_ids:
        if c not in result.cameras:
            raise FglocError(f"{where}: cameras: camera {c!r} of {rig.path} has no pose")


def known_motes_for(camera: CameraPose, calibration: HeadCalibration, result: Result, motes: list[str],
                    calibration_uncertainty: bool) -> KnownMotes:
    """The listed motes' predicted readings by ``camera`` and the covariance of the predicted tilts:
    the motes' position covariances (independent), plus the calibration's, shared by every
    prediction, with ``calibration_uncertainty`` (see the module docstring)."""
    positions = {m: np.asarray(result.nodes[m].position, dtype=float) for m in motes}
    covariances = {m: np.asarray(result.nodes[m].covariance, dtype=float) for m in motes}
    known = KnownMotes.from_positions(camera, HeadCalibration(calibration.values), positions, covariances)
    if not calibration_uncertainty or calibration.covariance is None:
        return known
    q = np.array([camera.rotation.T @ (positions[m] - camera.position) for m in motes])
    _, _, _, d_h = head_pan_tilt(q, calibration.values)
    assert d_h is not None
    cov = np.asarray(calibration.covariance, dtype=float)
    return replace(known, pan_covariance=known.pan_covariance + d_h[:, 0] @ cov @ d_h[:, 0].T,
                   tilt_covariance=known.tilt_covariance + d_h[:, 1] @ cov @ d_h[:, 1].T)


def monitor_readings(survey: Survey, result: Result, calibrations: dict[str, tuple[HeadCalibration, tuple[str, ...]]],
                     sigma: float, alpha: float = 1e-3, calibration_uncertainty: bool = False) -> dict[str, CameraCheck]:
    """Feed every reading of ``survey`` (journal order) to its camera's drift monitor, a two-sided
    SPRT with false-alarm probability at most ``alpha`` over the whole sequence
    (:class:`fgloc.solve.head_drift.DriftMonitor`). Off-centre readings (a coded rig's) are
    compared with the calibrated head's prediction at their view
    (:func:`fgloc.solve.head_drift.centred_equivalent_reading`)."""
    motes = sorted({o.node for o in survey.observations})
    monitors = {c: DriftMonitor(known_motes_for(result.cameras[c], calibrations[c][0], result, motes,
                                                calibration_uncertainty), sigma, alpha=alpha)
                for c in survey.camera_ids}
    checks = {c: CameraCheck(c) for c in survey.camera_ids}
    for o in survey.observations:
        pan, tilt = centred_equivalent_reading(o, result.cameras[o.camera], result.nodes[o.node].position,
                                               calibrations[o.camera][0].values)
        check = monitors[o.camera].add(o.node, pan, tilt)
        checks[o.camera].steps.append(CheckStep(o.node, check))
    for c, cc in checks.items():
        if cc.steps:
            cc.pose, updated = monitors[c].updated(result.cameras[c], calibrations[c][0])
            cc.calibration = updated
            est = calibrations[c][1]
            cc.estimated = est if "tilt_index" in est else ("tilt_index", *est)
    return checks


def run_head_check(
    rig: RigConfig,
    result_path: str | os.PathLike[str],
    motes: list[str],
    out_dir: str | os.PathLike[str],
    *,
    simulate: bool = False,
    resume: bool = False,
    repeats: int | None = None,
    alpha: float = 1e-3,
    calibration_uncertainty: bool = False,
    opened: OpenedRig | None = None,
    on_progress: Callable[[Any], None] | None = None,
) -> HeadCheckReport:
    """Re-read ``motes`` with every camera of ``rig``, test each camera for drift against the
    result's calibration, write ``out_dir/head_check.json`` and return the report.

    ``repeats`` readings per mote and camera (default: the rig's); ``opened`` overrides the
    devices (tests). The rig must be the surveyed rig (same cameras and node ids)."""
    where = str(result_path)
    result = read_result(result_path)
    check_motes(rig, result, motes, where)
    calibrations = read_head_calibrations(result_path, rig.camera_ids)
    if repeats is not None and repeats < 1:
        raise FglocError(f"--repeats: must be >= 1, got {repeats}")
    check_rig = replace(rig, node_ids=list(motes), repeats=repeats or rig.repeats, repeat_budget=0)
    own = opened is None
    devices = opened or _opened_for(rig, check_rig, simulate)
    try:
        survey, _ = run_survey(check_rig, out_dir, simulate=simulate, resume=resume, on_progress=on_progress,
                               opened=devices)
    finally:
        if own:
            devices.close()
    checks = monitor_readings(survey, result, calibrations, rig.sigma, alpha, calibration_uncertainty)
    report = HeadCheckReport(where, list(motes), checks, survey)
    write_json_atomic(report.to_json(), Path(out_dir) / REPORT_NAME)
    for cid in report.drifted:
        logger.warning(f"{cid}: head drift flagged against {where}")
    return report
