"""The convex relaxation of repeat selection: values and gradients against the dense model and central
differences, the certified bound against brute force over integer plans and greedy, tightness where the
optimum is known by symmetry, and the 'every reading 3x' feasibility certificate both ways."""

import itertools
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from fgloc.cli import main
from fgloc.core.model import CameraPose, NodeEstimate, NodeMode, Result, Survey
from fgloc.plan.repeat import RepeatModel, objective_of, plan_repeats
from fgloc.plan.repeat_bound import (
    PairSystem,
    certified_budgets,
    counts_of,
    evaluate,
    plan_bound,
    project_simplex,
    repeat_feasibility,
    solve_relaxation,
)
from fgloc.sim.bench_scenes import BenchScene, scene_survey
from fgloc.sim.scenes import observe, random_base_rotation, simulated_survey


def truth_result(survey: Survey) -> Result:
    """The survey's truth as a result: the model is linearized at the true positions (the exact CRB)."""
    assert survey.truth is not None
    nodes = {n: NodeEstimate(np.asarray(p, float), np.eye(2)) for n, p in survey.truth.nodes.items()}
    return Result(NodeMode.PLANAR, nodes, dict(survey.truth.cameras))


def bench(n: int, cams: int, seed: int = 1) -> tuple[Survey, Result]:
    survey = scene_survey(BenchScene(n, cams, seed=seed))
    return survey, truth_result(survey)


def symmetric_system(n_nodes: int, scale: float = 1.0) -> PairSystem:
    """One 2-dof 'camera' (with a unit prior) measuring the relative position of n nodes on a circle,
    anisotropically along the ray. A rotation by 2 pi / n maps pair k to pair k + 1 and leaves F's
    spectrum unchanged, so the objectives are invariant under the cyclic shift of the pairs."""
    jn, jc = [], []
    for k in range(n_nodes):
        t = 2 * math.pi * k / n_nodes
        r = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
        m = scale * r @ np.diag([1.0, 0.3]) @ r.T
        jn.append(m)
        jc.append(-m)
    return PairSystem(np.array(jc), np.array(jn), np.arange(n_nodes), np.ones(n_nodes), n_nodes, np.eye(2))


@pytest.mark.parametrize("objective", ["mean", "logdet"])
def test_evaluate_equals_the_dense_model(objective: str) -> None:
    survey, result = bench(30, 3)
    model = RepeatModel(survey, result)
    system = PairSystem.from_model(model)
    extra = np.zeros(system.n_pairs)
    assert evaluate(system, extra, objective).value == pytest.approx(objective_of(model, objective), rel=1e-9)
    for p in (0, 7, 7, 40):
        model.take(p)
        extra[p] += 1
    assert evaluate(system, extra, objective).value == pytest.approx(objective_of(model, objective), rel=1e-9)
    traces = evaluate(system, extra, objective).node_traces
    assert np.allclose(traces, model.node_traces(), rtol=1e-9)


@pytest.mark.parametrize("objective", ["mean", "logdet"])
def test_gradient_against_central_differences(objective: str) -> None:
    survey, result = bench(30, 3)
    system = PairSystem.from_model(RepeatModel(survey, result))
    w = np.random.default_rng(0).uniform(0.0, 2.0, system.n_pairs)
    g = evaluate(system, w, objective).gradient
    assert g is not None and np.all(g < 0)  # more readings always help
    h = 1e-4
    for p in (0, 11, 37, system.n_pairs - 1):
        e = np.zeros(system.n_pairs)
        e[p] = h
        fd = (evaluate(system, w + e, objective, False).value - evaluate(system, w - e, objective, False).value) / (2 * h)
        assert fd == pytest.approx(g[p], rel=1e-6)


def test_simplex_projection() -> None:
    rng = np.random.default_rng(1)
    y = rng.normal(size=30)
    w = project_simplex(y, 4.0)
    assert w.min() >= 0 and w.sum() == pytest.approx(4.0)
    # Optimality: y - w = tau on the support, <= tau off it.
    tau = (y - w)[w > 0]
    assert np.allclose(tau, tau[0]) and np.all((y - w)[w == 0] <= tau[0] + 1e-12)


@pytest.mark.parametrize(("objective", "budget"), [("mean", 3), ("logdet", 3), ("mean", 5)])
def test_bound_below_every_integer_plan_and_greedy(objective: str, budget: int) -> None:
    survey, result = bench(4, 2, seed=3)
    model = RepeatModel(survey, result)
    system = PairSystem.from_model(model)
    p = system.n_pairs
    best = np.inf
    for plan in itertools.combinations_with_replacement(range(p), budget):
        best = min(best, evaluate(system, np.bincount(plan, minlength=p).astype(float), objective, False).value)
    greedy = plan_repeats(survey, result, budget, objective)
    counts = counts_of(model, [(r.camera, r.node) for r in greedy.readings])
    b = plan_bound(system, counts, objective)
    assert b.achieved == pytest.approx(greedy.after, rel=1e-9)
    assert b.bound <= best <= b.achieved + 1e-12 * abs(best)
    assert b.bound <= b.relaxed <= best * (1 + 1e-12) or b.relaxed <= best  # relaxed min <= integer min
    assert 0 < b.gain_ratio <= 1 and b.gap >= 0


@pytest.mark.parametrize("objective", ["mean", "logdet"])
def test_bound_is_tight_where_the_optimum_is_known(objective: str) -> None:
    # Convex and invariant under a group transitive on the pairs: the uniform point is a relaxed optimum;
    # with budget k * P it is an integer plan, so it is the best plan and the bound must meet it.
    system = symmetric_system(6)
    uniform = np.full(6, 2.0)
    f_opt = evaluate(system, uniform, objective, False).value
    start = np.array([12.0, 0, 0, 0, 0, 0])  # the worst start: everything on one pair
    r = solve_relaxation(system, 12, objective, start=start, rtol=1e-9, max_iter=2000)
    f0 = evaluate(system, np.zeros(6), objective, False).value
    assert r.bound <= f_opt + 1e-12 * abs(f_opt)
    assert f_opt - r.bound <= 1e-6 * (f0 - f_opt)
    assert np.allclose(r.weights, 2.0, atol=1e-3)
    b = plan_bound(system, uniform, objective)
    assert b.gain_ratio == pytest.approx(1.0, abs=1e-5)


def test_certificate_proves_the_symmetric_scene_needs_exactly_two_passes_more() -> None:
    # Symmetric: the best plan of B extra readings is uniform, trace((C0 + (1 + B/P) sum A)^-1), which
    # reaches the 3x trace exactly at B = 2P and not before. The certificate must say so, to the reading.
    system = symmetric_system(8, scale=3.0)
    target = evaluate(system, 2.0 * system.base, "mean", False).value
    assert certified_budgets(system, target) == (16, 16)
    r = solve_relaxation(system, 2, "mean", start=system.base)  # 0.3 x one pass of 8 readings
    assert r.bound > target


def hazy_node_survey() -> Survey:
    """Two cameras, 21 nodes in the unit square; node n020's first readings were taken at 30x the
    survey's sigma (haze, a dim LED), so its trace dominates the survey's, and re-reading it at the
    nominal sigma cuts the total below a third. (Far-away nodes do not make such a scene: their
    error is dominated by the cameras' pose uncertainty, which repeating them does not reduce.)"""
    rng = np.random.default_rng(5)
    cams = [CameraPose(np.array([0.0, 0.0, 0.5]), random_base_rotation(rng, 3.0)),
            CameraPose(np.array([1.0, 0.0, 0.5]), random_base_rotation(rng, 3.0))]
    xy = rng.uniform(0.2, 0.9, size=(21, 2))
    nodes = np.column_stack([xy, np.zeros(len(xy))])
    ids, node_ids = ["cam0", "cam1"], [f"n{j:03d}" for j in range(len(xy))]
    sigma = math.radians(0.1)
    obs = [replace(o, sigma=30 * sigma) if o.node == "n020" else o
           for o in observe(ids, cams, node_ids, nodes, sigma, rng)]
    return simulated_survey(NodeMode.PLANAR, sigma, ids, cams, node_ids, nodes, obs)


def test_feasibility_feasible_when_one_node_dominates() -> None:
    survey = hazy_node_survey()
    f = repeat_feasibility(survey, truth_result(survey))
    assert f.n_readings == 42 and f.budget == 12
    assert f.target == pytest.approx(f.trace_one_pass / 3, rel=1e-9)  # prior-free: information scales
    assert f.status == "feasible" and f.greedy_budget is not None and f.greedy_budget <= f.budget
    assert f.bound <= f.target and f.certified_min_budget <= f.greedy_budget
    # The greedy plan really reaches the target (recomputed from scratch).
    plan = plan_repeats(survey, truth_result(survey), f.greedy_budget, "mean")
    assert plan.trace_after <= f.target


def test_feasibility_infeasible_on_a_bench_scene() -> None:
    survey, result = bench(30, 3)
    f = repeat_feasibility(survey, result)
    assert f.status == "infeasible" and f.bound > f.target
    # Consistent with every plan we can build: greedy needs more than the certified minimum.
    assert f.greedy_budget is not None and f.greedy_budget >= f.certified_min_budget > f.budget
    greedy = plan_repeats(survey, result, f.budget, "mean")
    assert greedy.trace_after >= f.bound
    assert f.free_bound > f.target  # not even a free allocation of 1.3 passes (first pass not kept) does it


def test_cli_repeat_bound_json(tmp_path, capsys) -> None:
    from fgloc.files.survey_result import write_result, write_survey

    survey, result = bench(30, 3)
    write_survey(survey, str(tmp_path / "s.json"))
    write_result(result, str(tmp_path / "r.json"))
    assert main(["plan", "repeat", str(tmp_path / "s.json"), str(tmp_path / "r.json"), "--budget", "27",
                 "--bound", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    b, feas = doc["bound"], doc["feasibility"]
    assert b["bound"] <= b["achieved"] == pytest.approx(doc["after"])
    assert 0 < b["gain_ratio"] <= 1
    assert feas["status"] == "infeasible" and feas["bound"] > feas["target"]
    assert main(["plan", "repeat", str(tmp_path / "s.json"), str(tmp_path / "r.json"), "--budget", "5",
                 "--bound", "--objective", "worst"]) == 0
    assert "not supported" in capsys.readouterr().out
