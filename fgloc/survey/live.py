"""Live estimates during a survey: the journal so far, solved in batch or on iSAM2.

An :class:`Estimator` turns the survey recorded so far into a
:class:`~fgloc.core.model.Result`; the runner calls it after every ``live_every``
nodes once :data:`MIN_SHARED_NODES` nodes are seen by two cameras. Estimates are
advisory: any failure is logged by the runner and the survey goes on.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from fgloc.core.errors import FglocError
from fgloc.core.model import NodeMode, Result, Survey

# Planar, two cameras: 8 camera unknowns after the gauge + 2 per node against 4 readings per
# node, so four nodes are exactly determined (and degenerate in practice); five is the first
# redundant case.
MIN_SHARED_NODES = 5


class Estimator(Protocol):
    """Turns the survey recorded so far into current estimates."""

    def update(self, survey: Survey) -> Result | None:
        """Estimates for ``survey`` (the journal so far), or None when there are none yet."""
        ...


class BatchEstimator:
    """Re-solves the whole survey with :func:`fgloc.solve.joint.solve_survey` each time."""

    def __init__(self, compute_marginals: bool = True) -> None:
        self.compute_marginals = compute_marginals

    def update(self, survey: Survey) -> Result:
        from fgloc.solve.joint import SolverOptions, solve_survey  # gtsam only when asked

        return solve_survey(survey, SolverOptions(compute_marginals=self.compute_marginals))


class IncrementalEstimator:
    """Live estimates from an incremental (iSAM2) localizer, fed each reading exactly once.

    ``factory(camera_ids, gauge, sigma)`` builds the localizer (default:
    ``fgloc.solve.incremental.IncrementalLocalizer``); it must offer
    ``add_observations(list[Observation])`` and ``estimate() -> Result`` (and may say
    ``bootstrapped``: until it does, estimates come from a batch solve). The localizer is
    planar: a 3d survey is always solved in batch. Each update
    passes only the readings the localizer has not seen: the survey's observations only
    ever grow, so within each (node, camera) group the first ones were fed before.
    """

    def __init__(self, factory: Callable[..., object] | None = None) -> None:
        self.factory = factory
        self.localizer: object | None = None
        self._batch = BatchEstimator()
        self._fed: dict[tuple[str, str], int] = {}

    def update(self, survey: Survey) -> Result:
        if survey.mode is not NodeMode.PLANAR:
            # The iSAM2 localizer is planar only: a 3d survey is re-solved in batch.
            return self._batch.update(survey)
        if self.localizer is None:
            factory = self.factory
            if factory is None:
                from fgloc.solve.incremental import IncrementalLocalizer  # type: ignore[import-not-found]

                factory = IncrementalLocalizer
            self.localizer = factory(list(survey.camera_ids), survey.gauge, survey.sigma)
        seen: dict[tuple[str, str], int] = {}
        new = []
        for o in survey.observations:
            k = (o.node, o.camera)
            seen[k] = seen.get(k, 0) + 1
            if seen[k] > self._fed.get(k, 0):
                new.append(o)
        self._fed = seen
        try:
            if new:
                self.localizer.add_observations(new)  # type: ignore[attr-defined]
            if not getattr(self.localizer, "bootstrapped", True):
                # iSAM2 starts from a batch solve once the gauge pair shares enough nodes
                # (12 by default); until then a batch solve of the few readings is cheap.
                return self._batch.update(survey)
            return self.localizer.estimate()  # type: ignore[attr-defined]
        except Exception as exc:  # noqa: BLE001 - GTSAM's RuntimeError, a degenerate start's ValueError, ...
            # The localizer's state is not trusted any more (e.g. GTSAM found an
            # indeterminate system), so the next update starts a new one from every reading.
            self.localizer = None
            self._fed = {}
            raise FglocError(f"incremental estimate: {exc}") from None


@dataclass(frozen=True)
class LiveEstimate:
    """Estimates after ``nodes_done`` nodes, and how long the solve took (seconds)."""

    nodes_done: int
    survey: Survey
    result: Result
    seconds: float


def format_estimate(live: LiveEstimate, limit: int = 5) -> str:
    """A short multi-line summary of a live estimate: node count, worst 1-sigma, a few nodes."""
    r = live.result
    sig = [math.sqrt(max(float(e.covariance[0, 0] + e.covariance[1, 1]), 0.0)) for e in r.nodes.values()
           if e.covariance.size and math.isfinite(float(e.covariance[0, 0]))]
    lines = [f"estimate after {live.nodes_done} nodes: {len(r.nodes)} localized, "
             f"{len(r.unlocalized)} unlocalized, median 1-sigma {sorted(sig)[len(sig) // 2] if sig else float('nan'):.4f}, "
             f"solve {live.seconds:.2f} s"]
    for nid, e in list(r.nodes.items())[-limit:]:
        lines.append(f"  {nid}: ({e.position[0]:.4f}, {e.position[1]:.4f}, {e.position[2]:.4f})")
    return "\n".join(lines)
