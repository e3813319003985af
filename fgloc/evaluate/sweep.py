"""Sweeps over many simulated scenes (Monte Carlo, deployment planning): the parallel seam.

Each trial is independent: it simulates one scene from a small frozen
dataclass, solves it and scores it against its truth. Trials share nothing,
so a sweep is an embarrassingly parallel ``map``. The seam is any object with
``map(fn, iterable)`` returning results in order:

* nothing (``executor=None``): the built-in ``map``, in this process;
* ``concurrent.futures.ProcessPoolExecutor()``: all local cores;
* Dask: :func:`dask_executor` (``distributed`` from the ``fgloc[cluster]`` extra):
  a ``LocalCluster`` started here, or the scheduler at an address
  (``tcp://HOST:8786``) of a real cluster whose workers have fgloc installed;
* Ray: ``ray.util.multiprocessing.Pool()`` (``Pool.map``).

``progress`` follows the sweep: a callback ``progress(done, total)`` called as each
trial's outcome arrives, or True for a tqdm bar on stderr (drawn only when stderr is
a terminal).

What crosses the seam is plain data (a :class:`~fgloc.sim.bench_scenes.BenchScene`
in, a :class:`TrialOutcome` out), never a GTSAM graph: graphs holding Python
``CustomFactor``s cannot be pickled, so every worker builds its own.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from fgloc.core.errors import FglocError
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
    scenes: Iterable[Any],
    executor: MapExecutor | None = None,
    progress: Callable[[int, int], None] | bool = False,
    trial: Callable[[Any], Any] = run_trial,
) -> list[Any]:
    """Run ``trial`` (default :func:`run_trial`) on every scene, in order, through ``executor`` if given.

    ``trial`` must be a module-level function (it is pickled to the workers) and pure.
    ``progress``: ``progress(done, total)`` after each outcome (outcomes arrive in scene order),
    or True for a tqdm bar on stderr (off when stderr is not a terminal)."""
    todo = list(scenes)
    mapper = executor.map if executor is not None else map
    outcomes: list[Any] = []
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="sweep", unit="scene", file=sys.stderr, disable=None, leave=False)
    try:
        for outcome in mapper(trial, todo):
            outcomes.append(outcome)
            if bar is not None:
                bar.update(1)
            elif callable(progress):
                progress(len(outcomes), len(todo))
    finally:
        if bar is not None:
            bar.close()
    return outcomes


class DaskExecutor:
    """The seam's ``map`` on a ``distributed.Client``: submits every item, yields results in order."""

    def __init__(self, client: Any) -> None:
        self.client = client

    def map(self, fn: Callable[[Any], Any], iterable: Iterable[Any]) -> Iterator[Any]:
        futures = self.client.map(fn, list(iterable), pure=False)
        try:
            for future in futures:
                yield future.result()
        finally:
            for future in futures:
                future.release()


#: Environment of LocalCluster workers: one BLAS thread each (many small solves).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextmanager
def dask_executor(
    address: str | None = None, n_workers: int = 2, processes: bool = True, timeout_s: float = 10.0
) -> Iterator[DaskExecutor]:
    """A Dask executor for :func:`run_sweep`: the scheduler at ``address``, or a ``LocalCluster`` of
    ``n_workers`` single-threaded workers (processes, or threads with ``processes=False``) started here
    and shut down on exit; ``timeout_s`` bounds the wait for a remote scheduler. Needs ``distributed`` (``pip install 'fgloc[cluster]'``)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise FglocError("dask: the distributed package is not installed (pip install 'fgloc[cluster]')") from None
    cluster = None
    if address:
        try:
            client = Client(address, timeout=f"{timeout_s}s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise FglocError(f"dask: cannot reach the scheduler at {address!r}: {exc}") from None
    else:
        if n_workers < 1:
            raise FglocError(f"dask: workers: must be >= 1 ({n_workers})")
        for var, value in WORKER_ENV.items():
            os.environ.setdefault(var, value)  # inherited by the worker processes
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=processes,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        yield DaskExecutor(client)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
