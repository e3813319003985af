"""Render the default blueprint headless (software Vulkan) and look at the picture like a person.

Needs Mesa's lavapipe Vulkan driver (Debian: mesa-vulkan-drivers). The session
fixture installs it when missing and this process may (root + apt-get); it
skips with the reason only when it cannot.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

import fgloc.viz as viz
from fgloc.sim.scenes import PaperScenario, paper_scenario
from fgloc.solve.joint import solve_survey

pytestmark = pytest.mark.slow

LAVAPIPE_ICD = "/usr/share/vulkan/icd.d/lvp_icd.*.json"


def _has_lavapipe() -> bool:
    return bool(glob.glob(LAVAPIPE_ICD))


@pytest.fixture(scope="session")
def software_vulkan() -> None:
    """Make sure a software Vulkan driver is installed, or skip saying why."""
    if _has_lavapipe():
        return
    if os.name != "posix" or os.geteuid() != 0 or shutil.which("apt-get") is None:
        pytest.skip("mesa-vulkan-drivers (lavapipe) is missing and cannot be installed here "
                    "(needs root and apt-get): `apt-get install mesa-vulkan-drivers`")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    install = ["apt-get", "install", "-y", "-q", "--no-install-recommends", "mesa-vulkan-drivers"]
    if subprocess.run(install, env=env, capture_output=True, timeout=600).returncode != 0:
        subprocess.run(["apt-get", "update", "-q"], env=env, capture_output=True, timeout=600)
        subprocess.run(install, env=env, capture_output=True, timeout=600)
    if not _has_lavapipe():
        pytest.skip("installing mesa-vulkan-drivers failed (no network or package source?)")


def _colour_mask(img_bgr: np.ndarray, rgb: tuple[int, int, int], tol: int = 40) -> np.ndarray:
    target = np.array(rgb[::-1], dtype=int)
    return (np.abs(img_bgr.astype(int) - target) <= tol).all(axis=2)


def test_default_blueprint_renders_without_errors_and_shows_the_scene(software_vulkan, tmp_path: Path) -> None:
    """No view may report an error, and the picture must show nodes (orange), both cameras
    (their colours) and the 95% ellipse of the close-up (cyan) where the layout puts them."""
    survey = paper_scenario(PaperScenario(n_nodes=40, seed=1))
    recorder = viz.IterationRecorder(survey)
    result = solve_survey(survey, on_iteration=recorder)
    rrd = viz.write_rrd(tmp_path / "scene.rrd", result, survey, recorder=recorder)
    report = viz.render_headless(rrd, tmp_path / "scene.png", window_size="1280x720", settle_seconds=5.0,
                                 timeout=150)
    assert report.view_reports and all(r == [] for r in report.view_reports.values()), report.view_reports
    assert {name.split(":")[0] for name in report.view_reports} == {"3D", "TimeSeries", "TextDocument"}
    assert report.problems == []
    assert report.listening and all(a.startswith("127.0.0.1:") for a in report.listening), report.listening
    img = cv2.imread(str(report.png))
    assert img is not None and img.shape[:2] == (720, 1280)
    assert img.std() > 10  # not blank
    scene = img[40:690, : int(0.58 * 1280)]  # the large 3D view on the left
    close_up = img[40:300, int(0.62 * 1280):]  # the close-up, top right
    node_pixels = _colour_mask(scene, viz.ESTIMATE_COLOR[:3]).sum()
    assert node_pixels > 40 * 5, node_pixels  # dozens of visible node discs
    for i in range(2):
        assert _colour_mask(scene, viz.camera_color(i)[:3], tol=30).sum() > 50  # frusta and rays
    b, g, r = (close_up[..., c].astype(int) for c in range(3))
    cyan = (r < 70) & (g > 140) & (b > 180)  # the 95% ellipse (rays are dim and more blue)
    assert cyan.sum() > 50, cyan.sum()
