"""Read and write survey.json and result.json (``docs/file-format.md``, version 1).

Reading checks the file against ``schemas/survey.schema.json`` or
``schemas/result.schema.json``, then what a schema cannot say (ids that must exist,
unique ids, covariance shapes, proper rotations), and raises :class:`FileFormatError`
with one line naming the file, the field and the offending value. Unknown extra
fields are ignored. Writes are atomic: a temporary file in the same directory is
written, flushed, fsynced and renamed over the target.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from fgloc.core.errors import FglocError, FileFormatError
from fgloc.core.geometry import is_rotation
from fgloc.core.model import (
    CameraPose,
    FitReport,
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
from fgloc.files.json_io import (
    POSITION_LIMIT,
    Bulk,
    check,
    is_number,
    is_vector3,
    load_json,
    show_value,
    write_json_atomic,
)

SURVEY_FORMAT = "fgloc-survey"
RESULT_FORMAT = "fgloc-result"
FORMAT_VERSION = 1


def _check_header(data: Any, expected_format: str, path: str) -> None:
    """``format`` and ``version`` pick the schema, so they are checked before it."""
    if not isinstance(data, dict):
        raise FileFormatError(f"{path}: (top level): expected an object, got {show_value(data)}")
    fmt = data.get("format")
    if "format" not in data:
        raise FileFormatError(f"{path}: format: missing required field")
    if fmt != expected_format:
        raise FileFormatError(f"{path}: format: expected {show_value(expected_format)}, got {show_value(fmt)}")
    version = data.get("version")
    if "version" not in data:
        raise FileFormatError(f"{path}: version: missing required field")
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise FileFormatError(
            f"{path}: version: unsupported version {show_value(version)} (this reader knows {FORMAT_VERSION})")


def _is_id(x: object) -> bool:
    return type(x) is str and x != ""


def _plain_observation(o: Any) -> bool:
    """Pre-accepts the common observation (no own sigma or subset, a zoom at most); never laxer than the schema."""
    if type(o) is not dict:
        return False
    tilt: Any = o.get("tilt")
    return (_is_id(o.get("camera")) and _is_id(o.get("node")) and is_number(o.get("pan"))
            and is_number(tilt) and -_TILT_LIMIT <= tilt <= _TILT_LIMIT and "sigma" not in o and "subset" not in o
            and "view" not in o and "sigma_axes" not in o and "view_pan" not in o and "view_tilt" not in o
            and _plain_zoom(o.get("zoom", 0)))


def _plain_zoom(z: Any) -> bool:
    """An absent or plain zoom (a number in [0, 1], as the schema's ``zoom``)."""
    return is_number(z) and 0 <= z <= 1


def _plain_node(v: Any) -> bool:
    """Pre-accepts a result node entry; never laxer than the schema."""
    if type(v) is not dict or not is_vector3(v.get("position")):
        return False
    cov = v.get("covariance")
    return (type(cov) is list and 2 <= len(cov) <= 3
            and all(type(row) is list and all(map(is_number, row)) for row in cov))


_TILT_LIMIT = 1.5707963277948966  # pi/2 + 1e-9, as in survey.schema.json
_SURVEY_BULK: Bulk = {("observations",): _plain_observation, ("node_ids",): _is_id, ("truth", "nodes"): is_vector3}
_RESULT_BULK: Bulk = {("nodes",): _plain_node}


#: Relative tolerance of the covariance checks: asymmetry and the smallest eigenvalue
#: are measured against the largest eigenvalue's magnitude.
COVARIANCE_RTOL = 1e-12


def covariance_problem(cov: np.ndarray) -> str | None:
    """Why ``cov`` (square, finite) is not a covariance: not symmetric, or not positive
    definite (a zero, negative or relatively tiny eigenvalue, within :data:`COVARIANCE_RTOL`
    of the largest), or None when it is one."""
    scale = float(np.max(np.abs(cov))) if cov.size else 0.0
    if not scale > 0 or not math.isfinite(scale):
        return "not positive definite (all zero)" if scale == 0 else "not finite"
    if float(np.max(np.abs(cov - cov.T))) > 1e-6 * scale:
        return "not symmetric"
    eig = np.linalg.eigvalsh(0.5 * (cov + cov.T) / scale)
    if eig[0] <= COVARIANCE_RTOL * eig[-1]:
        return "not positive definite (an eigenvalue <= 0, or singular)"
    return None


def _fail(path: str, field: str, problem: str) -> FileFormatError:
    return FileFormatError(f"{path}: {field}: {problem}")


def _unique(ids: list[str], name: str, path: str) -> None:
    seen: set[str] = set()
    for i, v in enumerate(ids):
        if v in seen:
            raise _fail(path, f"{name}[{i}]", f"duplicate id {show_value(v)}")
        seen.add(v)


def _camera_pose(value: dict, name: str, path: str) -> CameraPose:
    """A schema-checked pose; the rotation must be proper (R^T R = I, det = +1)."""
    rotation = np.array(value["rotation"], dtype=float)
    if not is_rotation(rotation, tol=1e-5):
        raise _fail(path, f"{name}.rotation", "not a proper rotation matrix (R^T R = I, det = +1)")
    return CameraPose(position=np.array(value["position"], dtype=float), rotation=rotation)


#: How far a planar survey's true node may lie off z = 0 (gauge units) and still be "on the plane".
PLANE_TOLERANCE = 1e-6


def truth_from_json(t: dict, mode: str, cameras: set[str], nodes: set[str], path: str,
                    error: type[FglocError] = FileFormatError) -> Truth:
    """A schema-checked truth block (survey.json or journal): ids from the survey, proper
    rotations, planar nodes on z = 0; ``error("PATH: FIELD: problem")`` otherwise."""
    def fail(field: str, problem: str) -> FglocError:
        return error(f"{path}: {field}: {problem}")

    for k in t.get("cameras", {}):
        if k not in cameras:
            raise fail(f"truth.cameras.{k}", f"camera {show_value(k)} is not in cameras")
    for k, v in t.get("nodes", {}).items():
        if k not in nodes:
            raise fail(f"truth.nodes.{k}", f"node {show_value(k)} is not in node_ids")
        if mode == "planar" and abs(v[2]) > PLANE_TOLERANCE:
            raise fail(f"truth.nodes.{k}", f"a planar survey's nodes lie on z = 0, got {show_value(v)}")
    poses = {}
    for k, v in t.get("cameras", {}).items():
        rotation = np.array(v["rotation"], dtype=float)
        if not is_rotation(rotation, tol=1e-5):
            raise fail(f"truth.cameras.{k}.rotation", "not a proper rotation matrix (R^T R = I, det = +1)")
        poses[k] = CameraPose(position=np.array(v["position"], dtype=float), rotation=rotation)
    return Truth(cameras=poses, nodes={k: np.array(v, dtype=float) for k, v in t.get("nodes", {}).items()})


def read_survey(path: str | os.PathLike[str]) -> Survey:
    """Read and validate a survey.json file (angles in radians, truth in the gauge frame)."""
    where = str(path)
    data = load_json(path, FileFormatError)
    _check_header(data, SURVEY_FORMAT, where)
    check(data, "survey", where, FileFormatError, bulk=_SURVEY_BULK)

    camera_ids = [c["id"] for c in data["cameras"]]
    _unique(camera_ids, "cameras", where)
    node_ids: list[str] = data["node_ids"]
    _unique(node_ids, "node_ids", where)
    origin, baseline = data["gauge"]["origin"], data["gauge"]["baseline"]
    known_cameras, known_nodes = set(camera_ids), set(node_ids)
    for name, cam in (("gauge.origin", origin), ("gauge.baseline", baseline)):
        if cam not in known_cameras:
            raise _fail(where, name, f"camera {show_value(cam)} is not in cameras")
    if origin == baseline:
        raise _fail(where, "gauge.baseline", f"must differ from gauge.origin, both are {show_value(origin)}")

    views: dict[str, dict] = data.get("views", {})
    for vid, v in views.items():
        if v["camera"] not in known_cameras:
            raise _fail(where, f"views.{vid}.camera", f"unknown camera {show_value(v['camera'])}")
    observations: list[Observation] = []
    for i, o in enumerate(data["observations"]):
        if o["camera"] not in known_cameras:
            raise _fail(where, f"observations[{i}].camera", f"unknown camera {show_value(o['camera'])}")
        if o["node"] not in known_nodes:
            raise _fail(where, f"observations[{i}].node", f"unknown node {show_value(o['node'])}")
        sigma = o.get("sigma")
        axes = o.get("sigma_axes")
        total = float(data["sigma"]) if sigma is None else float(sigma)
        view = _observation_view(o, i, views, total if axes is None else min(total, *axes), where)
        observations.append(Observation(camera=o["camera"], node=o["node"], pan=float(o["pan"]), tilt=float(o["tilt"]),
                                        sigma=None if sigma is None else float(sigma), subset=o.get("subset"),
                                        view=o.get("view"), view_sigma=None if view is None else float(view["sigma"]),
                                        view_pan=_view_pan(o, view),
                                        sigma_axes=None if axes is None else (float(axes[0]), float(axes[1])),
                                        zoom=None if o.get("zoom") is None else float(o["zoom"]),
                                        view_tilt=None if o.get("view_tilt") is None else float(o["view_tilt"])))

    truth = None
    if "truth" in data:
        truth = truth_from_json(data["truth"], data["nodes"], known_cameras, known_nodes, where)
    return Survey(
        mode=NodeMode(data["nodes"]),
        gauge=Gauge(origin=origin, baseline=baseline),
        sigma=float(data["sigma"]),
        camera_ids=camera_ids,
        node_ids=list(node_ids),
        observations=observations,
        truth=truth,
    )


def _view_pan(o: dict, view: dict | None) -> float | None:
    """An observation's view pan: its own ``view_pan`` (an off-centre reading's view angles), else
    its view's ``pan`` (the ``views`` block), else None."""
    if o.get("view_pan") is not None:
        return float(o["view_pan"])
    return None if view is None or "pan" not in view else float(view["pan"])


def _observation_view(o: dict, i: int, views: dict[str, dict], sigma: float, path: str) -> dict | None:
    """The ``views`` entry an observation names (None without ``view``): it must exist, belong to the
    observation's camera, and its ``sigma`` (the shared head part) must be below the reading's sigma."""
    vid = o.get("view")
    if vid is None:
        return None
    if vid not in views:
        raise _fail(path, f"observations[{i}].view", f"view {show_value(vid)} is not in views")
    view = views[vid]
    if view["camera"] != o["camera"]:
        raise _fail(path, f"observations[{i}].view",
                    f"view {show_value(vid)} belongs to camera {show_value(view['camera'])}, not {show_value(o['camera'])}")
    if not view["sigma"] < sigma:
        raise _fail(path, f"views.{vid}.sigma",
                    f"the shared head part must be below the reading's sigma {sigma} (observations[{i}]), "
                    f"got {show_value(view['sigma'])}")
    return view


def _views_json(survey: Survey) -> dict[str, dict]:
    """The ``views`` block: each view's camera, shared sigma and (when known) head pan, from its readings."""
    out: dict[str, dict] = {}
    for o in survey.observations:
        if o.view is not None and o.view_sigma is not None and o.view not in out:
            out[o.view] = {"camera": o.camera, "sigma": o.view_sigma} | ({} if o.view_pan is None else {"pan": o.view_pan})
    return out


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
            | ({} if o.view is None or o.view_sigma is None else {"view": o.view})
            | ({} if o.sigma_axes is None else {"sigma_axes": list(o.sigma_axes)})
            | ({} if o.zoom is None else {"zoom": o.zoom})
            | ({} if o.view_angles is None else {"view_pan": o.view_angles[0], "view_tilt": o.view_angles[1]})
            for o in survey.observations
        ],
    }
    views = _views_json(survey)
    if views:
        data["views"] = views
    if survey.truth is not None:
        data["truth"] = {
            "cameras": {k: _pose_json(v) for k, v in survey.truth.cameras.items()},
            "nodes": {k: [float(x) for x in v] for k, v in survey.truth.nodes.items()},
        }
    return data


def _unwritable(node: NodeEstimate) -> str | None:
    """Why an estimate is no estimate (diverged, or its covariance undefined), or None."""
    position = np.asarray(node.position, float)
    if not np.all(np.isfinite(position)) or np.max(np.abs(position)) > POSITION_LIMIT:
        return f"its estimate diverged (beyond {POSITION_LIMIT:g} baselines)"
    cov = np.asarray(node.covariance, float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or not np.all(np.isfinite(cov)) or covariance_problem(cov):
        return "its covariance is undefined or singular: the readings do not determine it"
    return None


def result_to_json(result: Result, extra: dict[str, Any] | None = None) -> dict:
    """The result as a JSON-ready dict per the spec, plus fgloc's extra fields.

    ``extra`` adds optional top-level blocks (e.g. ``head_calibration``); readers ignore them.
    """
    nodes, unlocalized = {}, dict(result.unlocalized)
    for k, v in result.nodes.items():
        why = _unwritable(v)
        if why is None:
            nodes[k] = {"position": [float(x) for x in v.position],
                        "covariance": np.asarray(v.covariance, float).tolist()}
        else:  # what read_result would refuse is reported, not written as if it were an estimate
            unlocalized[k] = why
    data: dict[str, Any] = {
        "format": RESULT_FORMAT,
        "version": FORMAT_VERSION,
        "nodes": nodes,
        "cameras": {k: _pose_json(v) for k, v in result.cameras.items()},
        "unlocalized": unlocalized,
        # Extra fields (allowed by the spec: readers ignore unknown fields).
        "mode": result.mode.value,
        "flagged_observations": [
            {"camera": f.camera, "node": f.node, "index": f.index,
             # JSON has no infinity: null means "the node could not be placed without this reading".
             "whitened_residual": f.whitened_residual if math.isfinite(f.whitened_residual) else None}
            for f in result.flagged
        ],
    }
    if result.fit is not None:
        f = result.fit
        data["fit"] = {"chi2": f.chi2, "dof": f.dof, "readings": f.readings,
                       "p_value": f.p_value if math.isfinite(f.p_value) else None,
                       "plausible": f.plausible, "problems": list(f.problems), "notes": list(f.notes)}
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
    if extra:
        data.update(extra)
    return data


def write_survey(survey: Survey, path: str | os.PathLike[str]) -> None:
    """Atomically write a survey.json file."""
    write_json_atomic(survey_to_json(survey), path)


def write_result(result: Result, path: str | os.PathLike[str], extra: dict[str, Any] | None = None) -> None:
    """Atomically write a result.json file (``extra``: optional top-level blocks, see result_to_json)."""
    write_json_atomic(result_to_json(result, extra), path)


def read_result(path: str | os.PathLike[str]) -> Result:
    """Read and validate a result.json file (gauge frame; fgloc's extra fields are optional)."""
    where = str(path)
    data = load_json(path, FileFormatError)
    _check_header(data, RESULT_FORMAT, where)
    check(data, "result", where, FileFormatError, bulk=_RESULT_BULK)

    mode_value = data.get("mode")  # fgloc's extra field: when it names a mode, the covariances must fit it
    stated = NodeMode(mode_value) if mode_value in ("planar", "3d") else None
    nodes: dict[str, NodeEstimate] = {}
    dims: set[int] = set()
    for k, v in data["nodes"].items():
        cov = v["covariance"]
        n = len(cov)
        field = f"nodes.{k}.covariance"
        if any(len(row) != n for row in cov):
            raise _fail(where, field, f"expected a 2x2 or 3x3 matrix, got {show_value(cov)}")
        if stated is not None and n != stated.position_dim:
            d = stated.position_dim
            raise _fail(where, field, f"a {stated.value} result needs a {d}x{d} covariance, got {n}x{n}")
        if dims and n not in dims:
            raise _fail(where, field, f"covariances mix 2x2 and 3x3 matrices, got {n}x{n} after {min(dims)}x{min(dims)}")
        dims.add(n)
        matrix = np.array(cov, dtype=float)
        problem = covariance_problem(matrix)
        if problem is not None:
            raise _fail(where, field, f"{problem}, got {show_value(cov)}")
        if n == 2 and abs(v["position"][2]) > PLANE_TOLERANCE:
            raise _fail(where, f"nodes.{k}.position", f"a planar result's nodes lie on z = 0, got {show_value(v['position'])}")
        nodes[k] = NodeEstimate(position=np.array(v["position"], dtype=float), covariance=matrix)
    mode = stated or (NodeMode.THREE_D if dims == {3} else NodeMode.PLANAR)
    both = sorted(set(nodes) & set(data.get("unlocalized", {})))
    if both:
        raise _fail(where, f"unlocalized.{both[0]}", f"node {show_value(both[0])} is also in nodes (a node is in exactly one)")
    cameras = {k: _camera_pose(v, f"cameras.{k}", where) for k, v in data["cameras"].items()}
    flagged = [
        FlaggedObservation(camera=f["camera"], node=f["node"], index=int(f["index"]),
                           # null (or absent) stands for infinity: no estimate without this reading
                           whitened_residual=math.inf if f.get("whitened_residual") is None
                           else float(f["whitened_residual"]))
        for f in data.get("flagged_observations", [])
    ]
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
    return Result(mode=mode, nodes=nodes, cameras=cameras, unlocalized=dict(data.get("unlocalized", {})),
                  flagged=flagged, stats=stats, fit=_fit(data.get("fit")))


def _fit(fit: Any) -> FitReport | None:
    """The informational ``fit`` block, or None when absent or not as fgloc writes it (never rejected)."""
    if not isinstance(fit, dict):
        return None
    try:
        p = fit.get("p_value")
        report = FitReport(chi2=float(fit["chi2"]), dof=int(fit["dof"]), readings=int(fit["readings"]),
                           p_value=math.nan if p is None else float(p), problems=[str(x) for x in fit["problems"]],
                           notes=[str(x) for x in fit.get("notes", [])])
    except (KeyError, TypeError, ValueError, OverflowError):
        return None
    return report if math.isfinite(report.chi2) else None


def check_against_survey(result: Result, survey: Survey, result_path: str, survey_path: str) -> None:
    """Refuse a result that does not belong to ``survey``: a different mode, ids the
    survey does not have, flagged readings that are not the survey's."""
    if result.mode is not survey.mode:
        d = survey.mode.position_dim
        raise FileFormatError(f"{result_path}: nodes: a {result.mode.value} result (covariances "
                              f"{result.mode.position_dim}x{result.mode.position_dim}) for the {survey.mode.value} "
                              f"survey {survey_path}, which needs {d}x{d}")
    node_ids, camera_ids = set(survey.node_ids), set(survey.camera_ids)
    for name, ids in (("nodes", result.nodes), ("unlocalized", result.unlocalized)):
        for k in ids:
            if k not in node_ids:
                raise FileFormatError(f"{result_path}: {name}.{k}: node {show_value(k)} is not in {survey_path}")
    for k in result.cameras:
        if k not in camera_ids:
            raise FileFormatError(f"{result_path}: cameras.{k}: camera {show_value(k)} is not in {survey_path}")
    for i, f in enumerate(result.flagged):
        obs = survey.observations[f.index] if f.index < len(survey.observations) else None
        if obs is None or (obs.camera, obs.node) != (f.camera, f.node):
            raise FileFormatError(f"{result_path}: flagged_observations[{i}].index: {f.index} is not a reading of "
                                  f"{f.node} by {f.camera} in {survey_path}")
