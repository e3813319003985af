"""Sweeps over many simulated scenes (Monte Carlo, deployment planning): the parallel seam.

Each trial is independent: it simulates one scene from a small frozen
dataclass, solves it and scores it against its truth. Trials share nothing,
so a sweep is an embarrassingly parallel ``map``. The seam is any object with
``map(fn, iterable)`` returning results in order:

* nothing (``executor=None``): the built-in ``map``, in this process;
* ``concurrent.futures.ProcessPoolExecutor()``: all local cores;
* Dask: ``distributed.Client(address).get_executor()`` (a ``concurrent.futures``
  executor running on the cluster);
* Ray: ``ray.util.multiprocessing.Pool()`` (``Pool.map``).

What crosses the seam is plain data (a :class:`~fgloc.sim.bench_scenes.BenchScene`
in, a :class:`TrialOutcome` out), never a GTSAM graph: graphs holding Python
``CustomFactor``s cannot be pickled, so every worker builds its own.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from fgloc.evaluate.score import score
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.solve.joint import solve_survey


class MapExecutor(Protocol):
    """The one method the seam needs (``concurrent.futures.Executor``, Ray's ``Pool``)."""

    def map(self, fn: Callable[[Any], Any], iterable: Iterable[Any]) -> Iterable[Any]: ...


@dataclass(frozen=True)
class TrialOutcome:
    """Scored result of one scene: position errors in baseline units, ANEES, wall time."""

    scene: BenchScene
    n_observations: int
    median_error: float
    rms_error: float
    anees: float
    iterations: int
    seconds: float


def run_trial(scene: BenchScene) -> TrialOutcome:
    """Simulate, solve (with marginals) and score one scene. Pure: same scene, same numbers."""
    t0 = time.perf_counter()
    survey = scene_survey(scene)
    result = solve_survey(survey)
    s = score(survey, result)
    assert result.stats is not None
    return TrialOutcome(
        scene=scene,
        n_observations=len(survey.observations),
        median_error=s.median,
        rms_error=s.rms,
        anees=s.anees,
        iterations=result.stats.iterations,
        seconds=time.perf_counter() - t0,
    )


def run_sweep(scenes: Iterable[BenchScene], executor: MapExecutor | None = None) -> list[TrialOutcome]:
    """Run :func:`run_trial` on every scene, in order, through ``executor`` if given."""
    mapper = executor.map if executor is not None else map
    return list(mapper(run_trial, list(scenes)))
