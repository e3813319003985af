"""Test helpers shipped with fgloc (like ``symforce.test_util``): scenes and checks that the
test suite and the stress scripts share.

This module sits at the top of the layers, beside :mod:`fgloc.cli`: it may import any
part of fgloc, and nothing in fgloc imports it.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.model import NodeMode, Survey
from fgloc.init.start import InitialEstimate
from fgloc.sim.scenes import RandomScene, random_scene
from fgloc.solve.joint import build_problem, solve, solve_survey

__all__ = ["reaches_global_optimum", "stress_scene"]


def stress_scene(index: int, mode: NodeMode) -> Survey:
    """The index-th stress scene (deterministic): 2-8 cameras, 20-400 nodes, random visibility.

    ``scripts/stress_scenes.py`` runs scenes 0..N-1; the tests run a seeded sample."""
    rng = np.random.default_rng(index)
    return random_scene(
        RandomScene(
            n_cameras=int(rng.integers(2, 9)),
            n_nodes=int(rng.integers(20, 401)),
            mode=mode,
            visibility=float(rng.uniform(0.5, 1.0)),
            seed=index,
        )
    )


def reaches_global_optimum(survey: Survey, rel_tol: float = 1e-6) -> tuple[bool, float, float]:
    """Solve ``survey`` from fgloc's own start and from the truth: (ok, our final error, the truth's).

    ``ok`` when our final cost is no higher than the cost of the solve started at the
    true scene (within ``rel_tol``): a start in another basin would end higher."""
    ours = solve_survey(survey)
    truth = survey.truth
    assert truth is not None, "reaches_global_optimum needs a simulated survey (with truth)"
    assert ours.stats is not None
    start = InitialEstimate(cameras=dict(truth.cameras), nodes={n: truth.nodes[n] for n in ours.nodes})
    ref = solve(build_problem(survey, start))
    assert ref.stats is not None
    ok = ours.stats.final_error <= ref.stats.final_error * (1 + rel_tol) + 1e-6
    return ok, ours.stats.final_error, ref.stats.final_error
