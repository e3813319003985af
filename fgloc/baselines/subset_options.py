"""Settings, status words and the error of the subset-Newton baseline (:mod:`fgloc.baselines.subset_newton`)."""

from __future__ import annotations

from dataclasses import dataclass

from fgloc.core.errors import FglocError

STATUS_OK = "ok"


FAILURE_KINDS = ("underdetermined", "degenerate", "no-convergence", "spurious", "non-physical")


class SubsetNewtonError(FglocError):
    """The survey cannot be solved by the subset-Newton baseline."""


@dataclass(frozen=True)
class SubsetNewtonOptions:
    """Settings of the baseline.

    ``subset_size``/``n_subsets`` are used only when the survey's observations
    carry no ``subset`` tags. ``seed`` drives that draw.
    """

    subset_size: int = 10
    n_subsets: int = 50
    seed: int = 0
    max_iterations: int = 100
    restarts: int = 1
    yaw_grid_deg: float = 5.0
    tolx: float = 1e-12  # scaled step below this: converged (NR's TOLX)
    tol_decrement: float = 1e-14  # Gauss-Newton decrement / max(f, 1) below this: converged
    tol_stall: float = 1e-6  # line search stalled with decrement / max(f, 1) below this: converged
    spurious_quantile: float = 0.999
    max_extent: float = 100.0  # baselines; farther nodes are non-physical
