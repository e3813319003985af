"""The self-calibrating solve on the node-eliminated fast path.

:func:`solve_self_calibrated_eliminated` is
:func:`fgloc.solve.self_calibration.solve_self_calibrated` with the nodes eliminated in
closed form: the camera graph of :func:`fgloc.solve.eliminated.build_eliminated` with
one head calibration vector per camera (one lever arm per zoom group) as an extra camera-side variable
(:mod:`fgloc.factors.camera_side`), the same datasheet prior, gauge and start. Same
optimum and marginals as the reference graph (``tests/test_camera_side.py``).

The returned :class:`~fgloc.solve.self_calibration.SelfCalibratedSolve` carries the
reference problem (built, not optimized) with the fast optimum's values, nodes
included, so the statistics of :mod:`fgloc.solve.self_calibration` (residual
flagging, likelihood ratios, reports) read it as they read a reference solve.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.core.head_model import head_dim, zoom_groups
from fgloc.core.model import Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.eliminated import (
    HeadSpec,
    build_eliminated,
    camera_covariance,
    collect_eliminated,
    optimize_eliminated,
)
from fgloc.solve.joint import RobustKernel, SolverOptions


def solve_self_calibrated_eliminated(
    survey: Survey, start: InitialEstimate, active: dict[str, tuple[int, ...]], options: SolverOptions,
    exclude: frozenset[int], prior_sigmas: FloatArray,
):  # type: ignore[no-untyped-def]  # -> SelfCalibratedSolve (imported lazily: no import cycle)
    """Optimize the extended problem with nodes eliminated; marginals by back-substitution."""
    from dataclasses import replace

    from fgloc.solve.self_calibration import SelfCalibratedSolve, build_self_calibration_problem

    gaussian = replace(options, robust=RobustKernel.NONE)
    fast = build_eliminated(survey, start, gaussian, exclude, HeadSpec(active, None, prior_sigmas))
    outcome = optimize_eliminated(fast, gaussian)
    result = collect_eliminated(fast, outcome, gaussian)
    values = fast.node_values(outcome.values)
    heads: dict[str, tuple[FloatArray, FloatArray]] = {}
    sigma = camera_covariance(fast, outcome.values) if fast.head_keys and options.compute_marginals else None
    offsets = dict(zip(fast.readings.keys, np.cumsum([0] + fast.readings.dims[:-1]).tolist()))
    zooms, _ = zoom_groups(survey)
    for cid in survey.camera_ids:
        d = head_dim(len(zooms[cid]))
        vals, cov = np.zeros(d), np.zeros((d, d))
        if cid in fast.head_keys:
            idx = list(fast.active[cid])
            key = fast.head_keys[cid]
            vals[idx] = np.asarray(outcome.values.atVector(key))
            if sigma is not None:
                o = int(offsets[key])
                cov[np.ix_(idx, idx)] = sigma[o:o + len(idx), o:o + len(idx)]
        heads[cid] = (vals, cov)
    problem = build_self_calibration_problem(survey, start, active, None, gaussian, exclude, prior_sigmas)
    return SelfCalibratedSolve(problem, values, result, heads, 2.0 * problem.data_error(values))
