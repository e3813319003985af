"""Survey and result data model: small dataclasses, no I/O.

Frames and units follow ``docs/file-format.md`` (version 1): angles in
radians, positions in the gauge frame (planar: nodes on z = 0, origin camera
above (0, 0), baseline camera above (1, 0)).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray


class NodeMode(str, enum.Enum):
    """Whether nodes are constrained to the ground plane z = 0 or free in 3D."""

    PLANAR = "planar"
    THREE_D = "3d"

    @property
    def position_dim(self) -> int:
        """Dimension of a node's estimated position (2 for planar, 3 for 3d)."""
        return 2 if self is NodeMode.PLANAR else 3


@dataclass(frozen=True)
class Gauge:
    """The two cameras that fix the normalized frame (see the spec's Gauge section)."""

    origin: str
    baseline: str


@dataclass(frozen=True)
class CameraPose:
    """A camera base: position ``c`` (world, 3,) and rotation ``R`` (base -> world, 3x3)."""

    position: FloatArray
    rotation: FloatArray


@dataclass(frozen=True)
class Observation:
    """One (pan, tilt) reading in radians of ``node`` by ``camera``.

    ``sigma`` (radians) overrides the survey's default noise when not None.
    ``subset`` (optional, >= 0) tags a reading taken for one subset of a
    re-measured survey (the subset-Newton baseline solves each tag on its own
    readings; every other solver ignores it).

    ``view`` (optional) names the head reading the angle was composed from: readings
    of one view (e.g. every mote decoded in one coded-survey view) share that view's
    head error, a zero-mean (pan, tilt) error of the head with standard deviation
    ``view_sigma`` (radians, per axis). ``sigma`` stays the reading's total standard
    deviation, so ``sqrt(sigma^2 - view_sigma^2)`` is its independent part; a solver
    that ignores views sees the same marginal noise. ``view_sigma`` must be below
    ``sigma``. ``view_pan`` (radians, optional) is the head pan the view was read at:
    a head tilt error turns an off-centre bearing about the tilt axis at that pan
    (:mod:`fgloc.factors.view_offset`); without it the reading's own pan is used.

    ``sigma_axes`` (optional, radians) gives pan's and tilt's total standard deviations
    where they differ (e.g. a decoder's pixel error maps to angles differently per axis);
    ``sigma`` then stays one value for both (e.g. their RMS) for readers that know no more.

    ``zoom`` (optional, fraction 0 widest ... 1 optical tele) is the zoom the reading was
    taken at; readings without it share the survey's one zoom. The head model gives each
    zoom a camera used its own lever arm (:mod:`fgloc.core.head_model`).

    ``view_tilt`` (radians, optional) with ``view_pan``: the head's encoder readings of the
    view the reading was composed at, when it was taken **off-centre** (a coded survey's LED
    pixel composed with the view's angles by the ideal pixel -> pan-tilt composition). The
    head model then predicts the reading from the view
    (:func:`fgloc.core.head_model.head_view_pan_tilt`) instead of as a centred one
    (:func:`~fgloc.core.head_model.head_pan_tilt`); a reading without them (or a sequential,
    centred one) is centred. :attr:`view_angles` tells whether a reading has both.
    """

    camera: str
    node: str
    pan: float
    tilt: float
    sigma: float | None = None
    subset: int | None = None
    view: str | None = None
    view_sigma: float | None = None
    view_pan: float | None = None
    sigma_axes: tuple[float, float] | None = None
    zoom: float | None = None
    view_tilt: float | None = None

    @property
    def view_angles(self) -> tuple[float, float] | None:
        """(pan, tilt) radians of the view an off-centre reading was composed at, None when not recorded."""
        return None if self.view_pan is None or self.view_tilt is None else (self.view_pan, self.view_tilt)


@dataclass(frozen=True)
class ObservationTable:
    """Observations as parallel arrays (indices into the survey's id lists)."""

    camera_index: np.ndarray  # (M,) int
    node_index: np.ndarray  # (M,) int
    pan: FloatArray  # (M,) radians
    tilt: FloatArray  # (M,) radians
    sigma: FloatArray  # (M,) radians, default already applied (total: view part included)
    #: (M,) index into ``Survey.view_ids`` of each reading's view, -1 for none.
    view_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: (M,) radians, the shared (view) part of ``sigma``; 0 for readings without a view.
    view_sigma: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: (M,) radians, the head pan of each reading's view (the reading's own pan where not given).
    view_pan: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: (M, 2) radians, pan's and tilt's total sigma (``sigma`` twice where not given).
    sigma_axes: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def reading_sigma(self) -> FloatArray:
        """(M, 2) radians: the independent part of each reading's pan and tilt noise,
        ``sqrt(sigma_axes^2 - view_sigma^2)``."""
        axes = self.sigma_axes if len(self.sigma_axes) == len(self.sigma) else np.column_stack([self.sigma] * 2)
        if len(self.view_sigma) != len(self.sigma):
            return axes
        return np.sqrt(np.maximum(axes**2 - self.view_sigma[:, None] ** 2, 0.0))

    def __len__(self) -> int:
        return int(self.pan.shape[0])


@dataclass
class Truth:
    """Ground truth of a simulated survey, in the gauge frame. Solvers never read it."""

    cameras: dict[str, CameraPose]
    nodes: dict[str, FloatArray]


@dataclass
class Survey:
    """A survey: cameras, nodes and their pan-tilt observations."""

    mode: NodeMode
    gauge: Gauge
    sigma: float
    camera_ids: list[str]
    node_ids: list[str]
    observations: list[Observation]
    truth: Truth | None = None

    @cached_property
    def observation_table(self) -> ObservationTable:
        """The observations as arrays; computed once (treat the survey as immutable)."""
        cam_index = {c: i for i, c in enumerate(self.camera_ids)}
        node_index = {n: i for i, n in enumerate(self.node_ids)}
        view_index = {v: i for i, v in enumerate(self.view_ids)}
        obs = self.observations
        return ObservationTable(
            camera_index=np.array([cam_index[o.camera] for o in obs], dtype=np.int64),
            node_index=np.array([node_index[o.node] for o in obs], dtype=np.int64),
            pan=np.array([o.pan for o in obs], dtype=float),
            tilt=np.array([o.tilt for o in obs], dtype=float),
            sigma=np.array([self.sigma if o.sigma is None else o.sigma for o in obs], dtype=float),
            view_index=np.array([-1 if o.view is None or o.view_sigma is None else view_index[o.view] for o in obs],
                                dtype=np.int64),
            view_sigma=np.array([0.0 if o.view is None or o.view_sigma is None else o.view_sigma for o in obs],
                                dtype=float),
            view_pan=np.array([o.pan if o.view_pan is None else o.view_pan for o in obs], dtype=float),
            sigma_axes=np.array([(self.sigma if o.sigma is None else o.sigma,) * 2 if o.sigma_axes is None
                                 else o.sigma_axes for o in obs], dtype=float).reshape(-1, 2),
        )

    @cached_property
    def view_ids(self) -> list[str]:
        """Ids of the views named by the observations (with a ``view_sigma``), in first-seen order."""
        return list(dict.fromkeys(o.view for o in self.observations if o.view is not None and o.view_sigma is not None))

    def truth_node_array(self) -> FloatArray:
        """True node positions (N, 3) in ``node_ids`` order. Raises if there is no truth."""
        if self.truth is None:
            raise FglocError("survey has no truth")
        return np.array([self.truth.nodes[n] for n in self.node_ids], dtype=float)


@dataclass(frozen=True)
class NodeEstimate:
    """A localized node: position (3,) in the gauge frame and its marginal covariance.

    ``covariance`` is 2x2 over (x, y) for planar surveys, 3x3 for 3d surveys.
    """

    position: FloatArray
    covariance: FloatArray


@dataclass(frozen=True)
class FlaggedObservation:
    """A reading whose residual is implausible under the noise model.

    ``whitened_residual`` is the square root of the deletion residual's
    Mahalanobis norm (chi-square, 2 dof, for a good reading), or inf when the
    reading's node could not be placed without it.
    """

    camera: str
    node: str
    index: int  # position in Survey.observations
    whitened_residual: float  # norm of the 2-vector residual / sigma


@dataclass
class SolveStats:
    """What the optimizer did: iterations, costs and wall time per stage (seconds)."""

    method: str
    iterations: int
    initial_error: float
    final_error: float
    converged: bool
    stage_seconds: dict[str, float] = field(default_factory=dict)
    error_history: list[float] = field(default_factory=list)


@dataclass
class FitReport:
    """Goodness of fit and plausibility of a solution (:mod:`fgloc.solve.plausibility`).

    ``chi2`` is the sum of the used readings' squared whitened residuals, chi-square
    with ``dof`` degrees of freedom under the noise model; ``p_value`` the chance of a
    chi2 at least as large (NaN when ``dof`` <= 0). ``problems`` lists, one sentence
    each, why the solution is implausible (empty when it is plausible).
    """

    chi2: float
    dof: int
    readings: int
    p_value: float
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # worth a look, not implausible (e.g. upside-down heads)

    @property
    def plausible(self) -> bool:
        return not self.problems


@dataclass
class Result:
    """A solved survey in the gauge frame."""

    mode: NodeMode
    nodes: dict[str, NodeEstimate]
    cameras: dict[str, CameraPose]
    unlocalized: dict[str, str] = field(default_factory=dict)
    flagged: list[FlaggedObservation] = field(default_factory=list)
    stats: SolveStats | None = None
    fit: FitReport | None = None
