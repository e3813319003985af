"""The closed-form start on its own, against truth."""

import numpy as np
import pytest

from fgloc.init.homography import DegenerateGeometryError, decompose_bearing_homography, estimate_bearing_homography
from fgloc.init.planar import initialize_planar
from fgloc.sim.scenes import PaperScenario, paper_scenario


@pytest.mark.parametrize("seed", range(10))
def test_noise_free_closed_form_is_exact(seed: int) -> None:
    rng = np.random.default_rng(seed)
    survey = paper_scenario(PaperScenario(n_nodes=30, sigma=1e-15, seed=seed,
                                          heights=tuple(rng.uniform(0.05, 0.5, 2)), max_roll_pitch_deg=10))
    init = initialize_planar(survey)
    for n in survey.node_ids:
        np.testing.assert_allclose(init.nodes[n], survey.truth.nodes[n], atol=1e-9)
    for c in survey.camera_ids:
        np.testing.assert_allclose(init.cameras[c].position, survey.truth.cameras[c].position, atol=1e-9)
        np.testing.assert_allclose(init.cameras[c].rotation, survey.truth.cameras[c].rotation, atol=1e-9)


def test_noisy_closed_form_is_close() -> None:
    """With 0.1 degree noise the start is within a few percent of the baseline everywhere."""
    for seed in range(10):
        survey = paper_scenario(PaperScenario(seed=seed))
        init = initialize_planar(survey)
        err = max(np.linalg.norm(init.nodes[n] - survey.truth.nodes[n]) for n in survey.node_ids)
        assert err < 0.05


def test_homography_decomposition_reproduces_h() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=20, sigma=1e-15, seed=1))
    from fgloc.init.start import BearingSet
    bs = BearingSet.from_survey(survey)
    H = estimate_bearing_homography(bs.bearings[0], bs.bearings[1])
    for cand in decompose_bearing_homography(H):
        np.testing.assert_allclose(cand.rotation @ cand.rotation.T, np.eye(3), atol=1e-9)
        np.testing.assert_allclose(cand.rotation + np.outer(cand.translation, cand.normal), H, atol=1e-9)


def test_too_few_shared_nodes_is_a_clear_error() -> None:
    survey = paper_scenario(PaperScenario(n_nodes=3, seed=0))
    with pytest.raises(DegenerateGeometryError, match="share 4 nodes"):
        initialize_planar(survey)
