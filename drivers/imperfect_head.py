"""What a simulated pan-tilt head with errors sees at given encoder readings.

The simulators render frames for an *ideal* head: at encoder readings (pan, tilt)
the optical frame is ``optical_to_base(pan, tilt)`` and the optical centre sits on the
axes' intersection (:mod:`fgloc.camera.pixel_angles`). A real head with the errors of
:mod:`fgloc.core.head_model` (calibration vector ``p``, that module's order and units)
reading (pan, tilt) stands at mechanical pan ``phi = pan / (1 + k_p)`` and tilt
``theta = (tilt - i_t) / (1 + k_t)``; its head frame is ``H = Rz(phi) Rx(tau) Ry(-theta)``,
its camera is turned by the collimation error, ``C = H Rz(gamma)`` (so the line of
sight is ``C x = H Rz(gamma) x``), and its optical centre sits at ``o = H (0, l_y, l_z)``.

:func:`head_view` gives the rotation ``M = C head_rotation(pan, tilt)^T`` (the ideal
head's frame -> the real camera's frame) and ``o``. A point ``q`` (base frame, relative
to the axes' intersection) appears in the real camera's image where the ideal head at the
same readings shows the base direction ``M^T (q - o)``
(:func:`ideal_equivalent_directions`), so every renderer keeps drawing for an ideal head
and the simulated encoders read what the imperfect head reads: the point is centred in
the image exactly when ``(pan, tilt) = head_pan_tilt(q, p)`` (tested in
tests/test_head_rig.py). Radians, survey length units.

The optical centre moves with zoom: :func:`head_at_zoom` gives the calibration vector of a
head at a zoom whose lever arm a rig lists (rig.json ``lever_by_zoom``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from fgloc.camera.pixel_angles import head_rotation
from fgloc.core.geometry import FloatArray, pan_tilt_bearing, rot_x, rot_y, rot_z
from fgloc.core.head_model import HEAD_DIM


def head_at_zoom(params: ArrayLike, levers: Mapping[float, tuple[float, float]] | None,
                 zoom: float | None) -> FloatArray:
    """``params`` (7,) with the lever arm ``levers`` gives at ``zoom`` (unchanged where it gives none)."""
    p = np.array(params, dtype=float).reshape(HEAD_DIM)
    if levers and zoom is not None:
        for z, lever in levers.items():
            if abs(float(z) - float(zoom)) < 1e-9:
                p[5], p[6] = float(lever[0]), float(lever[1])
    return p


def head_view(params: ArrayLike, pan: float, tilt: float) -> tuple[FloatArray, FloatArray]:
    """``(M, o)`` of a head with errors ``params`` (7,) at encoder readings (pan, tilt) radians.

    ``M`` (3x3) takes the ideal head's frame at (pan, tilt) to the real camera frame
    (both base-frame rotations: real = ``M`` ideal); ``o`` (3,) is the optical centre
    in the base frame relative to the axes' intersection (survey units).
    """
    p = np.asarray(params, dtype=float).reshape(HEAD_DIM)
    phi = pan / (1.0 + p[3])
    theta = (tilt - p[0]) / (1.0 + p[4])
    h = rot_z(phi) @ rot_x(p[2]) @ rot_y(-theta)
    camera = h @ rot_z(p[1])
    return camera @ head_rotation(pan, tilt).T, h @ np.array([0.0, p[5], p[6]])


def ideal_equivalent_directions(params: ArrayLike, pan: float, tilt: float, points: ArrayLike,
                                centre_shift: float = 0.0) -> FloatArray:
    """Base-frame directions (K, 3), not normalized, that the *ideal* head at (pan, tilt) sees
    where the head with errors ``params`` at the same encoder readings sees ``points`` (K, 3)
    (base frame, relative to the axes' intersection).

    ``centre_shift`` (survey units) moves the optical centre further along the real line of
    sight (an entrance pupil that moves with zoom, see drivers/rendered_camera.py).
    """
    m, o = head_view(params, pan, tilt)
    if centre_shift:
        o = o + centre_shift * (m @ pan_tilt_bearing(pan, tilt))
    q = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.asarray((q - o) @ m, dtype=float)
