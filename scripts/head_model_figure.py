"""The figure of docs/head-calibration.md "The model": the head's axes with its errors, and what
each error does to the readings, both computed by :mod:`fgloc.core.head_model`.

Left: the head frame ``H = Rz(phi) Rx(tau) Ry(-theta)`` at one mechanical pan and tilt, with
exaggerated errors (trunnion and collimation 8 degrees, lever arm 0.08 / 0.06 of the unit
length) beside the ideal head: pan axis, tilt (trunnion) axis, line of sight and optical centre.
Right: the reading error (head reading minus the ideal head's, degrees) of a point at range 0.5
(baseline units) and azimuth 30 degrees, against the true elevation, for each parameter at its
typical size (one prior sigma, :data:`fgloc.core.head_model.DEFAULT_PRIOR_SIGMAS`).

    .venv/bin/python scripts/head_model_figure.py [--out docs/img/head-model.png]
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fgloc.core.head_model import DEFAULT_PRIOR_SIGMAS, HEAD_DIM, HEAD_PARAMETERS, head_pan_tilt  # noqa: E402


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = -s, s
    return m


def head_frame(phi: float, theta: float, tau: float) -> np.ndarray:
    """``H = Rz(phi) Rx(tau) Ry(-theta)`` (the model of fgloc/core/head_model.py)."""
    return _rot(2, phi) @ _rot(0, tau) @ _rot(1, -theta)


def draw_axes(ax: plt.Axes) -> None:
    phi, theta = np.deg2rad(30.0), np.deg2rad(25.0)
    tau, gamma, lever = np.deg2rad(8.0), np.deg2rad(8.0), np.array([0.0, 0.08, 0.06])
    o = np.zeros(3)

    def arrow(v: np.ndarray, start: np.ndarray, style: str, color: str, label: str | None = None) -> None:
        ax.plot(*np.stack([start, start + v]).T, style, color=color, lw=2, label=label)

    arrow(np.array([0, 0, 1.0]), o, "-", "k", "pan axis (base z)")
    H0 = head_frame(phi, theta, 0.0)
    H = head_frame(phi, theta, tau)
    arrow(1.2 * H0[:, 1], -0.6 * H0[:, 1], ":", "tab:blue", "tilt axis, ideal")
    arrow(1.2 * H[:, 1], -0.6 * H[:, 1], "-", "tab:blue", "tilt axis with trunnion error τ")
    arrow(1.1 * H0[:, 0], o, ":", "tab:red", "line of sight, ideal")
    centre = H @ lever
    sight = H @ _rot(2, gamma)[:, 0]
    arrow(1.1 * sight, centre, "-", "tab:red", "line of sight: collimation γ, from the optical centre")
    ax.plot(*np.stack([o, centre]).T, "-", color="tab:green", lw=3, label="lever arm l = (0, l_y, l_z)")
    ax.scatter(*centre, color="tab:green", s=30)
    ax.set_xlim(-0.3, 1.1)
    ax.set_ylim(-0.6, 0.9)
    ax.set_zlim(0.0, 1.0)
    ax.set_xlabel("base x")
    ax.set_ylabel("base y")
    ax.set_zlabel("base z")
    ax.view_init(elev=20, azim=-25)
    ax.set_title("head at pan 30°, tilt 25°\n(errors exaggerated: τ = γ = 8°, |l| = 0.1)", fontsize=9)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.02), fontsize=7, ncol=2)


def reading_errors(elevation_deg: np.ndarray, azimuth_deg: float = 30.0, rng: float = 0.5) -> dict[str, np.ndarray]:
    """(pan, tilt) reading error in degrees per parameter at one prior sigma, (n, 2) each."""
    el, az = np.deg2rad(elevation_deg), np.deg2rad(azimuth_deg)
    q = rng * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    pan0, tilt0, _, _ = head_pan_tilt(q, np.zeros(HEAD_DIM), jacobians=False)
    out = {}
    for i, name in enumerate(HEAD_PARAMETERS):
        p = np.zeros(HEAD_DIM)
        p[i] = DEFAULT_PRIOR_SIGMAS[i]
        pan, tilt, _, _ = head_pan_tilt(q, p, jacobians=False)
        out[name] = np.rad2deg(np.stack([pan - pan0, tilt - tilt0], axis=-1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img/head-model.png")
    args = ap.parse_args()
    fig = plt.figure(figsize=(14, 5.2))
    grid = fig.add_gridspec(1, 3, width_ratios=(1.3, 1.0, 1.0))
    draw_axes(fig.add_subplot(grid[0, 0], projection="3d"))
    elevation = np.linspace(-70.0, 70.0, 141)
    errors = reading_errors(elevation)
    for k, (axis, title) in enumerate((("pan", "pan reading error"), ("tilt", "tilt reading error"))):
        ax = fig.add_subplot(grid[0, 1 + k])
        for name, e in errors.items():
            ax.plot(elevation, e[:, k], label=name)
        ax.axhline(0.1, color="0.6", lw=0.8, ls="--")
        ax.axhline(-0.1, color="0.6", lw=0.8, ls="--", label="σ = 0.1° of a reading")
        ax.set_xlabel("elevation of the point (deg)")
        ax.set_ylabel(f"{axis} error (deg)")
        ax.set_title(f"{title}, each parameter at one prior σ\n(point at azimuth 30°, range 0.5)", fontsize=9)
        ax.grid(alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
