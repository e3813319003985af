"""The sweep seam: trials are pure, so any executor gives the same outcomes in the same order."""

from concurrent.futures import ProcessPoolExecutor

import numpy as np

from fgloc.evaluate.sweep import run_sweep
from fgloc.sim.bench_scenes import BenchScene


def test_process_pool_sweep_equals_serial_sweep() -> None:
    scenes = [BenchScene(40, 3, seed=s) for s in range(3)]
    serial = run_sweep(scenes)
    with ProcessPoolExecutor(max_workers=2) as pool:
        parallel = run_sweep(scenes, pool)
    assert [t.scene for t in parallel] == scenes
    for a, b in zip(serial, parallel):
        assert a.n_observations == b.n_observations
        assert np.isclose(a.rms_error, b.rms_error, rtol=1e-12)
        assert np.isclose(a.anees, b.anees, rtol=1e-9)
    # Physical sanity (0.1 degree bearings over a unit field): errors are millimetres of a unit baseline.
    assert all(0 < t.rms_error < 0.02 for t in serial)
