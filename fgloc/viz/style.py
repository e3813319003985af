"""How fgloc draws: colours (RGBA), sizes in UI points, drawing options, palettes.

Colours are 8-bit RGBA tuples; radii are Rerun UI points (screen size, the same at
any zoom). Nothing here logs anything.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun as rr

from fgloc.core.confidence import DEFAULT_CONFIDENCE

# Colours (RGBA). Nodes orange, truth green, errors magenta, 95% regions cyan, outliers red.
ESTIMATE_COLOR = (255, 160, 0, 255)
TRUTH_COLOR = (60, 220, 90, 255)
ERROR_COLOR = (255, 60, 220, 255)
COVARIANCE_COLOR = (0, 210, 255, 255)
OUTLIER_COLOR = (255, 0, 0, 255)
ITERATE_COLOR = (200, 200, 200, 255)
GROUND_COLOR = (90, 90, 90, 255)
BASELINE_COLOR = (255, 255, 255, 255)
CAMERA_COLORS = [(80, 150, 255), (255, 230, 60), (200, 120, 255), (255, 120, 90), (120, 255, 220)]
RAY_ALPHA = 28

# Sizes in UI points (negative radii in Rerun), so they read the same at any zoom.
NODE_RADIUS = rr.Radius.ui_points(4.0)
TRUTH_RADIUS = rr.Radius.ui_points(3.0)
SUBSET_RADIUS = rr.Radius.ui_points(1.5)
LINE_RADIUS = rr.Radius.ui_points(1.0)
THIN_LINE_RADIUS = rr.Radius.ui_points(0.5)
ERROR_RADIUS = rr.Radius.ui_points(1.5)


@dataclass(frozen=True)
class VizOptions:
    """How to draw: confidence of the ellipses, size of camera frusta, table length.

    ``frustum_depth`` is in gauge units (baseline = 1); ``ray_overshoot`` is how
    far rays run past the estimated node, as a fraction of the range. Node labels
    are shown on hover unless ``show_node_labels``; the ``labelled_worst_nodes``
    worst nodes are always labelled (``world/nodes/worst``).
    """

    confidence: float = DEFAULT_CONFIDENCE
    frustum_depth: float = 0.05
    ray_overshoot: float = 0.1
    worst_nodes: int = 10
    show_node_labels: bool = False
    labelled_worst_nodes: int = 5


def camera_color(index: int, alpha: int = 255) -> tuple[int, int, int, int]:
    """A distinct colour per camera index."""
    r, g, b = CAMERA_COLORS[index % len(CAMERA_COLORS)]
    return (r, g, b, alpha)


def node_palette(n: int) -> np.ndarray:
    """``n`` well separated RGBA colours (uint8, (n, 4)) from golden-ratio hues."""
    h = (np.arange(n) * 0.618033988749895) % 1.0
    s, v = 0.75, 1.0
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    rgb = np.stack([r, g, b], axis=1) * 255.0
    return np.concatenate([rgb, np.full((n, 1), 255.0)], axis=1).astype(np.uint8)


def time_kwargs(static: bool) -> dict[str, bool]:
    """Keyword arguments of ``RecordingStream.log``: static (visible at any time) or on the current time."""
    return {"static": True} if static else {}
