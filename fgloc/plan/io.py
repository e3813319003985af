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
from fgloc.files.json_io import JsonFields, show_value, write_json_atomic
from fgloc.plan.placement import PlacementPlan
from fgloc.plan.site import PlanProblem, Visibility, grid_sites, sample_polygon


def _points(f: JsonFields, value: Any, name: str, at_least: int) -> np.ndarray:
    rows = f.array(value, name)
    if len(rows) < at_least:
        raise f.fail(name, f"expected at least {at_least} [x, y] points, got {show_value(value)}")
    return np.array([f.vector(r, f"{name}[{i}]", 2) for i, r in enumerate(rows)], float)


def _heights(f: JsonFields, value: Any, name: str) -> tuple[float, ...]:
    hs = f.array(value, name)
    if not hs:
        raise f.fail(name, "expected a non-empty list of heights in metres, got []")
    return tuple(f.number(h, f"{name}[{i}]", positive=True) for i, h in enumerate(hs))


def read_site_file(path: str | os.PathLike[str], sigma_deg: float | None = None) -> tuple[PlanProblem, np.ndarray | None]:
    """The planning problem of a site file and its field polygon (None when nodes are listed)."""
    f, top = JsonFields.load(path, FileFormatError)
    field = f.obj(f.get(top, "field", ""), "field")
    polygon = None
    nodes_raw = f.get(field, "nodes", "field")
    if isinstance(nodes_raw, list):
        nodes = _points(f, nodes_raw, "field.nodes", 4)
    else:
        n = f.number(nodes_raw, "field.nodes", positive=True)
        if n != int(n) or n < 4:
            raise f.fail("field.nodes", f"expected a node count >= 4 or a list of [x, y], got {show_value(nodes_raw)}")
        polygon = _points(f, f.get(field, "polygon", "field"), "field.polygon", 3)
        seed = int(f.number(field.get("seed", 0), "field.seed"))
        nodes = sample_polygon(polygon, int(n), seed)
    ids: list[str] = []
    xy: list[np.ndarray] = []
    heights: list[float] = []
    for i, s in enumerate(f.array(top.get("sites", []), "sites")):
        o = f.obj(s, f"sites[{i}]")
        sid = f.ident(f.get(o, "id", f"sites[{i}]"), f"sites[{i}].id")
        if sid in ids:
            raise f.fail(f"sites[{i}].id", f"duplicate site id {show_value(sid)}")
        pos = f.vector(f.get(o, "xy", f"sites[{i}]"), f"sites[{i}].xy", 2)
        for h in _heights(f, f.get(o, "heights", f"sites[{i}]"), f"sites[{i}].heights"):
            ids.append(sid)
            xy.append(pos)
            heights.append(h)
    if "grid" in top:
        g = f.obj(top["grid"], "grid")
        bounds = f.vector(f.get(g, "bounds", "grid"), "grid.bounds", 4)
        if bounds[2] < bounds[0] or bounds[3] < bounds[1]:
            raise f.fail("grid.bounds", f"expected [xmin, ymin, xmax, ymax], got {show_value(bounds.tolist())}")
        step = f.number(f.get(g, "step", "grid"), "grid.step", positive=True)
        if (bounds[2] - bounds[0]) * (bounds[3] - bounds[1]) / step**2 > 1e5:
            raise f.fail("grid.step", f"more than 100000 grid points, got {step:g}")
        gi, gxy, gh = grid_sites(tuple(bounds), step, _heights(f, f.get(g, "heights", "grid"), "grid.heights"))
        ids += list(gi)
        xy += list(gxy)
        heights += list(gh)
    if len(set(ids)) < 2:
        raise f.fail("sites", f"expected at least 2 candidate sites (in sites or grid), got {len(set(ids))}")
    v = f.obj(top.get("visibility", {}), "visibility")
    occluders = tuple(
        tuple(tuple(p) for p in _points(f, poly, f"visibility.occluders[{i}]", 2).tolist())
        for i, poly in enumerate(f.array(v.get("occluders", []), "visibility.occluders"))
    )
    vis = Visibility(
        min_range=f.number(v.get("min_range", 2.0), "visibility.min_range"),
        max_range=f.number(v.get("max_range", 1e12), "visibility.max_range", positive=True),
        occluders=occluders,
    )
    sd = sigma_deg if sigma_deg is not None else f.number(top.get("sigma_deg", 0.1), "sigma_deg", positive=True)
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
