"""What a plan is about: the field, the candidate camera sites and what each can see.

Everything here is in metres on the ground plane (x, y; z up). Nodes lie on
z = 0. A candidate is one (site, height) pair; a site may offer several heights
but holds at most one camera. Visibility is decided in plan view: a candidate
sees a node when the horizontal distance lies in ``[min_range, max_range]`` and
the ground segment from the camera's foot point to the node crosses no occluder
polygon edge (an occluder is taken to be taller than the line of sight).
``min_range`` keeps nodes away from the head's pole (a pan-tilt head looking
straight down has an undefined pan, see measured pitfalls).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.plan.fisher import Jacobians, jacobians, level_rotation


@dataclass(frozen=True)
class Visibility:
    """Plan-view visibility model: ranges in metres, occluders as polygons (list of (x, y) vertices)."""

    min_range: float = 2.0
    max_range: float = float("inf")
    occluders: tuple[tuple[tuple[float, float], ...], ...] = ()


@dataclass(frozen=True, eq=False)
class PlanProblem:
    """Nodes (N, 2) and candidates: ``site_ids`` (C,), ``xy`` (C, 2), ``heights`` (C,) metres; sigma radians.

    Candidates sharing a ``site_ids`` entry are the heights of one site (at most one is chosen).
    """

    nodes_xy: FloatArray
    site_ids: tuple[str, ...]
    xy: FloatArray
    heights: FloatArray
    sigma: float
    visibility: Visibility = field(default_factory=Visibility)

    def __post_init__(self) -> None:
        if len(self.nodes_xy) < 4:
            raise FglocError(f"field: nodes: a plan needs at least 4 nodes ({len(self.nodes_xy)})")
        if len(set(self.site_ids)) < 2:
            raise FglocError(f"sites: a plan needs at least 2 candidate sites ({len(set(self.site_ids))})")
        if not np.all(np.asarray(self.heights) > 0):
            raise FglocError(f"sites: heights: must be > 0 m ({float(np.min(self.heights))})")
        if not self.sigma > 0:
            raise FglocError(f"sigma: must be > 0 ({self.sigma})")

    @property
    def n_candidates(self) -> int:
        return len(self.site_ids)

    def label(self, c: int) -> str:
        """``site@height`` of candidate ``c``."""
        return f"{self.site_ids[c]}@{self.heights[c]:g}m"

    def positions(self) -> FloatArray:
        """(C, 3) camera positions in metres."""
        return np.column_stack([self.xy, self.heights])

    def rotations(self) -> FloatArray:
        """(C, 3, 3) level bases facing the node centroid."""
        centre = self.nodes_xy.mean(axis=0)
        return np.array([level_rotation(p, centre) for p in self.positions()])

    def visible(self) -> np.ndarray:
        """(C, N) bool: which candidate sees which node."""
        return visibility_mask(self.xy, self.nodes_xy, self.visibility)

    def jacobians(self) -> Jacobians:
        """Whitened Jacobians of every candidate against every node."""
        return jacobians(self.positions(), self.rotations(), self.nodes_xy, self.visible(), self.sigma)


def _segments_cross(p: FloatArray, q: FloatArray, a: FloatArray, b: FloatArray) -> np.ndarray:
    """Whether segments p->q (..., 2) properly cross segment a->b (2,), broadcast."""

    def orient(u: FloatArray, v: FloatArray, w: FloatArray) -> FloatArray:
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])

    d1, d2 = orient(a, b, p), orient(a, b, q)
    d3, d4 = orient(p, q, a), orient(p, q, b)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def visibility_mask(cam_xy: FloatArray, nodes_xy: FloatArray, model: Visibility) -> np.ndarray:
    """(C, N) bool under ``model`` (see the module docstring)."""
    cam = np.asarray(cam_xy, float)[:, None, :]
    nodes = np.asarray(nodes_xy, float)[None, :, :]
    dist = np.linalg.norm(nodes - cam, axis=2)
    seen = (dist >= model.min_range) & (dist <= model.max_range)
    for poly in model.occluders:
        verts = np.asarray(poly, float)
        for a, b in zip(verts, np.roll(verts, -1, axis=0)):
            seen &= ~_segments_cross(np.broadcast_to(cam, dist.shape + (2,)), np.broadcast_to(nodes, dist.shape + (2,)), a, b)
    return seen


def inside_polygon(points: FloatArray, polygon: FloatArray) -> np.ndarray:
    """Ray-casting point-in-polygon test for points (N, 2) and a polygon (V, 2)."""
    x, y = points[:, 0], points[:, 1]
    inside = np.zeros(len(points), bool)
    verts = np.asarray(polygon, float)
    for (x1, y1), (x2, y2) in zip(verts, np.roll(verts, -1, axis=0)):
        crosses = (y1 > y) != (y2 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < x_at)
    return inside


def sample_polygon(polygon: FloatArray, n: int, seed: int = 0) -> FloatArray:
    """``n`` node positions uniform in ``polygon`` (V, 2), deterministic by seed (rejection sampling)."""
    poly = np.asarray(polygon, float)
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    rng = np.random.default_rng(seed)
    out: list[FloatArray] = []
    have = 0
    for _ in range(1000):
        pts = rng.uniform(lo, hi, size=(max(2 * n, 64), 2))
        pts = pts[inside_polygon(pts, poly)]
        out.append(pts)
        have += len(pts)
        if have >= n:
            break
    if have < n:
        raise FglocError(f"field: polygon: has no area to place nodes in ({poly.tolist()})")
    return np.concatenate(out)[:n]


def grid_sites(bounds: tuple[float, float, float, float], step: float, heights: tuple[float, ...],
               exclude: FloatArray | None = None) -> tuple[tuple[str, ...], FloatArray, FloatArray]:
    """Candidates on a grid over ``bounds`` (xmin, ymin, xmax, ymax) every ``step`` metres, each at every height.

    Grid points inside the ``exclude`` polygon (if given) are skipped. Returns (site ids, xy, heights)."""
    xmin, ymin, xmax, ymax = bounds
    xs = np.arange(xmin, xmax + 1e-9 * max(1.0, abs(xmax)), step)
    ys = np.arange(ymin, ymax + 1e-9 * max(1.0, abs(ymax)), step)
    pts = np.array([(x, y) for y in ys for x in xs], float)
    if exclude is not None:
        pts = pts[~inside_polygon(pts, exclude)]
    ids = tuple(f"g{i:03d}" for i in range(len(pts)) for _ in heights)
    xy = np.repeat(pts, len(heights), axis=0)
    hs = np.tile(np.asarray(heights, float), len(pts))
    return ids, xy, hs


def corner_placement(polygon: FloatArray, n_cameras: int) -> FloatArray:
    """The naive placement: the field's bounding-box corners, then edge midpoints, (n, 2) metres."""
    lo, hi = np.asarray(polygon, float).min(axis=0), np.asarray(polygon, float).max(axis=0)
    mid = 0.5 * (lo + hi)
    spots = [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1]),
             (mid[0], lo[1]), (hi[0], mid[1]), (mid[0], hi[1]), (lo[0], mid[1])]
    if n_cameras > len(spots):
        raise FglocError(f"cameras: the naive placement has at most {len(spots)} spots ({n_cameras})")
    return np.array(spots[:n_cameras], float)
