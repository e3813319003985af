"""Initial guesses of the subset-Newton baseline from the readings alone: level cameras,
yaws from a coarse grid search (lengths in baselines, angles in radians)."""

from __future__ import annotations

import warnings

import numpy as np

from fgloc.baselines.subset_system import SubsetReadings, SubsetState
from fgloc.core.geometry import (
    FloatArray,
    bearing_pan_tilt,
    pan_tilt_bearing,
    rot_z,
)


def _lower_median(values: FloatArray, valid: np.ndarray) -> FloatArray:
    """Lower median of the valid entries along the last axis (NaN where none), keepdims."""
    srt = np.sort(np.where(valid, values, np.inf), axis=-1)
    count = valid.sum(axis=-1, keepdims=True)
    med = np.take_along_axis(srt, np.maximum(count - 1, 0) // 2, axis=-1)
    return np.where(count > 0, med, np.nan)


def level_camera_guesses(obs: SubsetReadings, grid_deg: float = 5.0, n_best: int = 1) -> list[SubsetState]:
    """Generic starts from the readings alone: level cameras, yaws from a grid search.

    For every (yaw0, yaw1) on a ``grid_deg`` grid, the pans triangulate each
    node in the plane (rays from (0, 0) and (1, 0)); its tilts imply camera
    heights; the heights are the medians and the score is the squared tilt
    misfit of that level-camera model (nodes behind a camera or implying a
    negative height cost a fixed penalty). Returns the ``n_best`` best
    candidates per subset as states (best first). Never reads truth.
    """
    S, k = obs.pan.shape[0], obs.k
    # Mean bearing per (subset, camera, slot).
    b = np.where(obs.mask[..., None], pan_tilt_bearing(obs.pan, obs.tilt), 0.0)
    acc = np.zeros((S, 2, k, 3))
    s_idx = np.repeat(np.arange(S)[:, None], obs.pan.shape[1], axis=1)
    np.add.at(acc, (s_idx, obs.camera, obs.slot), b)
    pan, tilt = bearing_pan_tilt(acc)  # (S, 2, k)
    grid = np.deg2rad(np.arange(-180.0, 180.0, grid_deg))
    G = grid.size
    a0 = grid[None, :, None, None] + pan[:, None, None, 0, :]  # (S, G, 1, k)
    a1 = grid[None, None, :, None] + pan[:, None, None, 1, :]  # (S, 1, G, k)
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN medians of hopeless yaw pairs
        den = np.sin(a1 - a0)
        t0 = np.sin(a1) / den
        t1 = np.sin(a0) / den
        h0 = -t0 * np.tan(tilt[:, None, None, 0, :])
        h1 = -t1 * np.tan(tilt[:, None, None, 1, :])
        valid = (t0 > 0) & (t1 > 0) & (h0 > 0) & (h1 > 0) & np.isfinite(h0) & np.isfinite(h1)
        h0m = _lower_median(h0, valid)
        h1m = _lower_median(h1, valid)
        e0 = np.arctan2(-h0m, t0) - tilt[:, None, None, 0, :]
        e1 = np.arctan2(-h1m, t1) - tilt[:, None, None, 1, :]
        cost = np.where(valid, e0**2 + e1**2, 1.0).sum(axis=-1)
    cost = np.where(np.isfinite(cost), cost, np.inf).reshape(S, G * G)
    order = np.argsort(cost, axis=1)[:, :n_best]
    states = []
    for c in range(n_best):
        flat = order[:, c]
        i0, i1 = flat // G, flat % G
        y0, y1 = grid[i0], grid[i1]
        rows = np.arange(S)
        pan0 = y0[:, None] + pan[:, 0, :]
        pan1 = y1[:, None] + pan[:, 1, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            tt0 = np.sin(pan1) / np.sin(pan1 - pan0)
        tt0 = np.where(np.isfinite(tt0), np.clip(tt0, -10.0, 10.0), 0.5)
        xy = np.stack([tt0 * np.cos(pan0), tt0 * np.sin(pan0)], axis=-1)
        hh = np.stack([h0m.reshape(S, G, G)[rows, i0, i1], h1m.reshape(S, G, G)[rows, i0, i1]], axis=1)
        hh = np.where(np.isfinite(hh) & (hh > 0), hh, 0.1)
        R = np.stack([np.stack([rot_z(a), rot_z(b_)]) for a, b_ in zip(y0, y1)])
        states.append(SubsetState(R=R, h=hh, xy=xy))
    return states
