"""Plan files: the site description in, plan.json and a rig.json skeleton out.

Site file (JSON, metres, degrees)::

    {"field": {"polygon": [[0, 0], [100, 0], [100, 100], [0, 100]], "nodes": 500, "seed": 0},
     "sites": [{"id": "mast-a", "xy": [-5, 50], "heights": [3, 6]}],
     "grid": {"bounds": [-10, -10, 110, 110], "step": 20, "heights": [3, 8]},
     "visibility": {"min_range": 2, "max_range": 150, "occluders": [[[40, 40], [60, 40], [60, 60]]]},
     "sigma_deg": 0.1}

``field.nodes`` is a count (drawn uniformly in the polygon, by ``seed``) or a list of
expected node positions. ``sites`` and ``grid`` may both be given. Every problem is one
line ``FILE: FIELD: problem (value)`` (:class:`fgloc.core.errors.FileFormatError`).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from fgloc.core.errors import FileFormatError
from fgloc.files.json_io import check, load_json, show_value, write_json_atomic
from fgloc.plan.placement import PlacementPlan
from fgloc.plan.site import PlanProblem, Visibility, grid_sites, sample_polygon


def _fail(path: str | os.PathLike[str], name: str, problem: str) -> FileFormatError:
    return FileFormatError(f"{path}: {name}: {problem}")


def read_site_file(path: str | os.PathLike[str], sigma_deg: float | None = None) -> tuple[PlanProblem, np.ndarray | None]:
    """The planning problem of a site file and its field polygon (None when nodes are listed).

    The structure is checked against ``fgloc/files/schemas/sites.schema.json``; what a
    schema cannot say (unique ids, ordered bounds, enough sites) is checked here.
    """
    top = load_json(path, FileFormatError)
    check(top, "sites", str(path), FileFormatError)
    field = top["field"]
    polygon = None
    if isinstance(field["nodes"], list):
        nodes = np.array(field["nodes"], float)
    else:
        polygon = np.array(field["polygon"], float)
        nodes = sample_polygon(polygon, int(field["nodes"]), int(field.get("seed", 0)))
    ids: list[str] = []
    xy: list[np.ndarray] = []
    heights: list[float] = []
    for i, site in enumerate(top.get("sites", [])):
        if site["id"] in ids:
            raise _fail(path, f"sites[{i}].id", f"duplicate site id {show_value(site['id'])}")
        for h in site["heights"]:
            ids.append(site["id"])
            xy.append(np.array(site["xy"], float))
            heights.append(float(h))
    if "grid" in top:
        g = top["grid"]
        bounds = np.array(g["bounds"], float)
        if bounds[2] < bounds[0] or bounds[3] < bounds[1]:
            raise _fail(path, "grid.bounds", f"expected [xmin, ymin, xmax, ymax], got {show_value(bounds.tolist())}")
        step = float(g["step"])
        if (bounds[2] - bounds[0]) * (bounds[3] - bounds[1]) / step**2 > 1e5:
            raise _fail(path, "grid.step", f"more than 100000 grid points, got {step:g}")
        gi, gxy, gh = grid_sites(tuple(bounds), step, tuple(float(h) for h in g["heights"]))
        ids += list(gi)
        xy += list(gxy)
        heights += list(gh)
    if len(set(ids)) < 2:
        raise _fail(path, "sites", f"expected at least 2 candidate sites (in sites or grid), got {len(set(ids))}")
    v = top.get("visibility", {})
    vis = Visibility(
        min_range=float(v.get("min_range", 2.0)),
        max_range=float(v.get("max_range", 1e12)),
        occluders=tuple(tuple((float(x), float(y)) for x, y in poly) for poly in v.get("occluders", [])),
    )
    sd = sigma_deg if sigma_deg is not None else float(top.get("sigma_deg", 0.1))
    problem = PlanProblem(nodes, tuple(ids), np.array(xy, float), np.array(heights, float), math.radians(sd), vis)
    return problem, polygon


def plan_document(plan: PlacementPlan) -> dict[str, Any]:
    """plan.json: chosen cameras (gauge pair first), predicted error in metres, per-node RMS."""
    p = plan.problem
    rms = np.sqrt(plan.covariances[:, 0, 0] + plan.covariances[:, 1, 1])
    return {
        "format": "fgloc-plan",
        "objective": plan.objective,
        "sigma_deg": math.degrees(p.sigma),
        "gauge": {"origin": "cam0", "baseline": "cam1", "baseline_m": plan.baseline_m},
        "cameras": [
            {"id": f"cam{i}", "site": p.site_ids[c], "xy_m": p.xy[c].tolist(), "height_m": float(p.heights[c])}
            for i, c in enumerate(plan.chosen)
        ],
        "predicted_error_m": {"median": plan.predicted.median, "p95": plan.predicted.p95,
                              "worst": plan.predicted.worst, "rms": plan.predicted.rms},
        "nodes": [{"xy_m": xy.tolist(), "rms_m": float(r)} for xy, r in zip(p.nodes_xy, rms)],
    }


def rig_skeleton(plan: PlacementPlan) -> dict[str, Any]:
    """A rig.json (docs/survey.md) for the plan: simulated drivers to replace, gauge pair, heights in
    baseline units for ``--simulate``, and the planned sites under ``plan`` (ignored by the reader)."""
    p = plan.problem
    cams = [f"cam{i}" for i in range(len(plan.chosen))]
    intrinsics = {"fx": 440.0, "fy": 440.0, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
    return {
        "format": "fgloc-rig",
        "nodes": "planar",
        "sigma_deg": math.degrees(p.sigma),
        "gauge": {"origin": cams[0], "baseline": cams[1]},
        "cameras": [{"id": c, "driver": "simulated", "model": "EVI-D100", "mounting": "upright", "zoom": 0.0,
                     "intrinsics": dict(intrinsics)} for c in cams],
        "motes": {"driver": "simulated"},
        "node_ids": [f"n{j:03d}" for j in range(len(p.nodes_xy))],
        "simulation": {"seed": 1, "heights": [float(p.heights[c]) / plan.baseline_m for c in plan.chosen]},
        "plan": {c: {"site": p.site_ids[k], "xy_m": p.xy[k].tolist(), "height_m": float(p.heights[k])}
                 for c, k in zip(cams, plan.chosen)},
    }


def write_plan(plan: PlacementPlan, out_dir: str | os.PathLike[str]) -> None:
    """Write plan.json and rig.json into ``out_dir`` (atomic writes)."""
    write_json_atomic(plan_document(plan), os.path.join(out_dir, "plan.json"))
    write_json_atomic(rig_skeleton(plan), os.path.join(out_dir, "rig.json"))
