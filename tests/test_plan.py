"""Survey planning: Fisher information against the solver's CRLB, greedy against brute force,
the relaxation bound against the achieved objective, repeat gains against recomputation, CLI errors."""

import itertools
import json
import math

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.evaluate.crlb import cramer_rao_bound
from fgloc.plan.fisher import candidate_info, cloud_evaluate, gauge_frame_covariances
from fgloc.plan.io import read_site_file, rig_skeleton
from fgloc.plan.placement import default_prior_m, greedy_select, objective_value, plan_placement, swap_refine
from fgloc.plan.relaxation import logdet_gradient, placement_bound
from fgloc.plan.repeat import RepeatModel, objective_of, plan_repeats
from fgloc.plan.site import PlanProblem, grid_sites, sample_polygon
from fgloc.plan.validate import PlanTrial, trial_survey

SQUARE = np.array([[0, 0], [100, 0], [100, 100], [0, 100.0]])
SIGMA = math.radians(0.1)


def small_problem(n_nodes: int = 40, step: float = 40.0) -> PlanProblem:
    ids, xy, hs = grid_sites((-10, -10, 110, 110), step, (3.0, 8.0))
    return PlanProblem(sample_polygon(SQUARE, n_nodes, 3), ids, xy, hs, SIGMA)


def test_gauge_frame_covariances_equal_solver_crlb() -> None:
    problem = small_problem(30)
    chosen = [0, 7, 12, 17]
    cov, ok = gauge_frame_covariances(problem.jacobians(), chosen, (0, 7))
    assert ok.all()
    trial = PlanTrial(problem.positions()[chosen], problem.rotations()[chosen], problem.nodes_xy,
                      problem.visible()[chosen], SIGMA, seed=0)
    survey, baseline = trial_survey(trial)
    bound = cramer_rao_bound(survey)
    ref = np.array([bound[n] for n in survey.node_ids]) * baseline**2
    # The solver's gauge prior is soft (1e-3 of a node sigma): agreement to ~1e-6 relative.
    assert np.allclose(cov, ref, rtol=1e-4, atol=1e-6 * np.abs(ref).max())


def test_cloud_logdet_gradient_matches_finite_differences() -> None:
    problem = small_problem(25)
    info = candidate_info(problem.jacobians(), problem.nodes_xy, default_prior_m(problem))
    weights = {0: 0.4, 5: 0.9, 9: 1.0}
    f, grad = logdet_gradient(info, weights)
    for c in (0, 5, 3):
        w = dict(weights)
        w[c] = w.get(c, 0.0) + 1e-6
        assert (cloud_evaluate(info, w).logdet - f) / 1e-6 == pytest.approx(grad[c], rel=1e-3)


@pytest.mark.parametrize("objective", ["logdet", "mean", "worst"])
def test_greedy_against_brute_force(objective: str) -> None:
    ids, xy, hs = grid_sites((-10, -10, 110, 110), 40, (5.0,))
    problem = PlanProblem(sample_polygon(SQUARE, 20, 4), ids, xy, hs, SIGMA)
    info = candidate_info(problem.jacobians(), problem.nodes_xy, default_prior_m(problem))
    k = 3
    chosen, value, _ = greedy_select(info, problem.site_ids, k, objective)
    values = {s: objective_value(objective, cloud_evaluate(info, dict.fromkeys(s, 1.0)))
              for s in itertools.combinations(range(problem.n_candidates), k)}
    best = min(values.values())
    assert value == pytest.approx(values[tuple(sorted(chosen))])
    assert value >= best - 1e-9 * abs(best)
    if objective == "logdet":
        empty = objective_value(objective, cloud_evaluate(info, {}))
        # Submodular, monotone: the greedy gain is at least (1 - 1/e) of the best gain.
        assert (empty - value) >= (1 - 1 / math.e) * (empty - best)
        lazy, _, _ = greedy_select(info, problem.site_ids, k, objective, lazy=True)
        plain, _, _ = greedy_select(info, problem.site_ids, k, objective, lazy=False)
        assert lazy == plain


@pytest.mark.parametrize(("objective", "seed"), [("mean", 6), ("worst", 8)])  # fields where greedy is not optimal
def test_swap_refinement_reaches_a_local_optimum_between_greedy_and_the_best(objective: str, seed: int) -> None:
    ids, xy, hs = grid_sites((-10, -10, 110, 110), 40, (3.0, 8.0))
    problem = PlanProblem(sample_polygon(SQUARE, 20, seed), ids, xy, hs, SIGMA)
    info = candidate_info(problem.jacobians(), problem.nodes_xy, default_prior_m(problem))
    site, k = problem.site_ids, 3

    def value(s) -> float:
        return objective_value(objective, cloud_evaluate(info, dict.fromkeys(s, 1.0)))

    greedy, g_value, _ = greedy_select(info, site, k, objective)
    chosen, r_value, _ = swap_refine(info, site, greedy, objective, g_value)
    assert r_value == pytest.approx(value(chosen)) and len({site[c] for c in chosen}) == k
    best = min(value(s) for s in itertools.combinations(range(problem.n_candidates), k)
               if len({site[c] for c in s}) == k)
    assert best - 1e-9 * abs(best) <= r_value < g_value
    for i, c in itertools.product(range(k), range(problem.n_candidates)):  # no single exchange improves it
        others = chosen[:i] + chosen[i + 1:]
        if site[c] not in {site[o] for o in others}:
            assert value([*others, c]) >= r_value - 1e-9 * abs(r_value)
    plan = plan_placement(problem, k, objective, refine=True)
    assert sorted(plan.chosen) == sorted(chosen) and plan.cloud_objective == pytest.approx(r_value)


def test_relaxation_bound_is_above_every_plan() -> None:
    ids, xy, hs = grid_sites((-10, -10, 110, 110), 40, (3.0, 8.0))
    problem = PlanProblem(sample_polygon(SQUARE, 20, 5), ids, xy, hs, SIGMA)
    info = candidate_info(problem.jacobians(), problem.nodes_xy, default_prior_m(problem))
    plan = plan_placement(problem, 3, "logdet")
    b = placement_bound(info, problem.site_ids, list(plan.chosen), iterations=10)
    assert b.achieved == pytest.approx(-plan.cloud_objective)
    best = max(cloud_evaluate(info, dict.fromkeys(s, 1.0)).logdet
               for s in itertools.combinations(range(problem.n_candidates), 3)
               if len({problem.site_ids[c] for c in s}) == 3)
    assert b.bound >= best >= b.achieved
    assert 0 < b.gain_ratio <= 1


def test_plan_picks_distinct_sites_and_gauge_pair_first() -> None:
    problem = small_problem(40)
    plan = plan_placement(problem, 4, "mean")
    sites = [problem.site_ids[c] for c in plan.chosen]
    assert len(set(sites)) == 4
    assert plan.localizable.all()
    p = plan.predicted
    assert 0 < p.median < p.p95 < p.worst < 1.0  # metres at 0.1 degree over a 100 m field
    rig = rig_skeleton(plan)
    from fgloc.files.rig_config import parse_rig

    parsed = parse_rig(json.loads(json.dumps(rig)))
    assert parsed.gauge.origin == "cam0" and len(parsed.cameras) == 4


def test_repeat_gains_equal_recomputed_objective() -> None:
    from fgloc.sim.bench_scenes import BenchScene, scene_survey
    from fgloc.solve.joint import solve_survey

    survey = scene_survey(BenchScene(30, 3, seed=1))
    result = solve_survey(survey)
    for objective in ("mean", "logdet", "worst"):
        model = RepeatModel(survey, result)
        gains = model.gains(objective)
        p = int(np.argmax(gains))
        before = objective_of(model, objective)
        model.take(p)
        assert np.allclose(model.covariance, np.linalg.inv(model.information), rtol=1e-8,
                           atol=1e-10 * np.abs(model.covariance).max())
        if objective != "worst":
            assert before - objective_of(model, objective) == pytest.approx(gains[p], rel=1e-6)
    plan = plan_repeats(survey, result, 15, "logdet")
    assert len(plan.readings) == 15
    assert plan.logdet_bound >= plan.logdet_gain > 0


def _write(tmp_path, doc) -> str:
    path = tmp_path / "sites.json"
    path.write_text(json.dumps(doc))
    return str(path)


GOOD = {"field": {"polygon": SQUARE.tolist(), "nodes": 30},
        "grid": {"bounds": [-10, -10, 110, 110], "step": 40, "heights": [5]}, "sigma_deg": 0.1}


@pytest.mark.parametrize("change, words", [
    ({"field": {"polygon": SQUARE.tolist(), "nodes": 2}}, "field.nodes"),
    ({"field": {"nodes": 30}}, "field.polygon: missing"),
    ({"grid": {"bounds": [0, 0, 10, 10], "step": -1, "heights": [5]}}, "grid.step: must be > 0"),
    ({"grid": {"bounds": [0, 0, 100, 100], "step": 10, "heights": []}}, "grid.heights"),
    ({"sigma_deg": "x"}, "sigma_deg: expected a number"),
])
def test_bad_site_file_is_one_line_exit_2(tmp_path, capsys, change, words) -> None:
    path = _write(tmp_path, {**GOOD, **change})
    assert main(["plan", "place", path, "--cameras", "2", "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and words in err and path in err


@pytest.mark.parametrize("args, words", [
    (["--cameras", "1"], "--cameras"), (["--cameras", "2", "--objective", "best"], "--objective"),
    (["--cameras", "40"], "cameras: more cameras than candidate sites"),
])
def test_bad_flags_are_one_line_exit_2(tmp_path, capsys, args, words) -> None:
    path = _write(tmp_path, GOOD)
    assert main(["plan", "place", path, *args, "-o", str(tmp_path / "out"), "--no-picture"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and words in err


def test_cli_place_writes_plan_and_rig(tmp_path, capsys) -> None:
    path = _write(tmp_path, GOOD)
    out = tmp_path / "out"
    assert main(["plan", "place", path, "--cameras", "3", "-o", str(out), "--no-picture"]) == 0
    doc = json.loads((out / "plan.json").read_text())
    assert len(doc["cameras"]) == 3 and doc["predicted_error_m"]["median"] > 0
    problem, _ = read_site_file(path)
    assert len(doc["nodes"]) == len(problem.nodes_xy) == 30


def test_cli_place_swap_writes_the_refined_plan(tmp_path) -> None:
    path = _write(tmp_path, GOOD)
    out = tmp_path / "out"
    assert main(["plan", "place", path, "--cameras", "3", "--swap", "-o", str(out), "--no-picture"]) == 0
    doc = json.loads((out / "plan.json").read_text())
    problem, _ = read_site_file(path)
    plan = plan_placement(problem, 3, "mean", refine=True)
    assert [c["site"] for c in doc["cameras"]] == [problem.site_ids[c] for c in plan.chosen]
