"""A scene's consistency: the NEES of all its node positions under their joint covariance.

The nodes of one scene share its camera-pose errors, so their per-node NEES are not
independent samples: the mean over one scene's nodes is not a chi-square mean with 2N
(planar) dof, and a scene whose cameras are a little off moves every node the same way
(:mod:`fgloc.evaluate.score`'s ANEES then leaves its independent-node bounds while every
covariance is right). The joint NEES ``e^T C^-1 e``, ``e`` the stacked node errors and ``C``
their joint covariance, is chi-square with ``d N`` dof (``d`` = 2 planar, 3 in 3d) when the
covariance is honest, however the nodes are correlated; summed over independent scenes
it is chi-square with the summed dof.

``C`` is the node block of the inverse Hessian of the graph the solver optimizes
(:func:`fgloc.solve.joint.build_problem`: the pan-tilt factors of the readings it kept,
the gauge prior, view offsets with their priors) linearized at the result; its diagonal
blocks are the solver's marginal covariances. View offsets are linearized at zero (the
result does not hold their estimates; they change the Jacobians by their own size, a
fraction of a degree). Positions in baseline units, gauge frame.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgloc.core.model import NodeMode, Result, Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import SolverOptions, build_problem


def joint_node_covariance(survey: Survey, result: Result,
                          options: SolverOptions = SolverOptions()) -> tuple[np.ndarray, list[str]]:
    """(dN, dN) joint covariance of the node positions of ``result`` (planar: x, y per node;
    3d: x, y, z), and the node order of its blocks."""
    start = InitialEstimate(cameras=dict(result.cameras),
                            nodes={n: np.asarray(e.position, float) for n, e in result.nodes.items()})
    problem = build_problem(survey, start, options, exclude=frozenset(f.index for f in result.flagged))
    problem.prepare(problem.initial)
    order = list(problem.node_keys)
    d = 2 if survey.mode is NodeMode.PLANAR else 3
    return inverse_hessian_block(problem.graph, problem.initial, [problem.node_keys[n] for n in order], d), order


def inverse_hessian_block(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: list[int],
                          dim: int) -> np.ndarray:
    """The (dim * len(keys))-square block of ``keys`` (each a ``dim``-vector variable, in that
    order) of the inverse Hessian of ``graph`` linearized at ``values``: their joint covariance."""
    linear = graph.linearize(values)
    ordered = sorted(values.keys())
    ordering = gtsam.Ordering()
    for k in ordered:
        ordering.push_back(k)
    information, _ = linear.hessian(ordering)
    dims = values.dims()
    offsets = np.cumsum([0] + [int(dims[k]) for k in ordered])
    where = {k: int(offsets[i]) for i, k in enumerate(ordered)}
    columns = np.concatenate([np.arange(where[k], where[k] + dim) for k in keys])
    covariance = np.linalg.inv(information)[np.ix_(columns, columns)]
    return 0.5 * (covariance + covariance.T)


def joint_nees(survey: Survey, result: Result, truth_nodes: dict[str, np.ndarray],
               options: SolverOptions = SolverOptions()) -> tuple[float, int]:
    """(joint NEES, its dof) of ``result``'s node positions against ``truth_nodes`` (node ->
    position, gauge frame): chi-square with dof = d N when the covariance is honest."""
    value, dof, _covariance, _order = joint_nees_and_covariance(survey, result, truth_nodes, options)
    return value, dof


def joint_nees_and_covariance(survey: Survey, result: Result, truth_nodes: dict[str, np.ndarray],
                              options: SolverOptions = SolverOptions()
                              ) -> tuple[float, int, np.ndarray, list[str]]:
    """:func:`joint_nees` (value, dof) with the joint covariance it used and that covariance's
    node order (:func:`joint_node_covariance`), for callers that also need ``C`` (e.g.
    :func:`fgloc.evaluate.anees_bounds.node_nees_eigenvalues`) without building it twice."""
    covariance, order = joint_node_covariance(survey, result, options)
    d = 2 if survey.mode is NodeMode.PLANAR else 3
    error = np.concatenate([np.asarray(result.nodes[n].position, float)[:d] - np.asarray(truth_nodes[n], float)[:d]
                            for n in order])
    return float(error @ np.linalg.solve(covariance, error)), len(error), covariance, order
