"""Every pan-tilt reading of a survey as ONE factor on the camera keys, the nodes eliminated in closed form.

The survey's structure: every reading links one camera to one node. For given
cameras ``c`` each node's best position is a tiny independent problem (d = 2
unknowns on z = 0, d = 3 in 3d), so the readings' cost can be written as a
function of the cameras alone (variable projection; GTSAM's smart factors do
the same with landmarks):

    f(c) = min_x  sum_r loss(|e_r(c, x_node(r))| / sigma_r)

with ``e_r`` the pan-tilt error of :func:`fgloc.factors.pan_tilt_factor.pan_tilt_error`
and ``loss`` GTSAM's (Gaussian 0.5 s^2, or the Huber / Cauchy M-estimator as
``gtsam.noiseModel.Robust``). :class:`EliminatedReadings` solves the node
problems (vectorized Gauss-Newton with per-node step halving, robust kernels as
IRLS weights per reading) and its :meth:`~EliminatedReadings.factor` is a
``gtsam.CustomFactor`` on the camera keys whose linearization is the
node-eliminated (Schur complement) system

    S = H_cc - sum_j B_j^T A_j^-1 B_j,   g = g_c - sum_j B_j^T A_j^-1 g_j

(``A_j`` node block, ``B_j`` node-camera coupling, ``g`` gradients, all with the
IRLS weights, exactly what GTSAM's linearization of the per-reading robust
factors would give). It is handed to GTSAM as a Jacobian factor of 6k + 1 rows:
``S = R^T R`` (eigen-decomposition, gauge directions of zero weight kept as
zero rows), ``e' = R^-T g`` and a constant row ``sqrt(2 f - |e'|^2)``, so that
the linear error at zero equals ``f`` and its gradient and Hessian are ``g``
and ``S``. Evaluated without Jacobians (``graph.error``) the factor returns a
vector of norm ``sqrt(2 f)``. GTSAM never sees one linear factor per reading.

Cameras: ``Pose3``, tangent ``[omega, v]`` with right perturbation (GTSAM's
convention); angles in radians; positions in gauge units. Evaluations are
cached by camera values, so ``graph.error`` / ``graph.linearize`` at the same
cameras share one node solve.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from fgloc.core.geometry import PAN_SINGULARITY_EPS, FloatArray, wrap_angle

if TYPE_CHECKING:
    from fgloc.factors.camera_side import CameraSide, SideState


class Kernel(str, enum.Enum):
    """Loss on the whitened residual norm s (GTSAM's M-estimators)."""

    GAUSSIAN = "gaussian"
    HUBER = "huber"
    CAUCHY = "cauchy"


def loss_and_weight(s2: FloatArray, kernel: Kernel, scale: float) -> tuple[FloatArray, FloatArray]:
    """GTSAM's ``loss(s)`` and IRLS ``weight(s)`` of squared whitened norms ``s2``.

    Gaussian: 0.5 s^2, 1. Huber (k): s^2/2 inside k, k s - k^2/2 beyond; weight
    min(1, k/s). Cauchy (k): k^2/2 log(1 + s^2/k^2); weight 1 / (1 + s^2/k^2).
    """
    if kernel is Kernel.HUBER:
        s = np.sqrt(s2)
        inside = s <= scale
        return np.where(inside, 0.5 * s2, scale * s - 0.5 * scale**2), np.where(inside, 1.0, scale / np.maximum(s, 1e-300))
    if kernel is Kernel.CAUCHY:
        u = s2 / scale**2
        return 0.5 * scale**2 * np.log1p(u), 1.0 / (1.0 + u)
    return 0.5 * s2, np.ones_like(s2)


def _sum_by(index: np.ndarray, columns: list[FloatArray], size: int) -> FloatArray:
    """(size, len(columns)): per-group sums of each column (groups given by ``index``)."""
    out = np.empty((size, len(columns)))
    for i, col in enumerate(columns):
        out[:, i] = np.bincount(index, weights=col, minlength=size)
    return out


@dataclass
class _Pass:
    """The readings evaluated at one set of cameras and nodes (whitened, IRLS-weighted)."""

    nodes: FloatArray  # (n, d)
    e: FloatArray  # (m, 2) sqrt(w) * error / sigma
    jn: FloatArray  # (m, 2, d) sqrt(w) * de/dx / sigma
    dq: FloatArray  # (m, 2, 3) sqrt(w) * de/dq / sigma (q: node in the camera base frame)
    q: FloatArray  # (m, 3)
    loss: FloatArray  # (m,)
    node_cost: FloatArray  # (n,)
    #: Kernel curvature term of the exact Hessian per reading: d^2 loss/de^2 = w I + c e e^T
    #: (whitened e); this is c / w^2, so that the term is coef * (jn^T e)(jn^T e)^T in weighted units.
    newton_coef: FloatArray | None = None
    #: (m, 2, w) sqrt(w) * de/d(extra camera-side variables) / sigma (see :mod:`fgloc.factors.camera_side`).
    dx: FloatArray | None = None


@dataclass
class ReducedSystem:
    """The node-eliminated Gauss-Newton system at some cameras (6k unknowns, camera slot order)."""

    cost: float  # f: the readings' cost with every node at its optimum
    gradient: FloatArray  # (6k,)
    hessian: FloatArray  # (6k, 6k) S
    node_information: FloatArray  # (n, d, d) A_j
    node_gain: FloatArray  # (n, d, 6k) A_j^-1 B_j: dx_j/dc = -node_gain
    node_gradient: FloatArray  # (n, d) g_j (~0 at the node optimum)


class EliminatedReadings:
    """The pan-tilt readings of a survey, nodes eliminated (see module docstring).

    Args:
        camera_keys: GTSAM keys of the cameras (slot order of the reduced system).
        camera: (m,) each reading's camera slot; node: (m,) its node row (0..n-1).
        pan, tilt: (m,) radians; sigma: (m,) radians, or (m, 2) pan's and tilt's.
        nodes: (n, d) starting node positions (d = 2: planar, (x, y) on z = 0; d = 3).
        kernel, scale: loss on the whitened residual norm (scale in sigmas).
        side: extra camera-side variables (head vectors or view offsets,
            :class:`~fgloc.factors.camera_side.CameraSide`, readings in the order given
            here); the reduced system then has ``6k + side.size`` unknowns, poses first.
    """

    #: Node Gauss-Newton stops when every node's predicted decrease is below this
    #: (GTSAM error units; the readings' cost is ~ one per reading).
    NODE_TOL = 1e-13
    MAX_NODE_STEPS = 30

    def __init__(
        self,
        camera_keys: list[int],
        camera: np.ndarray,
        node: np.ndarray,
        pan: FloatArray,
        tilt: FloatArray,
        sigma: FloatArray,
        nodes: FloatArray,
        kernel: Kernel = Kernel.GAUSSIAN,
        scale: float = 3.0,
        side: CameraSide | None = None,
    ) -> None:
        self.camera_keys = [int(k) for k in camera_keys]
        order = np.argsort(camera, kind="stable")  # readings grouped by camera: one GEMM per camera
        self.order = order
        self.side = side if side is not None and side.size > 0 else None
        if self.side is not None:
            self.side.reorder(order)
        self._state: SideState | None = None
        self._lin_state: SideState | None = None
        self.camera = np.asarray(camera, dtype=np.int64)[order]
        self.node = np.asarray(node, dtype=np.int64)[order]
        self.pan = np.asarray(pan, dtype=float)[order]
        self.tilt = np.asarray(tilt, dtype=float)[order]
        sig = np.asarray(sigma, dtype=float)
        # One sigma per reading, or pan's and tilt's (m, 2); inv_tilt is inv_sigma itself when isotropic.
        self.inv_sigma = 1.0 / (sig[:, 0] if sig.ndim == 2 else sig)[order]
        self.inv_tilt = self.inv_sigma
        if sig.ndim == 2 and not np.array_equal(sig[:, 0], sig[:, 1]):
            self.inv_tilt = 1.0 / sig[:, 1][order]
        self._aniso = self.inv_tilt is not self.inv_sigma
        self.nodes = np.array(nodes, dtype=float)
        self.dim = self.nodes.shape[1]
        self.kernel, self.scale = kernel, float(scale)
        k = len(self.camera_keys)
        bounds = np.searchsorted(self.camera, np.arange(k + 1))
        self._slices = [slice(int(bounds[i]), int(bounds[i + 1])) for i in range(k)]
        pair = self.node * k + self.camera
        n_nodes = len(nodes)
        # No repeated readings of a (node, camera) pair (a bincount: np.unique's hashing is slow).
        self._unique_pairs = bool(len(pair) == 0 or np.bincount(pair, minlength=n_nodes * k).max() <= 1)
        self._b_index: np.ndarray | None = None
        self._cols: np.ndarray | None = None
        self._cache_key: bytes | None = None
        self._pass: _Pass | None = None
        self._system: ReducedSystem | None = None
        self._lin_cameras: list[gtsam.Pose3] | None = None  # where _lin_gain was computed
        self._lin_nodes: FloatArray | None = None
        self._lin_gain: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.pan)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    # -- evaluation -----------------------------------------------------------------
    def _evaluate(
        self, rot: FloatArray, pos: FloatArray, nodes: FloatArray, base: _Pass | None = None,
        moved: np.ndarray | None = None,
    ) -> _Pass:
        """Whitened, weighted errors and node Jacobians of every reading (one vectorized pass).

        With ``base`` (a pass at the same cameras) and ``moved`` (n,) marking the only nodes
        whose position differs from ``base.nodes``, only those nodes' readings are evaluated
        and the rest is taken from ``base`` (when they are under half of the readings)."""
        rows = None
        if base is not None and moved is not None:
            rows = np.flatnonzero(moved[self.node])
            if len(rows) > len(self.node) // 2:
                rows = None
        if rows is None:
            node, pan, tilt, inv_sigma, slices = self.node, self.pan, self.tilt, self.inv_sigma, self._slices
            inv_tilt = self.inv_tilt
        else:
            node, pan, tilt, inv_sigma = self.node[rows], self.pan[rows], self.tilt[rows], self.inv_sigma[rows]
            inv_tilt = self.inv_tilt[rows] if self._aniso else inv_sigma
            bounds = np.searchsorted(self.camera[rows], np.arange(len(self.camera_keys) + 1))
            slices = [slice(int(bounds[i]), int(bounds[i + 1])) for i in range(len(self.camera_keys))]
        m, d = len(pan), self.dim
        x = nodes[node]
        qt = np.empty((3, m))  # q^T: component rows, contiguous
        for i, sl in enumerate(slices):
            # q = R^T (x - c) with x = (x, y, 0) in planar mode: rows x R[:d] - c R.
            np.matmul(rot[i][:d].T, x[sl].T, out=qt[:, sl])
            qt[:, sl] -= (pos[i] @ rot[i])[:, None]
        qx, qy, qz = qt
        r2xy = qx * qx + qy * qy
        n2 = r2xy + qz * qz
        rxy = np.sqrt(r2xy)
        r = np.maximum(rxy, np.maximum(PAN_SINGULARITY_EPS * np.sqrt(n2), 1e-100))
        rr = r * r
        n2 = np.maximum(n2, rr)
        e = np.empty((m, 2))
        generic = None
        if self.side is not None and self._state is not None:
            generic = self.side.predict(qt.T, rows, self._state)
            e[:, 0] = wrap_angle(pan - generic[0])
            e[:, 1] = tilt - generic[1]
        else:
            e[:, 0] = wrap_angle(pan - np.arctan2(qy, qx))
            e[:, 1] = tilt - np.arctan2(qz, rxy)
        if self._aniso:
            e[:, 0] *= inv_sigma
            e[:, 1] *= inv_tilt
        else:
            e *= inv_sigma[:, None]
        s2 = e[:, 0] ** 2 + e[:, 1] ** 2
        loss, weight = loss_and_weight(s2, self.kernel, self.scale)
        f = inv_sigma * np.sqrt(weight) if self.kernel is not Kernel.GAUSSIAN else inv_sigma
        ft = (inv_tilt * np.sqrt(weight) if self.kernel is not Kernel.GAUSSIAN else inv_tilt) if self._aniso else f
        if self.kernel is not Kernel.GAUSSIAN:
            e *= np.sqrt(weight)[:, None]
        # de/dq = -d(pan, tilt)/dq (geometry.pan_tilt_jacobian), whitened and weighted.
        dq = np.empty((m, 2, 3))
        f_rr = f / rr
        np.multiply(qy, f_rr, out=dq[:, 0, 0])
        np.multiply(qx, -f_rr, out=dq[:, 0, 1])
        dq[:, 0, 2] = 0.0
        f_rn = ft / (r * n2)
        np.multiply(qz, f_rn, out=rxy)  # rxy no longer needed: reuse as qz f / (r n2)
        np.multiply(qx, rxy, out=dq[:, 1, 0])
        np.multiply(qy, rxy, out=dq[:, 1, 1])
        np.multiply(r, -ft / n2, out=dq[:, 1, 2])
        dx = None
        if generic is not None:
            assert generic[2] is not None and generic[3] is not None
            fa = np.column_stack([f, ft])[:, :, None]
            dq = -fa * generic[2]
            dx = -fa * generic[3]
        jn = np.empty((m, 2, d))
        for i, sl in enumerate(slices):
            # de/dx = de/dq R^T: one (2 m_i x 3) @ (3 x d) GEMM per camera, not m_i tiny ones.
            jn[sl] = (dq[sl].reshape(-1, 3) @ rot[i].T[:, :d]).reshape(-1, 2, d)
        q = qt.T
        node_cost = np.asarray(np.bincount(node, weights=loss, minlength=len(nodes)), dtype=float)
        coef = None
        if self.kernel is Kernel.CAUCHY:
            coef = np.full(m, -2.0 / self.scale**2)
        elif self.kernel is Kernel.HUBER:
            sn = np.sqrt(s2)
            coef = np.where(sn > self.scale, -1.0 / (self.scale * np.maximum(sn, 1e-300)), 0.0)
        if rows is None or base is None or moved is None:
            return _Pass(nodes, e, jn, dq, q, loss, node_cost, coef, dx)
        out = _Pass(nodes, base.e.copy(), base.jn.copy(), base.dq.copy(), np.array(base.q), base.loss.copy(),
                    base.node_cost.copy(), None if base.newton_coef is None else base.newton_coef.copy(),
                    None if base.dx is None else base.dx.copy())
        out.e[rows], out.jn[rows], out.dq[rows], out.q[rows], out.loss[rows] = e, jn, dq, q, loss
        if out.dx is not None and dx is not None:
            out.dx[rows] = dx
        out.node_cost[moved] = node_cost[moved]  # every reading of a moved node is in rows
        if out.newton_coef is not None and coef is not None:
            out.newton_coef[rows] = coef
        return out

    def _node_costs(self, rot: FloatArray, pos: FloatArray, nodes: FloatArray, rows: np.ndarray) -> FloatArray:
        """(n,) cost of each node from the readings ``rows`` only (zero for other nodes)."""
        x = nodes[self.node[rows]]
        if self.dim == 2:
            x = np.column_stack([x, np.zeros(len(rows))])
        cam = self.camera[rows]
        q = np.einsum("mji,mj->mi", rot[cam], x - pos[cam])
        if self.side is not None and self._state is not None:
            pred_pan, pred_tilt, _, _ = self.side.predict(q, rows, self._state, jacobians=False)
            e0 = wrap_angle(self.pan[rows] - pred_pan)
            e1 = self.tilt[rows] - pred_tilt
        else:
            e0 = wrap_angle(self.pan[rows] - np.arctan2(q[:, 1], q[:, 0]))
            e1 = self.tilt[rows] - np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1]))
        s2 = (e0 * self.inv_sigma[rows]) ** 2 + (e1 * self.inv_tilt[rows]) ** 2
        loss, _ = loss_and_weight(s2, self.kernel, self.scale)
        return np.asarray(np.bincount(self.node[rows], weights=loss, minlength=len(nodes)), dtype=float)

    def _halve_batched(self, rot: FloatArray, pos: FloatArray, p: _Pass, step: FloatArray, worse: np.ndarray,
                       slack: FloatArray) -> np.ndarray:
        """The step-halving loop of :meth:`_solve_nodes` (scales 1/2 .. 1/2^30, the first that does not
        raise the node's cost wins) in one evaluation of all candidates: a head model's prediction
        costs a Newton solve per call, so 30 small calls would dominate. Scales ``step`` in place;
        returns the nodes no scale helped."""
        assert self.side is not None and self._state is not None
        T = 30
        scales = 0.5 ** np.arange(1, T + 1)
        rows = np.flatnonzero(worse[self.node])
        node_r = self.node[rows]
        x = (p.nodes[node_r][None] + scales[:, None, None] * step[node_r][None]).reshape(-1, self.dim)
        rows_t = np.tile(rows, T)
        if self.dim == 2:
            x = np.column_stack([x, np.zeros(len(x))])
        cam = self.camera[rows_t]
        q = np.einsum("mji,mj->mi", rot[cam], x - pos[cam])
        pred_pan, pred_tilt, _, _ = self.side.predict(q, rows_t, self._state, jacobians=False)
        e0 = wrap_angle(self.pan[rows_t] - pred_pan)
        e1 = self.tilt[rows_t] - pred_tilt
        s2 = (e0 * self.inv_sigma[rows_t]) ** 2 + (e1 * self.inv_tilt[rows_t]) ** 2
        loss, _ = loss_and_weight(s2, self.kernel, self.scale)
        n = len(p.nodes)
        group = np.repeat(np.arange(T), len(rows)) * n + np.tile(node_r, T)
        costs = np.bincount(group, weights=loss, minlength=T * n).reshape(T, n)
        ok = (costs <= (p.node_cost + slack)[None, :]) & worse[None, :]
        helped = ok.any(axis=0)
        first = np.argmax(ok, axis=0)
        step[helped] *= scales[first[helped]][:, None]
        return np.asarray(worse & ~helped)

    def _node_blocks(self, p: _Pass) -> tuple[FloatArray, FloatArray]:
        """A_j (n, d, d) and g_j (n, d) from a pass."""
        d, n = self.dim, len(p.nodes)
        jn, e = p.jn, p.e
        cols = []
        pairs = [(a, b) for a in range(d) for b in range(a, d)]
        for a, b in pairs:
            cols.append(jn[:, 0, a] * jn[:, 0, b] + jn[:, 1, a] * jn[:, 1, b])
        for a in range(d):
            cols.append(jn[:, 0, a] * e[:, 0] + jn[:, 1, a] * e[:, 1])
        sums = _sum_by(self.node, cols, n)
        A = np.empty((n, d, d))
        for i, (a, b) in enumerate(pairs):
            A[:, a, b] = A[:, b, a] = sums[:, i]
        return A, sums[:, len(pairs) :]

    def _newton_blocks(self, p: _Pass, A: FloatArray) -> FloatArray:
        """Robust kernels: the exact node Hessian (IRLS block plus the kernel's curvature term)
        where it is positive definite, else the IRLS block. Newton converges quadratically,
        IRLS only linearly; the reduced system keeps GTSAM's IRLS form either way."""
        if p.newton_coef is None:
            return A
        d = self.dim
        v = np.einsum("mki,mk->mi", p.jn, p.e)  # (m, d)
        cols = [p.newton_coef * v[:, a] * v[:, b] for a in range(d) for b in range(d)]
        extra = _sum_by(self.node, cols, len(A)).reshape(len(A), d, d)
        full = A + extra
        ok = _eig_extremes(full)[0] > 1e-9 * _eig_extremes(A)[1]
        return np.where(ok[:, None, None], full, A)

    def _solve_nodes(self, rot: FloatArray, pos: FloatArray, start: FloatArray) -> _Pass:
        """Every node at its optimum for the given cameras: Gauss-Newton per node, halving
        the step of any node whose cost would rise. A node is done when its predicted
        decrease is below ``NODE_TOL`` (relative to its cost, at least 1) or no step
        along its Gauss-Newton direction lowers its cost beyond rounding."""
        p = self._evaluate(rot, pos, start)
        active = np.ones(len(start), dtype=bool)
        for _ in range(self.MAX_NODE_STEPS):
            A, g = self._node_blocks(p)
            A = self._newton_blocks(p, A)
            step = -_solve_small(A, g)
            predicted = -0.5 * np.einsum("nd,nd->n", g, step)
            active &= predicted > self.NODE_TOL * np.maximum(p.node_cost, 1.0)
            if not active.any():
                break
            step[~active] = 0.0
            slack = 1e-13 * np.maximum(p.node_cost, 1.0)  # rounding of a node's cost
            trial = self._evaluate(rot, pos, p.nodes + step, p, active)
            worse = active & (trial.node_cost > p.node_cost + slack)
            if worse.any() and self.side is not None:
                worse = self._halve_batched(rot, pos, p, step, worse, slack)
                step[worse] = 0.0
                active &= ~worse
                trial = self._evaluate(rot, pos, p.nodes + step, p, active)
            elif worse.any():
                # Halve the steps of those few nodes, evaluating only their readings.
                for _ in range(30):
                    step[worse] *= 0.5
                    costs = self._node_costs(rot, pos, p.nodes + step, np.flatnonzero(worse[self.node]))
                    worse &= costs > p.node_cost + slack
                    if not worse.any():
                        break
                step[worse] = 0.0  # no decrease along the step: those nodes stay (and are done)
                active &= ~worse
                trial = self._evaluate(rot, pos, p.nodes + step, p, active)
            p = trial
        return p

    @staticmethod
    def _poses(values: gtsam.Values, keys: list[int]) -> tuple[list[gtsam.Pose3], FloatArray, FloatArray]:
        poses = [values.atPose3(k) for k in keys]
        mats = np.array([pose.matrix() for pose in poses])
        return poses, mats[:, :3, :3], mats[:, :3, 3]

    def at(self, values: gtsam.Values) -> _Pass:
        """The readings with every node at its optimum for the cameras in ``values`` (cached)."""
        poses, rot, pos = self._poses(values, self.camera_keys)
        state = self.side.state(values) if self.side is not None else None
        key = rot.tobytes() + pos.tobytes() + (b"" if state is None else state.vector.tobytes())
        if key == self._cache_key and self._pass is not None:
            return self._pass
        self._state = state
        start = self.nodes
        if self._lin_cameras is not None and self._lin_gain is not None and self._lin_nodes is not None:
            # First-order prediction of the node optima: dx_j = -A_j^-1 B_j dc.
            dc = np.concatenate([p0.localCoordinates(p1) for p0, p1 in zip(self._lin_cameras, poses)])
            if state is not None and self._lin_state is not None:
                dc = np.concatenate([dc, state.vector - self._lin_state.vector])
            start = self._lin_nodes - self._lin_gain @ dc
        self._pass = self._solve_nodes(rot, pos, start)
        self._system = None
        self._cache_key = key
        self.nodes = self._pass.nodes
        return self._pass

    def cost(self, values: gtsam.Values) -> float:
        """f(c): the readings' cost (GTSAM error units) with every node at its optimum."""
        return float(np.sum(self.at(values).loss))

    def reduced(self, values: gtsam.Values) -> ReducedSystem:
        """The node-eliminated Gauss-Newton system at the cameras in ``values`` (cached)."""
        p = self.at(values)
        if self._system is not None:
            return self._system
        poses, rot, _ = self._poses(values, self.camera_keys)
        k, d, n, m = len(self.camera_keys), self.dim, len(p.nodes), len(self.pan)
        # Camera Jacobians: de/dxi = [de/dq skew(q) | -de/dq]; row . skew(q) = row x q.
        jc = np.empty((m, 2, 6))
        dq, q = p.dq, p.q
        for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # (dq x q)_a = dq_b q_c - dq_c q_b
            np.multiply(dq[:, :, b], q[:, None, c], out=jc[:, :, a])
            jc[:, :, a] -= dq[:, :, c] * q[:, None, b]
        jc[:, :, 3:6] = -dq
        A, g = self._node_blocks(p)
        if self.side is not None:
            return self._reduced_general(p, poses, jc, A, g)
        # Node-camera coupling B_j = sum over the pair's readings of jn^T jc, stored (n, d, k, 6).
        prod = np.matmul(p.jn.transpose(0, 2, 1), jc)  # (m, d, 6) jn^T jc per reading
        if self._b_index is None:  # flat index of each product entry in B (n, d, k, 6), once per problem
            self._b_index = (((self.node[:, None, None] * d + np.arange(d)[None, :, None]) * k
                              + self.camera[:, None, None]) * 6 + np.arange(6)[None, None, :]).ravel()
        if self._unique_pairs:
            B = np.zeros(n * d * 6 * k)
            B[self._b_index] = prod.ravel()  # one reading per (node, camera): a scatter
        else:
            B = np.bincount(self._b_index, weights=prod.ravel(), minlength=n * d * 6 * k)
        B = B.reshape(n, d, 6 * k)
        H = np.zeros((6 * k, 6 * k))
        gc = np.zeros(6 * k)
        for i, sl in enumerate(self._slices):
            block = jc[sl].reshape(-1, 6)
            H[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = block.T @ block
            gc[6 * i : 6 * i + 6] = block.T @ p.e[sl].reshape(-1)
        A_inv = _inv_small(A)
        gain = A_inv @ B  # (n, d, 6k)
        flat_b = B.reshape(n * d, 6 * k)
        S = H - flat_b.T @ gain.reshape(n * d, 6 * k)
        S = 0.5 * (S + S.T)
        grad = gc - flat_b.T @ np.einsum("nij,nj->ni", A_inv, g).reshape(-1)
        self._system = ReducedSystem(float(np.sum(p.loss)), grad, S, A, gain, g)
        self._lin_cameras, self._lin_nodes, self._lin_gain = poses, p.nodes.copy(), gain
        return self._system

    def _reduced_general(self, p: _Pass, poses: list[gtsam.Pose3], jc: FloatArray, A: FloatArray,
                         g: FloatArray) -> ReducedSystem:
        """:meth:`reduced` with extra camera-side columns: every reading's Jacobian row block
        ``[jc | dx]`` scattered into the ``6k + size`` columns (one padding column, dropped)."""
        assert self.side is not None and p.dx is not None
        k, d, n = len(self.camera_keys), self.dim, len(p.nodes)
        P = 6 * k + self.side.size
        if self._cols is None:
            pose_cols = 6 * self.camera[:, None] + np.arange(6)[None, :]
            self._cols = np.concatenate([pose_cols, self.side.columns()], axis=1)
        cols = self._cols
        w = cols.shape[1]
        J = np.concatenate([jc, p.dx], axis=2)  # (m, 2, w)
        H = np.bincount((cols[:, :, None] * (P + 1) + cols[:, None, :]).ravel(),
                        weights=np.einsum("mka,mkb->mab", J, J).ravel(), minlength=(P + 1) ** 2)
        H = H.reshape(P + 1, P + 1)[:P, :P]
        gc = np.bincount(cols.ravel(), weights=np.einsum("mka,mk->ma", J, p.e).ravel(), minlength=P + 1)[:P]
        prod = np.matmul(p.jn.transpose(0, 2, 1), J)  # (m, d, w)
        index = ((self.node[:, None, None] * d + np.arange(d)[None, :, None]) * (P + 1) + cols[:, None, :]).ravel()
        B = np.bincount(index, weights=prod.ravel(), minlength=n * d * (P + 1)).reshape(n, d, P + 1)[:, :, :P]
        del w
        A_inv = _inv_small(A)
        gain = A_inv @ B  # (n, d, P)
        flat_b = B.reshape(n * d, P)
        S = H - flat_b.T @ gain.reshape(n * d, P)
        S = 0.5 * (S + S.T)
        grad = gc - flat_b.T @ np.einsum("nij,nj->ni", A_inv, g).reshape(-1)
        # A variable whose readings' information the nodes absorb entirely (e.g. a view whose only
        # readings are of nodes read once, planar) has Schur curvature zero up to rounding of the
        # cancelled terms; that rounding, Jacobi-scaled, would swamp factor_rows: exact zero.
        absorbed = np.diagonal(S) <= 1e-10 * np.maximum(np.diagonal(H), 1e-300)
        if absorbed.any():
            S[absorbed, :] = 0.0
            S[:, absorbed] = 0.0
            grad[absorbed] = 0.0
        self._system = ReducedSystem(float(np.sum(p.loss)), grad, S, A, gain, g)
        self._lin_cameras, self._lin_nodes, self._lin_gain = poses, p.nodes.copy(), gain
        self._lin_state = self._state
        return self._system

    @property
    def keys(self) -> list[int]:
        """Keys of the reduced system's unknowns: the cameras, then the extra camera-side variables."""
        return self.camera_keys + ([] if self.side is None else self.side.keys)

    @property
    def dims(self) -> list[int]:
        return [6] * len(self.camera_keys) + ([] if self.side is None else self.side.dims)

    # -- the GTSAM factor ---------------------------------------------------------
    def factor(self) -> gtsam.CustomFactor:
        """A ``CustomFactor`` on :attr:`camera_keys` (6k + 1 rows, unit noise): see module docstring."""
        dims = self.dims
        P = sum(dims)
        rows = P + 1
        offsets = np.concatenate([[0], np.cumsum(dims)]).astype(int)
        cache = self

        def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
            if H is None:
                out = np.zeros(rows)
                out[-1] = np.sqrt(2.0 * cache.cost(values))
                return out
            system = cache.reduced(values)
            root, e_red = factor_rows(system.hessian, system.gradient)
            out = np.zeros(rows)
            out[:-1] = e_red
            out[-1] = np.sqrt(max(2.0 * system.cost - float(e_red @ e_red), 0.0))
            jac = np.vstack([root, np.zeros((1, P))])
            for i in range(len(dims)):
                H[i] = np.ascontiguousarray(jac[:, offsets[i] : offsets[i + 1]])
            return out

        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(rows), self.keys, error)

    # -- back-substitution --------------------------------------------------------
    def node_covariances(self, camera_covariance: FloatArray, values: gtsam.Values) -> FloatArray:
        """(n, d, d) node marginals ``A_j^-1 + G_j Sigma_cc G_j^T`` (G = A^-1 B) given the
        cameras' joint covariance (6k x 6k, slot order) at ``values``."""
        system = self.reduced(values)
        a_inv = np.linalg.inv(system.node_information)
        spread = system.node_gain @ camera_covariance
        cov = a_inv + np.einsum("nik,njk->nij", spread, system.node_gain)
        return 0.5 * (cov + np.transpose(cov, (0, 2, 1)))


def _inv_small(A: FloatArray) -> FloatArray:
    """Inverses of a stack of symmetric d x d blocks (closed form for d = 2, else LAPACK)."""
    if A.shape[-1] != 2:
        return np.asarray(np.linalg.inv(A), dtype=float)
    a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 1, 1]
    det = a * c - b * b
    if not np.all(det > 0):
        return np.asarray(np.linalg.inv(A), dtype=float)  # LAPACK raises on a singular block, as before
    out = np.empty_like(A)
    out[:, 0, 0] = c / det
    out[:, 1, 1] = a / det
    out[:, 0, 1] = out[:, 1, 0] = -b / det
    return out


def _eig_extremes(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Smallest and largest eigenvalue of each symmetric d x d block (closed form for d = 2)."""
    if A.shape[-1] == 2:
        mid = 0.5 * (A[:, 0, 0] + A[:, 1, 1])
        rad = np.hypot(0.5 * (A[:, 0, 0] - A[:, 1, 1]), A[:, 0, 1])
        return mid - rad, mid + rad
    eig = np.asarray(np.linalg.eigvalsh(A), dtype=float)
    return eig[:, 0], eig[:, -1]


def _solve_small(A: FloatArray, g: FloatArray) -> FloatArray:
    """``A_j^-1 g_j`` for a stack of symmetric d x d blocks (closed form for d = 2, else LAPACK)."""
    if A.shape[-1] == 2:
        a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 1, 1]
        det = a * c - b * b
        if np.all(det > 0):
            out = np.empty_like(g)
            out[:, 0] = (c * g[:, 0] - b * g[:, 1]) / det
            out[:, 1] = (a * g[:, 1] - b * g[:, 0]) / det
            return out
    return np.asarray(np.linalg.solve(A, g[..., None])[..., 0])


def factor_rows(hessian: FloatArray, gradient: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``R`` (p x p) and ``e`` (p) with ``R^T R = hessian`` and ``R^T e = gradient``.

    Symmetric eigen-decomposition after Jacobi scaling; directions of (numerically)
    zero curvature, the gauge freedoms the priors fix, get a zero row and no gradient.
    """
    diag = np.diagonal(hessian)
    d = np.sqrt(np.maximum(diag, 1e-30 * max(float(np.max(diag)), 1e-300)))
    scaled = hessian / d[:, None] / d[None, :]
    lam, vec = np.linalg.eigh(scaled)
    keep = lam > 1e-13 * max(float(lam[-1]), 1e-300)
    root_lam = np.sqrt(np.where(keep, lam, 0.0))
    root = (root_lam[:, None] * vec.T) * d[None, :]
    e = np.where(keep, (vec.T @ (gradient / d)) / np.where(keep, root_lam, 1.0), 0.0)
    return root, e
