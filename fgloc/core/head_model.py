"""A non-ideal pan-tilt head: the classic theodolite errors as a per-camera calibration vector.

The ideal head (``fgloc.core.geometry``) has a pan axis (base z), a tilt axis
perpendicular to it, a line of sight perpendicular to the tilt axis, all meeting
in the optical centre, and encoders that read the true angles. A real head
deviates; this module models the deviations a survey can estimate.

Kinematics (base frame, radians, survey length units). With mechanical pan
``phi`` about base z and mechanical tilt ``theta`` about the trunnion axis, the
head frame is ``H = Rz(phi) Rx(tau) Ry(-theta)``; the line of sight is
``H Rz(gamma) x`` and the optical centre sits at ``H l`` with
``l = (0, l_y, l_z)``. A point ``q`` (base frame, relative to the axes'
intersection) is seen when ``r = H^T q - l`` is parallel to ``Rz(gamma) x``.
The encoders read ``pan = (1 + k_p) phi`` and ``tilt = (1 + k_t) theta + i_t``.

The calibration vector (:data:`HEAD_PARAMETERS`, this order):

=====  ==================  ==========  ==================================================
index  name                unit        meaning
=====  ==================  ==========  ==================================================
0      ``tilt_index``      rad         vertical index error ``i_t``: tilt read at level sight
1      ``collimation``     rad         ``gamma``: line of sight turned toward +pan from the
                                       perpendicular to the tilt axis (pan reads ~ -gamma/cos t)
2      ``trunnion``        rad         ``tau``: tilt axis rolled about the pointing direction
                                       (pan reads ~ +tau tan t)
3      ``pan_scale``       1           ``k_p``: relative pan encoder scale error
4      ``tilt_scale``      1           ``k_t``: relative tilt encoder scale error
5      ``lever_y``         survey      ``l_y``: optical centre left of the axes (head frame)
6      ``lever_z``         survey      ``l_z``: optical centre above the axes (head frame)
=====  ==================  ==========  ==================================================

Left out because bearings cannot observe them at all: a **pan index offset**
(the encoder zero's azimuth) is the base yaw; a **vertical-axis tilt** is the
base roll and pitch; the lever arm **along the line of sight** (``l_x``) slides
the centre along the ray it sees. Pan scale acts on the wrapped pan in
(-pi, pi] (an encoder's range does not cross +-180 degrees).

**Zoom.** The optical centre moves with zoom (the paper: the centre of rotation
coincides with the focal point only at the widest zoom), the axes and encoders do
not. A camera whose readings were taken at G distinct zooms (``Observation.zoom``,
:func:`zoom_groups`) has the *extended* vector of :func:`head_dim` (G) = 5 + 2 G
entries: the five angular and scale parameters (indices 0..4, shared) and one lever
arm ``(l_y, l_z)`` per zoom group g at indices ``5 + 2 g, 6 + 2 g`` (groups in
ascending zoom, readings without a zoom first). A reading of group g sees the
7-vector ``extended[reading_index(g)]``. With one zoom (G = 1) the extended vector
*is* the 7-vector above.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from fgloc.core.geometry import FloatArray, wrap_angle

if TYPE_CHECKING:
    from fgloc.core.model import Survey

HEAD_PARAMETERS: tuple[str, ...] = (
    "tilt_index", "collimation", "trunnion", "pan_scale", "tilt_scale", "lever_y", "lever_z",
)
HEAD_DIM = len(HEAD_PARAMETERS)
#: Unit of each parameter, for reports.
HEAD_UNITS: tuple[str, ...] = ("rad", "rad", "rad", "1", "1", "survey", "survey")
#: Parameter groups reported together (observability, model selection summaries).
HEAD_GROUPS: dict[str, tuple[int, ...]] = {
    "tilt_index": (0,), "collimation": (1,), "trunnion": (2,), "pan_scale": (3,), "tilt_scale": (4,),
    "lever_arm": (5, 6),
}

#: Datasheet-scale tolerances of a commodity PTZ head, read as ~95 % bounds of the
#: population of heads: index, collimation and trunnion 0.6 / 0.4 / 0.4 degree, encoder
#: scales 1 %, lever arm 0.1 % of the baseline per component.
DATASHEET_TOLERANCES: FloatArray = np.array(
    [np.deg2rad(0.6), np.deg2rad(0.4), np.deg2rad(0.4), 0.01, 0.01, 0.001, 0.001]
)
#: The zero-mean Gaussian prior of each parameter (one sigma): a tolerance quoted as a
#: ~95 % bound is two sigma, so sigma = tolerance / 2 = the "typical head errors" of
#: issue 17 (tilt index 0.3 degree, collimation and trunnion 0.2 degree, encoder scales
#: 0.5 %, lever arm 0.05 % of the baseline). The simulator draws heads from this same
#: population (:func:`fgloc.sim.head_errors.sample_head_errors`), so the prior describes it.
DEFAULT_PRIOR_SIGMAS: FloatArray = DATASHEET_TOLERANCES / 2.0

#: Entries of the extended vector shared by every zoom (tilt index ... tilt scale).
SHARED_DIM = 5
#: Zooms equal to this many decimals (fraction of the optical range) are one zoom group.
ZOOM_DIGITS = 6


def head_dim(n_zooms: int = 1) -> int:
    """Length of a camera's extended head vector with ``n_zooms`` lever arms (7 for one zoom)."""
    return SHARED_DIM + 2 * max(int(n_zooms), 1)


def reading_index(group: int) -> tuple[int, ...]:
    """Extended-vector index of each of the 7 parameters a reading of zoom ``group`` sees."""
    return (0, 1, 2, 3, 4, SHARED_DIM + 2 * group, SHARED_DIM + 2 * group + 1)


def lever_group(index: int) -> int | None:
    """The zoom group whose lever arm extended index ``index`` is, None for a shared parameter."""
    return None if index < SHARED_DIM else (index - SHARED_DIM) // 2


def local_index(index: int, group: int) -> int | None:
    """Position in a zoom-``group`` reading's 7-vector of extended index ``index`` (None: another
    group's lever arm, which the reading does not see)."""
    g = lever_group(index)
    if g is None:
        return index
    return None if g != group else 5 + (index - SHARED_DIM) % 2


def extend_vector(values7: FloatArray, n_zooms: int) -> FloatArray:
    """A 7-vector (e.g. prior sigmas) as an extended vector: its lever arm repeated per zoom group."""
    v = np.asarray(values7, dtype=float)
    if len(v) == head_dim(n_zooms):
        return v.copy()
    return np.concatenate([v[:SHARED_DIM]] + [v[SHARED_DIM:HEAD_DIM]] * max(int(n_zooms), 1))


def reading_params(extended: FloatArray, group: np.ndarray) -> FloatArray:
    """(M, 7) parameters each reading sees: ``extended`` (D,) or (M, D), ``group`` (M,) zoom groups."""
    ext = np.asarray(extended, dtype=float)
    g = np.asarray(group, dtype=np.int64)
    idx = np.array([reading_index(0)] * len(g), dtype=np.int64).reshape(-1, HEAD_DIM)
    idx[:, 5] += 2 * g
    idx[:, 6] += 2 * g
    if ext.ndim == 1:
        return ext[idx]
    return np.take_along_axis(ext, idx, axis=1)


def zoom_label(zoom: float | None) -> str:
    """How a zoom group is named in reports: ``zoom 0.25`` or ``survey zoom`` (no zoom given)."""
    return "survey zoom" if zoom is None else f"zoom {zoom:g}"


def parameter_names(zooms: Sequence[float | None]) -> tuple[str, ...]:
    """Names of the extended vector's entries: :data:`HEAD_PARAMETERS` for one zoom, else the
    shared five and ``lever_y@<zoom>``, ``lever_z@<zoom>`` per group (``@-`` : no zoom given)."""
    if len(zooms) <= 1:
        return HEAD_PARAMETERS
    out = list(HEAD_PARAMETERS[:SHARED_DIM])
    for z in zooms:
        tag = "-" if z is None else f"{z:g}"
        out += [f"lever_y@{tag}", f"lever_z@{tag}"]
    return tuple(out)


def head_groups(zooms: Sequence[float | None]) -> dict[str, tuple[int, ...]]:
    """Parameter groups of the extended vector: :data:`HEAD_GROUPS` for one zoom, else the shared
    five and ``lever_arm@<zoom>`` per group."""
    if len(zooms) <= 1:
        return dict(HEAD_GROUPS)
    out = {k: v for k, v in HEAD_GROUPS.items() if k != "lever_arm"}
    names = parameter_names(zooms)
    for g in range(len(zooms)):
        out["lever_arm@" + names[SHARED_DIM + 2 * g].split("@")[1]] = (SHARED_DIM + 2 * g, SHARED_DIM + 2 * g + 1)
    return out


def zoom_groups(survey: Survey) -> tuple[dict[str, tuple[float | None, ...]], np.ndarray]:
    """Per camera its distinct reading zooms (ascending, None first: readings without a zoom),
    and (M,) each observation's group index into its camera's tuple. A camera without readings
    has one group (None)."""
    per_cam: dict[str, list[float | None]] = {c: [] for c in survey.camera_ids}
    keys = []
    for o in survey.observations:
        z = None if o.zoom is None else round(float(o.zoom), ZOOM_DIGITS)
        keys.append(z)
        if z not in per_cam[o.camera]:
            per_cam[o.camera].append(z)
    groups: dict[str, tuple[float | None, ...]] = {}
    for c, zs in per_cam.items():
        groups[c] = tuple(sorted(zs, key=lambda z: (z is not None, z or 0.0))) or (None,)
    index = np.array([groups[o.camera].index(z) for o, z in zip(survey.observations, keys)], dtype=np.int64)
    return groups, index


_NEWTON_STEPS = 4
_X, _Y, _Z = np.eye(3)


@dataclass(frozen=True)
class HeadCalibration:
    """One camera's head calibration: ``values`` (7,) in :data:`HEAD_PARAMETERS` order.

    ``covariance`` (7, 7) is the estimate's uncertainty (None: exact / unknown).
    """

    values: FloatArray
    covariance: FloatArray | None = None

    @staticmethod
    def ideal() -> HeadCalibration:
        """The ideal head: every error zero."""
        return HeadCalibration(np.zeros(HEAD_DIM))

    def as_dict(self) -> dict[str, float]:
        """Parameter name to value."""
        return {n: float(v) for n, v in zip(HEAD_PARAMETERS, self.values)}


def _rot(axis: int, angle: FloatArray) -> FloatArray:
    """Batched right-handed rotations (..., 3, 3) about base axis 0, 1 or 2."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(np.shape(angle) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _mv(m: FloatArray, v: FloatArray) -> FloatArray:
    return np.einsum("...ij,...j->...i", m, v)


def _mechanical_start(q: FloatArray, gamma: FloatArray, tau: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Closed-form (phi, theta) without lever arm: the sight line through q's direction."""
    u = q / np.linalg.norm(q, axis=-1, keepdims=True)
    sin_t = (u[..., 2] - np.sin(gamma) * np.sin(tau)) / (np.cos(gamma) * np.cos(tau))
    theta = np.arcsin(np.clip(sin_t, -1.0, 1.0))
    wx = np.cos(gamma) * np.cos(theta)
    wy = np.sin(gamma) * np.cos(tau) - np.cos(gamma) * np.sin(theta) * np.sin(tau)
    phi = np.arctan2(u[..., 1], u[..., 0]) - np.arctan2(wy, wx)
    return phi, theta


def _constraint(q: FloatArray, phi: FloatArray, theta: FloatArray, p: FloatArray) -> dict[str, FloatArray]:
    """F = A(gamma) r with r = H^T q - l, and its partials (batched)."""
    gamma, tau = p[..., 1], p[..., 2]
    rz, rx, ry = _rot(2, -phi), _rot(0, -tau), _rot(1, theta)
    a = _mv(rz, q)
    b = _mv(rx, a)
    m = _mv(ry, b)
    r = m.copy()
    r[..., 1] -= p[..., 5]
    r[..., 2] -= p[..., 6]
    sg, cg = np.sin(gamma), np.cos(gamma)
    A = np.zeros(np.shape(gamma) + (2, 3))
    A[..., 0, 0], A[..., 0, 1], A[..., 1, 2] = -sg, cg, 1.0
    ry_rx = ry @ rx
    dm_dphi = _mv(ry_rx, -np.cross(_Z, a))
    dm_dtau = _mv(ry, -np.cross(_X, b))
    dm_dtheta = np.cross(_Y, m)
    F = _mv(A, r)
    J_a = np.stack([_mv(A, dm_dphi), _mv(A, dm_dtheta)], axis=-1)  # (..., 2, 2)
    F_q = A @ ry_rx @ rz  # (..., 2, 3) = A H^T
    F_p = np.zeros(np.shape(gamma) + (2, HEAD_DIM))
    F_p[..., 0, 1] = -cg * r[..., 0] - sg * r[..., 1]
    F_p[..., :, 2] = _mv(A, dm_dtau)
    F_p[..., 0, 5] = -cg
    F_p[..., 1, 6] = -1.0
    return {"F": F, "J_a": J_a, "F_q": F_q, "F_p": F_p}


def head_pan_tilt(
    q: ArrayLike, params: ArrayLike, jacobians: bool = True
) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
    """Encoder readings (pan, tilt) at which a head with ``params`` sees base-frame point(s) ``q``.

    ``q`` (..., 3) is relative to the axes' intersection (the camera's position),
    ``params`` (..., 7) broadcasts against it. Returns ``pan`` (wrapped to
    (-pi, pi]), ``tilt``, and when asked ``d(pan, tilt)/dq`` (..., 2, 3) and
    ``d(pan, tilt)/dparams`` (..., 2, 7), analytic (implicit-function theorem on
    the sight condition). All zero ``params`` give exactly the ideal model.
    """
    q = np.asarray(q, dtype=float)
    p = np.broadcast_to(np.asarray(params, dtype=float), q.shape[:-1] + (HEAD_DIM,))
    phi, theta = _mechanical_start(q, p[..., 1], p[..., 2])
    for _ in range(_NEWTON_STEPS if np.any(p[..., 5:7]) else 1):  # exact start without lever arm
        c = _constraint(q, phi, theta, p)
        step = np.linalg.solve(c["J_a"], c["F"][..., None])[..., 0]
        phi, theta = phi - step[..., 0], theta - step[..., 1]
    phi = wrap_angle(phi)
    pan = (1.0 + p[..., 3]) * phi
    tilt = (1.0 + p[..., 4]) * theta + p[..., 0]
    if not jacobians:
        return pan, tilt, None, None
    c = _constraint(q, phi, theta, p)
    J_inv = np.linalg.inv(c["J_a"])
    d_ang_q = -J_inv @ c["F_q"]
    d_ang_p = -J_inv @ c["F_p"]
    scale = np.stack([1.0 + p[..., 3], 1.0 + p[..., 4]], axis=-1)[..., None]
    d_q = scale * d_ang_q
    d_p = scale * d_ang_p
    d_p[..., 0, 3] += phi
    d_p[..., 1, 4] += theta
    d_p[..., 1, 0] += 1.0
    return pan, tilt, d_q, d_p


def head_view_pan_tilt(
    q: ArrayLike, params: ArrayLike, view_pan: ArrayLike, view_tilt: ArrayLike, jacobians: bool = True
) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
    """The (pan, tilt) an **off-centre** reading gives for base-frame point(s) ``q`` when a head
    with ``params`` stands at encoder readings (``view_pan``, ``view_tilt``) radians.

    A coded survey reads the head once per view and composes each LED's pixel with those
    encoder angles through the *ideal* head (:func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt`).
    The real head at those readings has head frame ``H = Rz(phi) Rx(tau) Ry(-theta)``
    (``phi = view_pan / (1 + k_p)``, ``theta = (view_tilt - i_t) / (1 + k_t)``), camera frame
    ``H Rz(gamma)`` and optical centre ``o = H l``; the ideal head at the same readings
    (frame ``K = Rz(view_pan) Ry(-view_tilt)``) shows ``q`` along
    ``e = K Rz(-gamma) (H^T q - l)`` (:func:`fgloc.drivers.imperfect_head.ideal_equivalent_directions`),
    and the reading is ``e``'s bearing (pan wrapped to (-pi, pi]). When ``q`` is centred in
    the view (the view's readings are :func:`head_pan_tilt` of ``q``) the reading is the view's
    readings: the centred model is this one at the view that centres the point.

    Shapes as :func:`head_pan_tilt` (``view_pan``, ``view_tilt`` broadcast against ``q``'s
    leading axes); returns ``pan``, ``tilt`` and when asked ``d(pan, tilt)/dq`` (..., 2, 3) and
    ``d(pan, tilt)/dparams`` (..., 2, 7), analytic, the view's readings held fixed.
    """
    q = np.asarray(q, dtype=float)
    p = np.broadcast_to(np.asarray(params, dtype=float), q.shape[:-1] + (HEAD_DIM,))
    pan0 = np.broadcast_to(np.asarray(view_pan, dtype=float), q.shape[:-1])
    tilt0 = np.broadcast_to(np.asarray(view_tilt, dtype=float), q.shape[:-1])
    kp, kt = 1.0 + p[..., 3], 1.0 + p[..., 4]
    phi = pan0 / kp
    theta = (tilt0 - p[..., 0]) / kt
    gamma, tau = p[..., 1], p[..., 2]
    rz, rx, ry = _rot(2, -phi), _rot(0, -tau), _rot(1, theta)
    a = _mv(rz, q)
    b = _mv(rx, a)
    m = _mv(ry, b)  # H^T q
    r = m.copy()
    r[..., 1] -= p[..., 5]
    r[..., 2] -= p[..., 6]
    k = _rot(2, pan0) @ _rot(1, -tilt0)  # the ideal head's frame at the view's readings
    k_g = k @ _rot(2, -gamma)  # K Rz(-gamma)
    e = _mv(k_g, r)
    x, y, z = e[..., 0], e[..., 1], e[..., 2]
    rho2 = x * x + y * y
    pan = wrap_angle(np.arctan2(y, x))
    tilt = np.arctan2(z, np.sqrt(rho2))
    if not jacobians:
        return pan, tilt, None, None
    rho, n2 = np.sqrt(rho2), rho2 + z * z
    d_b = np.zeros(np.shape(x) + (2, 3))  # d(pan, tilt)/de
    d_b[..., 0, 0], d_b[..., 0, 1] = -y / rho2, x / rho2
    d_b[..., 1, 0], d_b[..., 1, 1], d_b[..., 1, 2] = -x * z / (n2 * rho), -y * z / (n2 * rho), rho / n2
    d_q = d_b @ k_g @ ry @ rx @ rz
    de_dp = np.zeros(np.shape(x) + (3, HEAD_DIM))
    dm_dtheta = np.cross(_Y, m)
    de_dp[..., 0] = _mv(k_g, dm_dtheta) * (-1.0 / kt)[..., None]
    de_dp[..., 1] = -np.cross(k[..., :, 2], e)  # d/dgamma K Rz(-gamma) r = -K (z x Rz(-gamma) r) = -(K z) x e
    de_dp[..., 2] = _mv(k_g, _mv(ry, -np.cross(_X, b)))
    de_dp[..., 3] = _mv(k_g, _mv(ry @ rx, -np.cross(_Z, a))) * (-phi / kp)[..., None]
    de_dp[..., 4] = _mv(k_g, dm_dtheta) * (-theta / kt)[..., None]
    de_dp[..., 5] = -k_g[..., :, 1]
    de_dp[..., 6] = -k_g[..., :, 2]
    return pan, tilt, d_q, d_b @ de_dp
