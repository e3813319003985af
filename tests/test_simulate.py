"""The simulator: deterministic by seed, truth in the gauge frame, noise as specified."""

import numpy as np

from fgloc.core.geometry import project_pan_tilt, wrap_angle
from fgloc.sim.scenes import PAPER_SIGMA, PaperScenario, paper_scenario


def test_deterministic_by_seed() -> None:
    a = paper_scenario(PaperScenario(seed=42))
    b = paper_scenario(PaperScenario(seed=42))
    c = paper_scenario(PaperScenario(seed=43))
    assert a.observations == b.observations
    assert a.observations != c.observations


def test_truth_in_gauge_frame_and_paper_layout() -> None:
    s = paper_scenario(PaperScenario(heights=(0.2, 0.3), seed=1))
    np.testing.assert_allclose(s.truth.cameras["cam0"].position, [0, 0, 0.2])
    np.testing.assert_allclose(s.truth.cameras["cam1"].position, [1, 0, 0.3])
    nodes = s.truth_node_array()
    assert nodes.shape == (100, 3) and np.all(nodes[:, 2] == 0)
    assert np.all((nodes[:, :2] >= 0) & (nodes[:, :2] <= 1))
    assert len(s.observations) == 200


def test_noise_is_gaussian_with_sigma() -> None:
    """Truth: readings minus exact projections / sigma ~ N(0, 1) in pan and tilt (chi-square on variance)."""
    s = paper_scenario(PaperScenario(n_nodes=2000, seed=3, repeats=2))
    res = []
    for o in s.observations:
        cam = s.truth.cameras[o.camera]
        p, t = project_pan_tilt(cam.rotation, cam.position, s.truth.nodes[o.node])
        res.append([wrap_angle(o.pan - p), o.tilt - t])
    z = np.array(res) / PAPER_SIGMA
    assert abs(z.mean()) < 0.03
    assert abs(z[:, 0].std() - 1) < 0.03 and abs(z[:, 1].std() - 1) < 0.03
