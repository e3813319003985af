"""A small generic RANSAC (Fischler & Bolles) with the adaptive iteration count."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.init.homography import DegenerateGeometryError

Model = TypeVar("Model")


def ransac(
    n: int,
    sample_size: int,
    fit: Callable[[np.ndarray], Model],
    residual: Callable[[Model], np.ndarray],
    threshold: float,
    rng: np.random.Generator,
    confidence: float = 0.999,
    max_iterations: int = 1000,
    what: str = "the readings",
) -> tuple[Model, np.ndarray]:
    """Best model by inlier count, refitted on its inliers, and the inlier mask (n,).

    ``fit(indices)`` fits a model to the given items (may raise ``ValueError``
    or ``np.linalg.LinAlgError`` or ``FglocError`` for a degenerate sample);
    ``residual(model)`` gives one non-negative residual per item; items with
    residual below ``threshold`` are inliers. When no sample gives a model that
    ``sample_size`` items agree with, raises :class:`DegenerateGeometryError` naming
    ``what`` was being fitted ("the bearings cam0 and cam1 share").
    """
    if n < sample_size:
        raise DegenerateGeometryError(f"{what}: {n} items, at least {sample_size} needed")
    best_mask: np.ndarray | None = None
    best_count = -1
    needed = max_iterations
    iteration = 0
    while iteration < min(needed, max_iterations):
        iteration += 1
        sample = rng.choice(n, size=sample_size, replace=False)
        try:
            model = fit(sample)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError, FglocError):  # degenerate sample
            continue
        mask = residual(model) < threshold
        count = int(mask.sum())
        if count > best_count:
            best_count, best_mask, best_model = count, mask, model
            w = count / n
            if w >= 1.0:
                break
            miss = 1.0 - w**sample_size
            if 1e-12 < miss < 1.0:
                needed = int(np.ceil(np.log(1 - confidence) / np.log(miss)))
    if best_mask is None or best_count < sample_size:
        raise DegenerateGeometryError(
            f"{what}: no {sample_size} of the {n} agree on a model within {threshold:.3g} rad (degenerate: "
            "readings all alike, collinear or random; or intrinsics/angles far from what they should be)")
    # Refit on all inliers; keep the refit only if it explains at least as many items.
    try:
        model = fit(np.flatnonzero(best_mask))
    except (ValueError, ArithmeticError, np.linalg.LinAlgError, FglocError):
        return best_model, best_mask
    mask = residual(model) < threshold
    if mask.sum() < best_count:
        return best_model, best_mask
    return model, mask
