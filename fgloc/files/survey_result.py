"""Read and write survey.json and result.json (``shared/spec/survey-format.md``, version 1).

Reading validates everything a solver relies on and raises :class:`FileFormatError`
with one line naming the file, the field and the offending value. Unknown extra
fields are ignored. Writes are atomic: a temporary file in the same directory is
written, flushed, fsynced and renamed over the target.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from fgloc.core.errors import FileFormatError
from fgloc.core.geometry import is_rotation
from fgloc.core.model import (
    CameraPose,
    FlaggedObservation,
    Gauge,
    NodeEstimate,
    NodeMode,
    Observation,
    Result,
    SolveStats,
    Survey,
    Truth,
)
from fgloc.files.json_io import JsonFields, show_value, write_json_atomic

SURVEY_FORMAT = "fgloc-survey"
RESULT_FORMAT = "fgloc-result"
FORMAT_VERSION = 1


def _check_header(r: JsonFields, data: dict, expected_format: str) -> None:
    fmt = r.get(data, "format", "")
    if fmt != expected_format:
        raise r.fail("format", f"expected {show_value(expected_format)}, got {show_value(fmt)}")
    version = r.get(data, "version", "")
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise r.fail("version", f"unsupported version {show_value(version)} (this reader knows {FORMAT_VERSION})")


def _mode(r: JsonFields, data: dict) -> NodeMode:
    value = r.get(data, "nodes", "")
    try:
        return NodeMode(value)
    except ValueError:
        raise r.fail("nodes", f'expected "planar" or "3d", got {show_value(value)}') from None


def _camera_pose(r: JsonFields, value: Any, name: str) -> CameraPose:
    obj = r.obj(value, name)
    position = r.vector(r.get(obj, "position", name), f"{name}.position", 3)
    rotation = r.matrix(r.get(obj, "rotation", name), f"{name}.rotation", 3)
    if not is_rotation(rotation, tol=1e-5):
        raise r.fail(f"{name}.rotation", "not a proper rotation matrix (R^T R = I, det = +1)")
    return CameraPose(position=position, rotation=rotation)


def read_survey(path: str | os.PathLike[str]) -> Survey:
    """Read and validate a survey.json file."""
    r, data = JsonFields.load(path, FileFormatError)
    _check_header(r, data, SURVEY_FORMAT)
    mode = _mode(r, data)
    sigma = r.number(r.get(data, "sigma", ""), "sigma", positive=True)

    cameras = r.array(r.get(data, "cameras", ""), "cameras")
    camera_ids = [
        r.ident(r.get(r.obj(c, f"cameras[{i}]"), "id", f"cameras[{i}]"), f"cameras[{i}].id")
        for i, c in enumerate(cameras)
    ]
    r.unique_ids(camera_ids, "cameras")
    node_ids = [r.ident(n, f"node_ids[{i}]") for i, n in enumerate(r.array(r.get(data, "node_ids", ""), "node_ids"))]
    r.unique_ids(node_ids, "node_ids")

    gauge_obj = r.obj(r.get(data, "gauge", ""), "gauge")
    origin = r.ident(r.get(gauge_obj, "origin", "gauge"), "gauge.origin")
    baseline = r.ident(r.get(gauge_obj, "baseline", "gauge"), "gauge.baseline")
    known_cameras = set(camera_ids)
    for name, cam in (("gauge.origin", origin), ("gauge.baseline", baseline)):
        if cam not in known_cameras:
            raise r.fail(name, f"camera {show_value(cam)} is not in cameras")
    if origin == baseline:
        raise r.fail("gauge.baseline", f"must differ from gauge.origin, both are {show_value(origin)}")

    known_nodes = set(node_ids)
    observations: list[Observation] = []
    for i, item in enumerate(r.array(r.get(data, "observations", ""), "observations")):
        where = f"observations[{i}]"
        o = r.obj(item, where)
        cam = r.ident(r.get(o, "camera", where), f"{where}.camera")
        if cam not in known_cameras:
            raise r.fail(f"{where}.camera", f"unknown camera {show_value(cam)}")
        node = r.ident(r.get(o, "node", where), f"{where}.node")
        if node not in known_nodes:
            raise r.fail(f"{where}.node", f"unknown node {show_value(node)}")
        pan = r.number(r.get(o, "pan", where), f"{where}.pan")
        tilt = r.number(r.get(o, "tilt", where), f"{where}.tilt")
        if abs(tilt) > math.pi / 2 + 1e-9:
            raise r.fail(f"{where}.tilt", f"must lie in [-pi/2, pi/2], got {show_value(tilt)}")
        obs_sigma = r.get(o, "sigma", where, required=False)
        obs_subset = r.get(o, "subset", where, required=False)
        if obs_subset is not None and (isinstance(obs_subset, bool) or not isinstance(obs_subset, int) or obs_subset < 0):
            raise r.fail(f"{where}.subset", f"expected a non-negative integer, got {show_value(obs_subset)}")
        observations.append(
            Observation(
                camera=cam,
                node=node,
                pan=pan,
                tilt=tilt,
                sigma=None if obs_sigma is None else r.number(obs_sigma, f"{where}.sigma", positive=True),
                subset=obs_subset,
            )
        )

    truth = None
    truth_value = r.get(data, "truth", "", required=False)
    if truth_value is not None:
        t = r.obj(truth_value, "truth")
        cams_obj = r.obj(r.get(t, "cameras", "truth", required=False) or {}, "truth.cameras")
        nodes_obj = r.obj(r.get(t, "nodes", "truth", required=False) or {}, "truth.nodes")
        truth = Truth(
            cameras={k: _camera_pose(r, v, f"truth.cameras.{k}") for k, v in cams_obj.items()},
            nodes={k: r.vector(v, f"truth.nodes.{k}", 3) for k, v in nodes_obj.items()},
        )
    return Survey(
        mode=mode,
        gauge=Gauge(origin=origin, baseline=baseline),
        sigma=sigma,
        camera_ids=camera_ids,
        node_ids=node_ids,
        observations=observations,
        truth=truth,
    )


def _pose_json(pose: CameraPose) -> dict:
    return {"position": [float(v) for v in pose.position], "rotation": np.asarray(pose.rotation, float).tolist()}


def survey_to_json(survey: Survey) -> dict:
    """The survey as a JSON-ready dict per the spec."""
    data: dict[str, Any] = {
        "format": SURVEY_FORMAT,
        "version": FORMAT_VERSION,
        "nodes": survey.mode.value,
        "gauge": {"origin": survey.gauge.origin, "baseline": survey.gauge.baseline},
        "sigma": survey.sigma,
        "cameras": [{"id": c} for c in survey.camera_ids],
        "node_ids": list(survey.node_ids),
        "observations": [
            {"camera": o.camera, "node": o.node, "pan": o.pan, "tilt": o.tilt}
            | ({} if o.sigma is None else {"sigma": o.sigma})
            | ({} if o.subset is None else {"subset": o.subset})
            for o in survey.observations
        ],
    }
    if survey.truth is not None:
        data["truth"] = {
            "cameras": {k: _pose_json(v) for k, v in survey.truth.cameras.items()},
            "nodes": {k: [float(x) for x in v] for k, v in survey.truth.nodes.items()},
        }
    return data


def result_to_json(result: Result) -> dict:
    """The result as a JSON-ready dict per the spec, plus fgloc's extra fields."""
    data: dict[str, Any] = {
        "format": RESULT_FORMAT,
        "version": FORMAT_VERSION,
        "nodes": {
            k: {"position": [float(x) for x in v.position], "covariance": np.asarray(v.covariance, float).tolist()}
            for k, v in result.nodes.items()
        },
        "cameras": {k: _pose_json(v) for k, v in result.cameras.items()},
        "unlocalized": dict(result.unlocalized),
        # Extra fields (allowed by the spec: readers ignore unknown fields).
        "mode": result.mode.value,
        "flagged_observations": [
            {"camera": f.camera, "node": f.node, "index": f.index,
             # JSON has no infinity: null means "the node could not be placed without this reading".
             "whitened_residual": f.whitened_residual if math.isfinite(f.whitened_residual) else None}
            for f in result.flagged
        ],
    }
    if result.stats is not None:
        s = result.stats
        data["solver"] = {
            "method": s.method,
            "iterations": s.iterations,
            # Informational; an incremental solver may not know them (NaN -> null).
            "initial_error": s.initial_error if math.isfinite(s.initial_error) else None,
            "final_error": s.final_error if math.isfinite(s.final_error) else None,
            "converged": s.converged,
            "stage_seconds": s.stage_seconds,
            "error_history": s.error_history,
        }
    return data


def write_survey(survey: Survey, path: str | os.PathLike[str]) -> None:
    """Atomically write a survey.json file."""
    write_json_atomic(survey_to_json(survey), path)


def write_result(result: Result, path: str | os.PathLike[str]) -> None:
    """Atomically write a result.json file."""
    write_json_atomic(result_to_json(result), path)


def _residual_or_inf(r: JsonFields, value: object, name: str) -> float:
    """A flagged reading's whitened residual; null (or absent) stands for infinity."""
    return math.inf if value is None else r.number(value, name)


def read_result(path: str | os.PathLike[str]) -> Result:
    """Read and validate a result.json file (fgloc's extra fields are optional)."""
    r, data = JsonFields.load(path, FileFormatError)
    _check_header(r, data, RESULT_FORMAT)
    nodes_obj = r.obj(r.get(data, "nodes", ""), "nodes")
    nodes: dict[str, NodeEstimate] = {}
    dims: set[int] = set()
    for k, v in nodes_obj.items():
        where = f"nodes.{k}"
        o = r.obj(v, where)
        position = r.vector(r.get(o, "position", where), f"{where}.position", 3)
        cov_rows = r.array(r.get(o, "covariance", where), f"{where}.covariance")
        if len(cov_rows) not in (2, 3):
            raise r.fail(f"{where}.covariance", f"expected a 2x2 or 3x3 matrix, got {show_value(cov_rows)}")
        cov = r.matrix(cov_rows, f"{where}.covariance", len(cov_rows))
        dims.add(len(cov_rows))
        nodes[k] = NodeEstimate(position=position, covariance=cov)
    if len(dims) > 1:
        raise r.fail("nodes", "covariances mix 2x2 and 3x3 matrices")
    mode_value = data.get("mode")
    if mode_value in ("planar", "3d"):
        mode = NodeMode(mode_value)
    else:
        mode = NodeMode.THREE_D if dims == {3} else NodeMode.PLANAR
    cams_obj = r.obj(r.get(data, "cameras", ""), "cameras")
    cameras = {k: _camera_pose(r, v, f"cameras.{k}") for k, v in cams_obj.items()}
    unloc_obj = r.obj(r.get(data, "unlocalized", "", required=False) or {}, "unlocalized")
    unlocalized = {}
    for k, v in unloc_obj.items():
        if not isinstance(v, str):
            raise r.fail(f"unlocalized.{k}", f"expected a reason string, got {show_value(v)}")
        unlocalized[k] = v
    flagged = []
    for i, f in enumerate(r.array(data.get("flagged_observations", []), "flagged_observations")):
        where = f"flagged_observations[{i}]"
        fo = r.obj(f, where)
        flagged.append(
            FlaggedObservation(
                camera=r.ident(r.get(fo, "camera", where), f"{where}.camera"),
                node=r.ident(r.get(fo, "node", where), f"{where}.node"),
                index=int(r.number(r.get(fo, "index", where), f"{where}.index")),
                whitened_residual=_residual_or_inf(r, fo.get("whitened_residual"), f"{where}.whitened_residual"),
            )
        )
    stats = None
    solver = data.get("solver")
    if isinstance(solver, dict):
        try:
            stats = SolveStats(
                method=str(solver["method"]),
                iterations=int(solver["iterations"]),
                initial_error=float(solver["initial_error"]),
                final_error=float(solver["final_error"]),
                converged=bool(solver["converged"]),
                stage_seconds={str(k): float(v) for k, v in solver.get("stage_seconds", {}).items()},
                error_history=[float(e) for e in solver.get("error_history", [])],
            )
        except (KeyError, TypeError, ValueError):
            stats = None  # informational only; never reject a result for it
    return Result(mode=mode, nodes=nodes, cameras=cameras, unlocalized=unlocalized, flagged=flagged, stats=stats)
