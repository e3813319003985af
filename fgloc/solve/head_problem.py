"""The self-calibration problem: the reference graph with head-model bearing factors.

The extended problem is the reference graph of :func:`fgloc.solve.joint.build_problem`
(same keys, gauge and start) with every pan-tilt factor replaced by a head-model
factor (:mod:`fgloc.factors.pan_tilt_head_factor`), one head-calibration Vector per camera
(key ``h<i>``, :data:`head_key`) holding the parameters chosen for it (its extended vector:
one lever arm per zoom, :func:`fgloc.core.head_model.zoom_groups`), and a zero-mean datasheet
prior on each. Solved and judged in :mod:`fgloc.solve.self_calibration`. Off-centre readings
(``Observation.view_angles``: a coded survey's) are predicted from their view
(:func:`fgloc.core.head_model.head_view_pan_tilt`), centred ones by ``head_pan_tilt``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.core.head_model import (
    DEFAULT_PRIOR_SIGMAS,
    HEAD_DIM,
    extend_vector,
    head_dim,
    reading_params,
    zoom_groups,
)
from fgloc.core.model import Survey
from fgloc.factors.pan_tilt_head_factor import HeadFactorSet, head_prior_factor
from fgloc.init.start import InitialEstimate
from fgloc.solve.joint import LocalizationProblem, RobustKernel, SolverOptions, build_problem

head_key = gtsam.symbol_shorthand.H


@dataclass
class SelfCalibrationProblem(LocalizationProblem):
    """A :class:`LocalizationProblem` whose bearings go through head-model factors."""

    heads: HeadFactorSet | None = None
    head_keys: dict[str, int] = field(default_factory=dict)
    active: dict[str, tuple[int, ...]] = field(default_factory=dict)
    #: Per camera its zoom groups (:func:`fgloc.core.head_model.zoom_groups`): one lever arm each.
    zooms: dict[str, tuple[float | None, ...]] = field(default_factory=dict)

    def prepare(self, values: gtsam.Values) -> None:
        assert self.heads is not None
        self.heads.prepare(values)

    def data_error(self, values: gtsam.Values) -> float:
        """0.5 * chi-square of the bearings alone (no gauge, no head prior)."""
        assert self.heads is not None
        return self.heads.error(values)

    def error(self, values: gtsam.Values) -> float:
        assert self.heads is not None
        rest = sum(self.graph.at(i).error(values) for i in range(len(self.heads), self.graph.size()))
        return self.heads.error(values) + float(rest)

    def elimination_ordering(self) -> gtsam.Ordering:
        ordering = gtsam.Ordering()
        late = set(self.camera_keys.values()) | set(self.head_keys.values())
        for k in sorted(set(self.initial.keys()) - late):
            ordering.push_back(k)
        for k in list(self.camera_keys.values()) + list(self.head_keys.values()):
            ordering.push_back(k)
        return ordering


def build_self_calibration_problem(
    survey: Survey,
    initial: InitialEstimate,
    active: dict[str, tuple[int, ...]],
    head_start: dict[str, FloatArray] | None = None,
    options: SolverOptions = SolverOptions(),
    exclude: frozenset[int] = frozenset(),
    prior_sigmas: FloatArray = DEFAULT_PRIOR_SIGMAS,
    with_prior: bool = True,
) -> SelfCalibrationProblem:
    """The reference problem with head factors; ``active[cid]`` lists the indices estimated for it
    (into the camera's extended vector, :func:`fgloc.core.head_model.head_dim` of its zoom groups;
    ``head_start[cid]`` and ``prior_sigmas`` as extended vectors, a 7-vector prior is extended)."""
    base = build_problem(survey, initial, replace(options, robust=RobustKernel.NONE), exclude)
    zooms, group_of = zoom_groups(survey)
    dims = {cid: head_dim(len(zooms[cid])) for cid in survey.camera_ids}
    values = gtsam.Values(base.initial)
    head_keys: dict[str, int] = {}

    def start_of(cid: str) -> FloatArray:  # a 7-vector start gives every zoom its lever arm
        zero = np.zeros(dims[cid])
        if head_start is None or cid not in head_start:
            return zero
        return extend_vector(np.asarray(head_start[cid], dtype=float), len(zooms[cid]))

    for i, cid in enumerate(survey.camera_ids):
        idx = tuple(sorted(active.get(cid, ())))
        if cid in base.camera_keys and idx:
            head_keys[cid] = head_key(i)
            values.insert(head_keys[cid], start_of(cid)[list(idx)].copy())
    pt = base.pan_tilt
    cam_of_key = {v: k for k, v in base.camera_keys.items()}
    obs_head = np.array([head_keys.get(cam_of_key[int(k)], -1) for k in pt.camera_keys], dtype=np.int64)
    obs_group = group_of[base.observation_index] if len(pt) else np.zeros(0, dtype=np.int64)
    fixed = np.zeros((len(pt), HEAD_DIM))
    if head_start is not None:
        for j, k in enumerate(pt.camera_keys):
            fixed[j] = reading_params(start_of(cam_of_key[int(k)]), obs_group[j:j + 1])[0]
    sigma = survey.observation_table.sigma[base.observation_index]
    noise = {float(s): gtsam.noiseModel.Isotropic.Sigma(2, float(s)) for s in np.unique(sigma)}
    heads = HeadFactorSet(
        pt.camera_keys, pt.node_keys, obs_head,
        {head_keys[c]: tuple(sorted(active[c])) for c in head_keys}, fixed, pt.pan, pt.tilt,
        [noise[float(s)] for s in sigma], planar=pt.planar, zoom_group=obs_group,
        view=view_angles(survey, base.observation_index),
    )
    graph = gtsam.NonlinearFactorGraph()
    for f in heads.factors:
        graph.add(f)
    for i in range(len(pt), base.graph.size()):
        graph.add(base.graph.at(i))
    if with_prior:
        for cid, key in head_keys.items():
            graph.add(head_prior_factor(key, tuple(sorted(active[cid])), None,
                                        extend_vector(prior_sigmas, len(zooms[cid]))))
    return SelfCalibrationProblem(
        survey=survey, graph=graph, initial=values, camera_keys=base.camera_keys, node_keys=base.node_keys,
        pan_tilt=pt, observation_index=base.observation_index, unlocalized=dict(base.unlocalized),
        heads=heads, head_keys=head_keys, active={c: tuple(sorted(active[c])) for c in head_keys}, zooms=zooms,
    )


def view_angles(survey: Survey, rows: np.ndarray) -> FloatArray | None:
    """(len(rows), 2) radians: the view angles of the off-centre readings ``survey.observations[rows]``
    (``Observation.view_angles``), NaN for centred ones; None when no reading has them."""
    obs = [survey.observations[int(i)] for i in rows]
    if not any(o.view_angles is not None for o in obs):
        return None
    return np.array([o.view_angles or (np.nan, np.nan) for o in obs], dtype=float).reshape(-1, 2)


def node_rms_bound(problem: SelfCalibrationProblem) -> float:
    """sqrt(mean over nodes of the trace of their marginal covariance) at ``problem.initial``:
    the Cramer-Rao (with the head prior: Bayesian) RMS bound when ``initial`` is the truth."""
    problem.prepare(problem.initial)
    marginals = gtsam.Marginals(problem.graph.linearize(problem.initial), problem.initial)
    return float(np.sqrt(np.mean([np.trace(marginals.marginalCovariance(k)) for k in problem.node_keys.values()])))
