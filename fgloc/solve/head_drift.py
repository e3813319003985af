"""Calibration-only mode: re-read known motes with one camera and flag a drift of its tilt index.

After a survey (and its self-calibration) the motes' positions, the camera's base
pose and its head calibration are estimated *jointly*: their errors are
correlated so that the tilt the survey predicts for a mote is known much better
than the mote, the pose or the tilt index alone (a tilt index error and a base
pitch error cancel in every prediction). :class:`KnownMotes` holds, for the motes a
camera can re-read, the predicted readings under the survey's calibration and the
joint covariance of the predicted tilts, from the survey's posterior
(:func:`known_motes_from_survey`; :meth:`KnownMotes.from_positions` for motes known
without a survey fit).

Test. A tilt reading of mote j is ``tilt_j = pred_j + delta + e_j + n``: ``delta``
the tilt index change (radians, 1 dof), ``e`` the prediction error (covariance
``T`` over the motes), ``n`` the reading noise (``sigma``). With ``m_j`` readings
of mote j the mean residuals ``r`` have covariance ``C = diag(sigma^2 / m_j) + T``;
the generalized-least-squares change is ``delta_hat = 1'C^-1 r / I`` with
information ``I = 1'C^-1 1``. :class:`DriftMonitor` runs a two-sided sequential
probability ratio test (Wald) of ``delta = 0`` against ``delta = +-drift`` on
it: ``log LR(+-) = +-drift * I * delta_hat - drift^2 I / 2``, exact for the
correlated Gaussian readings, flagged when either reaches ``ln(2 / alpha)``.
Under no drift each likelihood ratio is a martingale, so by Ville's inequality the
chance of *ever* flagging, however many motes are read, is at most ``alpha``.
Pan readings give the pan offset (a base-yaw change) as a GLS estimate, reported
but not tested.

Choice of motes: :meth:`KnownMotes.best` picks them greedily by the information
they add about the change (far motes, whose tilt depends little on their position,
and motes whose prediction errors cancel), and reading each several times averages
the reading noise down.

Off-centre readings (a coded survey's, ``Observation.view_angles``) are compared through
:func:`centred_equivalent_reading`: the reading moved by the difference between the
model's centred prediction and its prediction at that view, so the residual is the
reading minus what the calibrated head shows at that view (the tilt residual in units of
the tilt-index change it measures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np

from fgloc.core.geometry import FloatArray, pan_tilt_residual, rot_z, wrap_angle
from fgloc.core.head_model import HEAD_DIM, HeadCalibration, head_pan_tilt, head_view_pan_tilt, reading_index
from fgloc.core.model import CameraPose, Observation, Result, Survey
from fgloc.init.start import InitialEstimate
from fgloc.solve.self_calibration import HeadCalibrationReport, HeadModel, build_self_calibration_problem

#: Default tilt-index change the test is designed to detect (radians).
DEFAULT_DRIFT = math.radians(0.1)


@dataclass(frozen=True)
class KnownMotes:
    """Predicted readings of known motes by one camera and the uncertainty of the tilt predictions.

    ``pan``, ``tilt`` (n,) radians under the survey's calibration; ``tilt_covariance``
    and ``pan_covariance`` (n, n) the joint covariance of those predictions.
    """

    ids: tuple[str, ...]
    pan: FloatArray
    tilt: FloatArray
    tilt_covariance: FloatArray
    pan_covariance: FloatArray

    def index(self, mote: str) -> int:
        return self.ids.index(mote)

    def best(self, k: int, sigma: float, readings: int = 1) -> list[str]:
        """The ``k`` motes that tell most about a tilt-index change, in reading order.

        Greedy: each next mote maximizes the GLS information ``1'C^-1 1`` of the motes so
        far read ``readings`` times each with noise ``sigma`` (radians). With independent
        prediction errors that is the smallest predicted-tilt std first (far motes);
        with correlated ones it also picks motes whose prediction errors cancel.
        """
        n = len(self.ids)
        chosen: list[int] = []
        noise = sigma**2 / readings
        for _ in range(min(k, n)):
            best_j, best_info = -1, -1.0
            for j in range(n):
                if j in chosen:
                    continue
                c = chosen + [j]
                C = self.tilt_covariance[np.ix_(c, c)] + noise * np.eye(len(c))
                info = float(np.sum(np.linalg.solve(C, np.ones(len(c)))))
                if info > best_info:
                    best_j, best_info = j, info
            chosen.append(best_j)
        return [self.ids[j] for j in chosen]

    @staticmethod
    def from_positions(
        camera: CameraPose, calibration: HeadCalibration, positions: dict[str, FloatArray],
        position_covariances: dict[str, FloatArray] | None = None,
    ) -> KnownMotes:
        """Motes at world ``positions`` (3,), independent position covariances (2x2 planar or 3x3)
        or exact; the camera pose and calibration taken as exact."""
        ids = tuple(positions)
        q = np.array([camera.rotation.T @ (np.asarray(positions[m], dtype=float) - camera.position) for m in ids])
        pan, tilt, d_q, _ = head_pan_tilt(q.reshape(-1, 3), calibration.values)
        assert d_q is not None
        var = np.zeros((len(ids), 2))
        for j, m in enumerate(ids):
            if position_covariances is not None and m in position_covariances:
                P = np.zeros((3, 3))
                c = np.asarray(position_covariances[m], dtype=float)
                P[: c.shape[0], : c.shape[0]] = c
                D = d_q[j] @ camera.rotation.T
                var[j] = np.diag(D @ P @ D.T)
        return KnownMotes(ids, np.asarray(pan), np.asarray(tilt), np.diag(var[:, 1]), np.diag(var[:, 0]))


def known_motes_from_survey(
    survey: Survey, result: Result, report: HeadCalibrationReport, camera: str,
) -> KnownMotes:
    """The motes ``camera`` read in ``survey``, predicted from ``result`` and its head ``report``.

    The prediction covariance is the survey posterior's (poses, nodes, head parameters
    jointly) pushed through each reading's Jacobian: the extended model is rebuilt at
    the result with the parameters the report estimated (for ``auto`` that kept the
    ideal head: the determinable ones at zero under their prior; an approximation that
    leaves out the offset of the ideal estimate from the extended one) and linearized there.
    """
    active: dict[str, tuple[int, ...]] = {}
    values: dict[str, FloatArray] = {}
    for cid, est in report.cameras.items():
        idx = tuple(est.names.index(n) for n in est.estimated)  # extended indices (one lever arm per zoom)
        if not idx and report.model is HeadModel.AUTO:
            idx = tuple(int(i) for i in np.flatnonzero(np.isfinite(est.data_std)))
        active[cid], values[cid] = idx, np.asarray(est.values, dtype=float)
    start = InitialEstimate(cameras=dict(result.cameras), nodes={n: e.position for n, e in result.nodes.items()},
                            unlocalized=dict(result.unlocalized))
    exclude = frozenset(f.index for f in result.flagged)
    problem = build_self_calibration_problem(survey, start, active, values, exclude=exclude)
    assert problem.heads is not None
    cam_key = problem.camera_keys[camera]
    rows: dict[int, int] = {}  # node key -> first factor of this camera reading it
    for j in range(len(problem.heads)):
        if int(problem.heads.camera_keys[j]) == cam_key and problem.heads.zoom_group[j] == 0:
            rows.setdefault(int(problem.heads.node_keys[j]), j)
    node_of_key = {k: n for n, k in problem.node_keys.items()}
    ids = tuple(node_of_key[k] for k in rows)
    problem.prepare(problem.initial)
    keys = [cam_key] + ([problem.head_keys[camera]] if camera in problem.head_keys else []) + list(rows)
    dims = {k: int(problem.initial.dims()[k]) for k in keys}
    offset = dict(zip(keys, np.cumsum([0] + [dims[k] for k in keys])[:-1]))
    G = np.zeros((2 * len(ids), sum(dims.values())))  # d(pan, tilt prediction) / d(variables), unwhitened
    for i, (node_key, j) in enumerate(rows.items()):
        factor = problem.graph.at(j)
        A, _ = factor.linearize(problem.initial).jacobian()
        A = A / problem.heads.inv_sigmas[j][:, None]
        col = 0
        for k in factor.keys():
            G[2 * i:2 * i + 2, offset[k]:offset[k] + dims[k]] = A[:, col:col + dims[k]]
            col += dims[k]
    marginals = gtsam.Marginals(problem.graph.linearize(problem.initial), problem.initial)
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector(keys))
    S = np.zeros((G.shape[1], G.shape[1]))
    for a in keys:
        for b in keys:
            S[offset[a]:offset[a] + dims[a], offset[b]:offset[b] + dims[b]] = joint.at(a, b)
    cov = G @ S @ G.T
    pose = result.cameras[camera]
    q = np.array([pose.rotation.T @ (result.nodes[n].position - pose.position) for n in ids]).reshape(-1, 3)
    # predicted at the camera's first zoom (its survey zoom), where the motes are re-read
    params = values.get(camera, np.zeros(HEAD_DIM))[list(reading_index(0))]
    pan, tilt, _, _ = head_pan_tilt(q, params, jacobians=False)
    return KnownMotes(ids, np.asarray(pan), np.asarray(tilt), cov[1::2, 1::2], cov[0::2, 0::2])


def centred_equivalent_reading(observation: Observation, camera: CameraPose, position: FloatArray,
                                params: FloatArray) -> tuple[float, float]:
    """``observation``'s (pan, tilt) radians as the centred reading with the same residual under
    head calibration ``params`` (7,): unchanged for a centred reading (no view angles); for an
    off-centre one, the reading plus the model's centred prediction minus its prediction at
    the reading's view (:func:`fgloc.core.head_model.head_view_pan_tilt`), with the mote at
    ``position`` (world frame) seen by ``camera``, the tilt residual divided by the view
    model's d tilt / d tilt index (about the cosine of the reading's pan off the view's centre;
    1 for a centred reading). :class:`DriftMonitor` compares readings with centred predictions
    and models a drift as shifting every tilt residual by the change, so this makes its
    residual the reading minus the view model's, in tilt-index units. Radians."""
    view = observation.view_angles
    if view is None:
        return observation.pan, observation.tilt
    q = (np.asarray(camera.rotation, float).T @ (np.asarray(position, float) - np.asarray(camera.position, float)))
    c_pan, c_tilt, _, _ = head_pan_tilt(q.reshape(1, 3), params, jacobians=False)
    v_pan, v_tilt, _, d_p = head_view_pan_tilt(q.reshape(1, 3), params, view[0], view[1])
    assert d_p is not None
    # an off-centre reading moves by less than a tilt-index change (about its cosine off the
    # view's centre in pan): the residual is scaled to the change it measures
    gain = float(np.asarray(d_p).reshape(2, HEAD_DIM)[1, 0])
    pan = float(wrap_angle(observation.pan + float(np.ravel(c_pan)[0]) - float(np.ravel(v_pan)[0])))
    return pan, float(np.ravel(c_tilt)[0]) + (observation.tilt - float(np.ravel(v_tilt)[0])) / gain


@dataclass(frozen=True)
class DriftCheck:
    """The drift test after ``n_readings`` readings of ``n_motes`` motes.

    ``offset`` (2,) is the estimated (pan offset, tilt index change) in radians and
    ``covariance`` their 2x2 covariance (GLS each; cross term not estimated, 0);
    ``chi2`` the tilt change's squared z against zero (1 dof, for reports);
    ``llr`` the larger of the two SPRT log likelihood ratios, ``threshold`` its
    ``ln(2 / alpha)``; ``drifted`` once ``llr`` has reached it.
    """

    n_motes: int
    n_readings: int
    offset: FloatArray
    covariance: FloatArray
    chi2: float
    threshold: float
    drifted: bool
    llr: float = 0.0


@dataclass
class DriftMonitor:
    """Sequential (SPRT) test of one camera's tilt index against its last calibration (module docstring).

    ``known`` the camera's known motes, ``sigma`` the reading noise (radians),
    ``drift`` the tilt-index change to detect (radians), ``alpha`` the bound on the
    false-alarm probability over the whole (unbounded) sequence.
    """

    known: KnownMotes
    sigma: float
    drift: float = DEFAULT_DRIFT
    alpha: float = 0.01
    _sums: dict[str, list[float]] = field(default_factory=dict)  # mote -> [pan residual sum, tilt sum, count]
    _n: int = 0
    _flagged: bool = False

    @property
    def threshold(self) -> float:
        """``ln(2 / alpha)``: each side's likelihood ratio reaches 1/(alpha/2) with chance <= alpha/2 (Ville)."""
        return math.log(2.0 / self.alpha)

    def add(self, mote: str, pan: float, tilt: float) -> DriftCheck:
        """Add one reading (radians) of known mote ``mote`` and test."""
        j = self.known.index(mote)
        r = pan_tilt_residual(pan, tilt, self.known.pan[j], self.known.tilt[j])
        s = self._sums.setdefault(mote, [0.0, 0.0, 0.0])
        s[0] += float(r[0])
        s[1] += float(r[1])
        s[2] += 1.0
        self._n += 1
        check = self.check()
        self._flagged = self._flagged or check.llr >= check.threshold
        return DriftCheck(check.n_motes, check.n_readings, check.offset, check.covariance, check.chi2,
                          check.threshold, self._flagged, check.llr)

    def _gls(self, axis: int, cov: FloatArray) -> tuple[float, float]:
        """GLS offset and its variance on ``axis`` (0 pan, 1 tilt) from the readings so far."""
        idx = [self.known.index(m) for m in self._sums]
        count = np.array([s[2] for s in self._sums.values()])
        mean = np.array([s[axis] for s in self._sums.values()]) / count
        C = cov[np.ix_(idx, idx)] + np.diag(self.sigma**2 / count)
        w = np.linalg.solve(C, np.ones(len(idx)))
        info = float(w.sum())
        return float(w @ mean) / info, 1.0 / info

    def check(self) -> DriftCheck:
        """The test on the readings so far (``drifted``: the SPRT has crossed at any look)."""
        if not self._n:
            return DriftCheck(0, 0, np.zeros(2), np.full((2, 2), np.inf), 0.0, self.threshold, False, 0.0)
        pan, var_pan = self._gls(0, self.known.pan_covariance)
        tilt, var_tilt = self._gls(1, self.known.tilt_covariance)
        info = 1.0 / var_tilt
        llr = abs(self.drift * info * tilt) - 0.5 * self.drift**2 * info
        return DriftCheck(len(self._sums), self._n, np.array([pan, tilt]), np.diag([var_pan, var_tilt]),
                          tilt**2 / var_tilt, self.threshold, self._flagged or llr >= self.threshold, llr)

    def updated(self, camera: CameraPose, calibration: HeadCalibration) -> tuple[CameraPose, HeadCalibration]:
        """Camera and calibration corrected by the estimated offsets (pan offset as a base-yaw turn).

        The tilt index gains the estimated change; its variance gains the change's variance.
        """
        check = self.check()
        values = np.array(calibration.values, dtype=float).copy()
        values[0] += check.offset[1]
        cov = None
        if calibration.covariance is not None:
            cov = np.array(calibration.covariance, dtype=float).copy()
            cov[0, 0] += check.covariance[1, 1]
        # A pan reading larger by d means the base turned by -d about its z axis.
        rotation = camera.rotation @ rot_z(-float(check.offset[0]) / (1.0 + values[3]))
        return CameraPose(camera.position, rotation), HeadCalibration(values, cov)
