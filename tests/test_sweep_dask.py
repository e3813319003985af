"""Sweeps on Dask: a real 2-worker LocalCluster gives exactly the serial outcomes, in order."""

from dataclasses import replace

import pytest

from fgloc.evaluate.sweep import dask_executor, run_sweep
from fgloc.sim.bench_scenes import BenchScene

pytest.importorskip("distributed")


def test_local_cluster_sweep_equals_serial_sweep() -> None:
    scenes = [BenchScene(20, 3, seed=s) for s in range(6)]
    serial = run_sweep(scenes)
    with dask_executor(n_workers=2, processes=True) as executor:
        seen: list[tuple[int, int]] = []
        distributed = run_sweep(scenes, executor, progress=lambda d, t: seen.append((d, t)))
    assert seen[-1] == (6, 6)
    assert [t.scene for t in distributed] == scenes
    # Same numbers bit for bit (wall time aside): trials are pure and each worker runs one BLAS thread.
    assert [replace(t, seconds=0.0) for t in distributed] == [replace(t, seconds=0.0) for t in serial]


def test_unreachable_scheduler_is_one_line_error() -> None:
    from fgloc.core.errors import FglocError

    with pytest.raises(FglocError, match="cannot reach the scheduler"):
        with dask_executor("tcp://127.0.0.1:9", timeout_s=1.0):
            pass
