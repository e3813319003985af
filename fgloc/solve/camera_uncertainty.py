"""Marginal covariances of the camera base poses of a solved survey.

``solve_survey`` reports node covariances only; this re-linearizes the same
factor graph (:func:`fgloc.solve.joint.build_problem`) at the solution and asks
``gtsam.Marginals`` for each camera's 6x6 covariance in GTSAM's Pose3 tangent
``[omega, v]`` with the right perturbation ``T Exp(xi)``: both blocks are in the
camera *base* frame (rotate by R to get world-frame position uncertainty). The
covariances are relative to the gauge (origin camera and baseline), so the
gauge cameras' pinned components are ~0.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgloc.core.model import Result, Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import SolveError, SolverOptions, build_problem


def camera_covariances(survey: Survey, result: Result, options: SolverOptions = SolverOptions()) -> dict[str, np.ndarray]:
    """Camera id -> 6x6 marginal covariance ([omega (rad), v (gauge units)], base frame)."""
    at = InitialEstimate(
        cameras=dict(result.cameras),
        nodes={n: np.asarray(e.position, dtype=float) for n, e in result.nodes.items()},
        unlocalized=dict(result.unlocalized),
    )
    problem = build_problem(survey, at, options)
    problem.prepare(problem.initial)
    try:
        marginals = gtsam.Marginals(problem.graph.linearize(problem.initial), problem.initial)
        return {cid: np.asarray(marginals.marginalCovariance(key), dtype=float)
                for cid, key in problem.camera_keys.items()}
    except RuntimeError as exc:
        raise SolveError(f"camera covariances are undefined (the graph is rank deficient): {exc}") from None
