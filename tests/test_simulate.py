"""The simulator: deterministic by seed, truth in the gauge frame, noise as specified."""

from pathlib import Path

import numpy as np
import pytest

from fgloc.core.errors import FglocError
from fgloc.core.geometry import project_pan_tilt, wrap_angle
from fgloc.core.model import Survey
from fgloc.sim.head_errors import inject_head_errors, limit_pan_range, mechanical_pan
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


def _base_frame_pans(s: Survey) -> np.ndarray:
    """The ideal head's mechanical pan of every reading, from the truth: atan2 of R^T (x - c)."""
    out = []
    for o in s.observations:
        cam = s.truth.cameras[o.camera]
        q = cam.rotation.T @ (s.truth.nodes[o.node] - cam.position)
        out.append(np.arctan2(q[1], q[0]))
    return np.array(out)


def test_pan_range_drops_exactly_the_readings_beyond_it() -> None:
    """Ideal heads: the dropped readings are exactly those with |mechanical pan| > range (none within);
    the kept ones are the original readings, unchanged and in order."""
    s = paper_scenario(PaperScenario(heights=(0.3, 0.3), seed=3))
    phi = _base_frame_pans(s)
    for deg in (170.0, 100.0):
        beyond = np.abs(phi) > np.deg2rad(deg)
        assert 0 < beyond.sum() < len(phi)  # the scene has readings on both sides of the limit
        limited, dropped = limit_pan_range(s, np.deg2rad(deg))
        assert dropped == list(np.flatnonzero(beyond))
        assert limited.observations == [o for o, b in zip(s.observations, beyond) if not b]
        assert inject_head_errors(s, {}, np.deg2rad(deg)).observations == limited.observations
    assert limit_pan_range(s, np.pi)[1] == []  # +-180 deg: nothing beyond


def test_pan_range_with_head_errors_uses_the_true_mechanical_pan() -> None:
    """With head errors the limit applies to the head's mechanical pan (the encoder reading / (1 + k_p)),
    which differs from the ideal pan by the head's small errors: readings clearly beyond are dropped,
    clearly within are kept, and the kept ones carry the same head errors as without a range."""
    s = paper_scenario(PaperScenario(heights=(0.3, 0.3), seed=3))
    heads = {c: np.array([0.005, 0.004, -0.004, 0.02, 0.01, 0.0, 0.0]) for c in s.camera_ids}
    limit = np.deg2rad(170.0)
    phi_ideal = _base_frame_pans(s)
    phi = mechanical_pan(s, heads)
    assert np.max(np.abs(wrap_angle(phi - phi_ideal))) < 0.05  # same pointing, small head errors
    limited, dropped = limit_pan_range(s, limit, heads)
    assert set(np.flatnonzero(np.abs(phi_ideal) > limit + 0.05)) <= set(dropped)
    assert not set(np.flatnonzero(np.abs(phi_ideal) < limit - 0.05)) & set(dropped)
    assert set(dropped) == set(np.flatnonzero(np.abs(phi) > limit))
    full = inject_head_errors(s, heads)
    kept = [o for j, o in enumerate(full.observations) if j not in set(dropped)]
    assert inject_head_errors(s, heads, limit).observations == kept
    with pytest.raises(FglocError):
        limit_pan_range(s, 0.0)


def test_simulate_cli_pan_range(tmp_path: Path) -> None:
    from fgloc.cli import main
    from fgloc.files.survey_result import read_survey

    out = tmp_path / "s.json"
    args = ["simulate", "-o", str(out), "--seed", "3", "--heights", "0.3", "0.3"]
    assert main([*args, "--pan-range-deg", "100", "--head-errors", "typical"]) == 0
    s = read_survey(out)
    assert len(s.observations) < 200
    assert np.all(np.abs(_base_frame_pans(s)) < np.deg2rad(100.5))
    assert main([*args, "--pan-range-deg", "0"]) == 2
    assert main([*args, "--pan-range-deg", "nan"]) == 2
