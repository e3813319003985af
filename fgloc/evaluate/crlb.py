"""Cramér–Rao bound on node positions in the gauge frame.

The bound is the inverse Fisher information of the pan-tilt measurement model
at the true configuration, with the gauge fixed exactly as the solver fixes it:
the marginal covariance of the gauge-fixed factor graph linearized at the truth.
For Gaussian pan/tilt noise the Fisher information is ``J^T Sigma^-1 J`` with J
the Jacobian of the predicted angles, which is exactly what GTSAM's
linearization of the whitened pan-tilt factors gives; the gauge prior removes
the 7 unobservable similarity directions and leaks only O(gauge sigma^2).
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray
from fgloc.core.model import NodeMode, Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import SolverOptions, build_problem


def cramer_rao_bound(survey: Survey) -> dict[str, FloatArray]:
    """Per-node CRLB covariance (2x2 planar, 3x3 3d) for every observable node with truth.

    Needs ``survey.truth`` with every camera and observed node.
    """
    truth = survey.truth
    if truth is None:
        raise FglocError("the Cramér–Rao bound needs a survey with truth")
    missing = [c for c in survey.camera_ids if c not in truth.cameras]
    if missing:
        raise FglocError(f"truth: cameras {missing} missing")
    cameras_of: dict[str, set[str]] = {}
    for o in survey.observations:
        cameras_of.setdefault(o.node, set()).add(o.camera)
    # A 3d node needs two cameras to be observable; a planar node one.
    need = 1 if survey.mode is NodeMode.PLANAR else 2
    observed = {n for n, cams in cameras_of.items() if len(cams) >= need}
    start = InitialEstimate(
        cameras=dict(truth.cameras),
        nodes={n: np.asarray(truth.nodes[n], float) for n in survey.node_ids if n in observed and n in truth.nodes},
    )
    problem = build_problem(survey, start, SolverOptions())
    values = problem.initial
    problem.prepare(values)
    marginals = gtsam.Marginals(problem.graph.linearize(values), values)
    return {nid: np.asarray(marginals.marginalCovariance(key)) for nid, key in problem.node_keys.items()}


def crlb_rms(survey: Survey) -> float:
    """Root of the mean trace of the per-node bound: the smallest achievable RMS node error."""
    bound = cramer_rao_bound(survey)
    return float(np.sqrt(np.mean([np.trace(c) for c in bound.values()])))

