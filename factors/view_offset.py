"""A view's head error as a rotation of the bearings read in that view.

A coded survey reads the head once per view and composes every decoded mote's
(pan, tilt) from that head reading and the mote's pixel. A head reading off by
``v = (v_pan, v_tilt)`` (radians) turns every bearing of the view by the same
rotation: the head frame at the read angles is ``Rz(p + v_pan) Ry(-(t + v_tilt))``
instead of ``Rz(p) Ry(-t)``, so a base-frame bearing ``q`` is read as ::

    q' = M(v) q,   M(v) = Rz(v_pan) * Rz(h) Ry(-v_tilt) Rz(-h)

with ``h`` the view's head pan (the tilt error turns about the tilt axis at that
pan; the head tilt itself drops out). For the bearing at the view centre this is
``pan + v_pan``, ``tilt + v_tilt``; off-centre, a tilt error also moves pan by
about ``v_tilt sin(pan - h) tan(tilt)``. Derivatives (``u = Rz(v_pan + h) y``)::

    dq'/dq = M,   dq'/dv_pan = z x q',   dq'/dv_tilt = -u x q'

Frames: the camera's base frame; angles in radians. Vectorized over a leading axis.
"""

from __future__ import annotations

import numpy as np

from fgloc.core.geometry import FloatArray, bearing_pan_tilt, pan_tilt_jacobian, pan_tilt_residual, skew


def view_rotation(v: FloatArray, head_pan: FloatArray) -> FloatArray:
    """(m, 3, 3) ``M(v)`` of offsets ``v`` (m, 2) at view head pans ``head_pan`` (m,)."""
    v = np.asarray(v, dtype=float).reshape(-1, 2)
    h = np.asarray(head_pan, dtype=float).reshape(-1)
    ch, sh = np.cos(h), np.sin(h)
    ct, st = np.cos(v[:, 1]), np.sin(v[:, 1])
    # A = Rz(h) Ry(-t) Rz(-h): rotation by -t about a = (-sin h, cos h, 0) (Rodrigues).
    a = np.stack([-sh, ch, np.zeros_like(h)], axis=1)
    skew_a = np.zeros((len(h), 3, 3))
    skew_a[:, 0, 2], skew_a[:, 1, 2] = a[:, 1], -a[:, 0]
    skew_a[:, 2, 0], skew_a[:, 2, 1] = -a[:, 1], a[:, 0]
    aa = np.einsum("mi,mj->mij", a, a)
    A = ct[:, None, None] * np.eye(3) - st[:, None, None] * skew_a + (1.0 - ct)[:, None, None] * aa
    cp, sp = np.cos(v[:, 0]), np.sin(v[:, 0])
    Rz = np.zeros((len(h), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = cp, -sp, sp, cp, 1.0
    return np.asarray(Rz @ A)


def rotate_by_view(q: FloatArray, v: FloatArray, head_pan: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(q' (m, 3), dq'/dq (m, 3, 3), dq'/dv (m, 3, 2))`` for bearings ``q`` (m, 3)."""
    M = view_rotation(v, head_pan)
    qp = np.einsum("mij,mj->mi", M, np.asarray(q, dtype=float).reshape(-1, 3))
    phi = np.asarray(v, dtype=float).reshape(-1, 2)[:, 0] + np.asarray(head_pan, dtype=float).reshape(-1)
    dv = np.empty((len(qp), 3, 2))
    dv[:, 0, 0], dv[:, 1, 0], dv[:, 2, 0] = -qp[:, 1], qp[:, 0], 0.0  # z x q'
    ux, uy = -np.sin(phi), np.cos(phi)  # -u x q' = q' x u, u = (ux, uy, 0)
    dv[:, 0, 1] = -qp[:, 2] * uy
    dv[:, 1, 1] = qp[:, 2] * ux
    dv[:, 2, 1] = qp[:, 0] * uy - qp[:, 1] * ux
    return qp, M, dv


def view_pan_tilt_error(
    rotation: FloatArray, position: FloatArray, point: FloatArray, pan: FloatArray, tilt: FloatArray,
    v: FloatArray, head_pan: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Errors and Jacobians of readings taken in views, batched over m (see the module docstring).

    ``rotation`` (m, 3, 3), ``position`` / ``point`` (m, 3) world, ``pan`` / ``tilt`` (m,)
    measured, ``v`` (m, 2) the view offsets, ``head_pan`` (m,). Returns ``e`` (m, 2)
    (measured minus predicted, pan wrapped), ``H_pose`` (m, 2, 6) (GTSAM ``Pose3``
    tangent ``[omega, v]``, right perturbation), ``H_point`` (m, 2, 3), ``H_view`` (m, 2, 2).
    """
    q = np.einsum("mji,mj->mi", rotation, np.asarray(point, dtype=float) - position)
    qp, M, dv = rotate_by_view(q, v, head_pan)
    pred_pan, pred_tilt = bearing_pan_tilt(qp)
    e = pan_tilt_residual(pan, tilt, pred_pan, pred_tilt)
    d = -pan_tilt_jacobian(qp) @ M  # de/dq
    h_pose = np.concatenate([d @ skew(q), -d], axis=2)
    h_point = np.einsum("mij,mkj->mik", d, rotation)
    h_view = -pan_tilt_jacobian(qp) @ dv
    return e, h_pose, h_point, h_view
