"""Check a plan's prediction by Monte Carlo: simulated surveys at the planned placement, solved and scored.

A :class:`PlanTrial` is plain data (camera positions and bases in metres, node
positions, the visibility mask, sigma, extra readings per pair, a seed); the
trial moves it into the solver's gauge (origin camera above (0, 0), baseline
camera above (1, 0)), simulates noisy readings, solves with
:func:`fgloc.solve.joint.solve_survey` and scores against the truth. Errors
are reported in metres (gauge units times the baseline). Trials run through
:func:`fgloc.evaluate.sweep.run_sweep`, so any executor (a process pool, a Dask
cluster) gives the same outcomes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.core.geometry import FloatArray
from fgloc.core.model import CameraPose, NodeMode, Observation, Survey
from fgloc.evaluate.score import score
from fgloc.evaluate.sweep import MapExecutor, run_sweep
from fgloc.sim.scenes import observe, simulated_survey
from fgloc.solve.joint import solve_survey


@dataclass(frozen=True, eq=False)
class PlanTrial:
    """One simulated survey: cameras (K, 3) and bases (K, 3, 3) in metres (the first two are the gauge
    pair), nodes (N, 2), ``visible`` (K, N), sigma in radians, ``repeats`` (K, N) readings per pair
    (None: one per visible pair), noise ``seed``."""

    positions: FloatArray
    rotations: FloatArray
    nodes_xy: FloatArray
    visible: np.ndarray
    sigma: float
    seed: int
    repeats: np.ndarray | None = None


@dataclass(frozen=True)
class PlanTrialOutcome:
    """Scored errors of one simulated survey in metres; ANEES of the solver's covariances."""

    seed: int
    n_observations: int
    median_m: float
    p95_m: float
    max_m: float
    rms_m: float
    anees: float
    seconds: float


def trial_survey(trial: PlanTrial) -> tuple[Survey, float]:
    """The simulated survey of ``trial`` in the solver's gauge and the baseline length in metres."""
    g0, g1 = trial.positions[0], trial.positions[1]
    d = g1[:2] - g0[:2]
    baseline = float(np.linalg.norm(d))
    ang = float(np.arctan2(d[1], d[0]))
    c, s = np.cos(-ang), np.sin(-ang)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    shift = np.array([g0[0], g0[1], 0.0])

    def move(p: FloatArray) -> FloatArray:
        return (np.asarray(p, float) - shift) @ rot.T / baseline

    cameras = [CameraPose(move(p), rot @ r) for p, r in zip(trial.positions, trial.rotations)]
    nodes = move(np.column_stack([trial.nodes_xy, np.zeros(len(trial.nodes_xy))]))
    camera_ids = [f"cam{i}" for i in range(len(cameras))]
    width = max(3, len(str(len(nodes) - 1)))
    node_ids = [f"n{j:0{width}d}" for j in range(len(nodes))]
    rng = np.random.default_rng(trial.seed)
    observations: list[Observation] = observe(camera_ids, cameras, node_ids, nodes, trial.sigma, rng, visible=trial.visible)
    if trial.repeats is not None:
        extra = np.asarray(trial.repeats, int) - trial.visible.astype(int)
        for r in range(1, int(extra.max(initial=0)) + 1):
            observations += observe(camera_ids, cameras, node_ids, nodes, trial.sigma, rng, visible=extra >= r)
    return simulated_survey(NodeMode.PLANAR, trial.sigma, camera_ids, cameras, node_ids, nodes, observations), baseline


def run_plan_trial(trial: PlanTrial) -> PlanTrialOutcome:
    """Simulate, solve and score one planned survey (pure: same trial, same numbers)."""
    t0 = time.perf_counter()
    survey, baseline = trial_survey(trial)
    s = score(survey, solve_survey(survey), baseline_m=baseline)
    return PlanTrialOutcome(trial.seed, len(survey.observations), s.median_m, s.p95_m, s.max_m, s.rms_m, s.anees,
                            time.perf_counter() - t0)


@dataclass(frozen=True)
class Simulated:
    """Monte Carlo summary in metres: the mean over trials of each survey's statistic."""

    trials: int
    median: float
    p95: float
    worst: float
    rms: float
    anees: float


def summarize(outcomes: list[PlanTrialOutcome]) -> Simulated:
    """Average the per-survey statistics over trials."""
    return Simulated(
        trials=len(outcomes),
        median=float(np.mean([o.median_m for o in outcomes])),
        p95=float(np.mean([o.p95_m for o in outcomes])),
        worst=float(np.mean([o.max_m for o in outcomes])),
        rms=float(np.sqrt(np.mean([o.rms_m**2 for o in outcomes]))),
        anees=float(np.mean([o.anees for o in outcomes])),
    )


def simulate_plan(
    positions: FloatArray,
    rotations: FloatArray,
    nodes_xy: FloatArray,
    visible: np.ndarray,
    sigma: float,
    trials: int,
    seed: int = 0,
    repeats: np.ndarray | None = None,
    executor: MapExecutor | None = None,
    progress: Callable[[int, int], None] | bool = False,
) -> tuple[Simulated, list[PlanTrialOutcome]]:
    """Run ``trials`` simulated surveys (noise seeds ``seed``..) through the sweep seam."""
    todo = [PlanTrial(np.asarray(positions, float), np.asarray(rotations, float), np.asarray(nodes_xy, float),
                      np.asarray(visible, bool), float(sigma), seed + i, repeats) for i in range(trials)]
    outcomes: list[PlanTrialOutcome] = run_sweep(todo, executor, progress, trial=run_plan_trial)
    return summarize(outcomes), outcomes
