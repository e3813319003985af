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

``progress`` follows the sweep: a callback ``progress(done, total)`` called as each
trial's outcome arrives, or True for a tqdm bar on stderr (drawn only when stderr is
a terminal).

What crosses the seam is plain data (a :class:`~fgloc.sim.bench_scenes.BenchScene`
in, a :class:`TrialOutcome` out), never a GTSAM graph: graphs holding Python
``CustomFactor``s cannot be pickled, so every worker builds its own.
"""

from __future__ import annotations

import sys
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


def run_sweep(
    scenes: Iterable[BenchScene],
    executor: MapExecutor | None = None,
    progress: Callable[[int, int], None] | bool = False,
) -> list[TrialOutcome]:
    """Run :func:`run_trial` on every scene, in order, through ``executor`` if given.

    ``progress``: ``progress(done, total)`` after each outcome (outcomes arrive in scene order),
    or True for a tqdm bar on stderr (off when stderr is not a terminal)."""
    todo = list(scenes)
    mapper = executor.map if executor is not None else map
    outcomes: list[TrialOutcome] = []
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="sweep", unit="scene", file=sys.stderr, disable=None, leave=False)
    try:
        for outcome in mapper(run_trial, todo):
            outcomes.append(outcome)
            if bar is not None:
                bar.update(1)
            elif callable(progress):
                progress(len(outcomes), len(todo))
    finally:
        if bar is not None:
            bar.close()
    return outcomes
