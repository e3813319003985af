"""Plan the views one camera records in a coded survey: cover the search region in few tiles.

The region is a set of base-frame directions (radians, ``(pan, tilt)`` rows) to cover:
a sampled pan-tilt box (:func:`box_targets`) or the directions of a sampled deployment
area. A view at head (pan, tilt) *covers* a target when the target projects inside the
image at least ``margin_px`` from the border, by the exact composition of
:mod:`fgloc.camera.pixel_angles` (so views near the nadir, whose footprint spans a wide
range of pan, are used as such). Views are chosen greedily (largest number of still
uncovered targets first, candidates on a grid of ``step`` x the field of view), then
ordered nearest-neighbour from the head's start position so slews stay short.
"""

from __future__ import annotations

import math

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import in_image, pan_tilt_to_pixel
from fgloc.core.geometry import pan_tilt_bearing


def box_targets(pan_min: float, pan_max: float, tilt_min: float, tilt_max: float, step: float) -> np.ndarray:
    """(M, 2) (pan, tilt) samples of a box, ``step`` radians apart (the edges included)."""
    pans = np.linspace(pan_min, pan_max, max(2, math.ceil((pan_max - pan_min) / step) + 1))
    tilts = np.linspace(tilt_min, tilt_max, max(2, math.ceil((tilt_max - tilt_min) / step) + 1))
    pp, tt = np.meshgrid(pans, tilts)
    return np.column_stack([pp.ravel(), tt.ravel()])


def coverage(intr: CameraIntrinsics, targets: np.ndarray, views: np.ndarray, margin_px: float) -> np.ndarray:
    """(V, M) bool: view v (head pan, tilt) sees target m at least ``margin_px`` inside the image."""
    out = np.zeros((len(views), len(targets)), dtype=bool)
    for v, (p, t) in enumerate(views):
        uv, front = pan_tilt_to_pixel(intr, targets[:, 0], targets[:, 1], float(p), float(t))
        out[v] = front & in_image(intr, uv, margin_px)
    return out


def plan_views(
    intr: CameraIntrinsics, targets: np.ndarray, margin_px: float = 12.0, step: float = 0.125,
    start: tuple[float, float] = (0.0, 0.0), tilt_limits: tuple[float, float] = (-math.pi / 2, math.pi / 2),
) -> list[tuple[float, float]]:
    """Head positions (pan, tilt) radians whose views cover every target, in visiting order.

    Targets no candidate view can cover (beyond the tilt limits) are left out silently;
    :func:`coverage` tells which are covered.
    """
    targets = np.asarray(targets, dtype=float)
    if targets.size == 0:
        return []
    hfov = 2.0 * math.atan(intr.width / (2.0 * intr.fx))
    vfov = 2.0 * math.atan(intr.height / (2.0 * intr.fy))
    centre = np.mean(pan_tilt_bearing(targets[:, 0], targets[:, 1]), axis=0)
    c_pan = math.atan2(centre[1], centre[0])
    rel = np.remainder(targets[:, 0] - c_pan + math.pi, 2.0 * math.pi) - math.pi + c_pan
    pans = np.arange(rel.min(), rel.max() + step * hfov, step * hfov)
    t_lo = max(float(targets[:, 1].min()), tilt_limits[0])
    t_hi = min(float(targets[:, 1].max()), tilt_limits[1])
    tilts = np.arange(t_lo, t_hi + step * vfov, step * vfov)
    tilts = np.clip(tilts, *tilt_limits)
    cand = np.array([(p, t) for t in tilts for p in pans])
    cov = coverage(intr, targets, cand, margin_px)
    todo = cov.any(axis=0)
    chosen: list[int] = []
    while todo.any():
        gain = (cov & todo).sum(axis=1)
        best = int(np.argmax(gain))
        if gain[best] == 0:
            break
        chosen.append(best)
        todo &= ~cov[best]
    order: list[tuple[float, float]] = []
    here = pan_tilt_bearing(*start)
    left = [(float(cand[i, 0]), float(cand[i, 1])) for i in chosen]
    while left:
        d = [math.acos(min(1.0, float(pan_tilt_bearing(*v) @ here))) for v in left]
        k = int(np.argmin(d))
        order.append(left.pop(k))
        here = pan_tilt_bearing(*order[-1])
    return order
