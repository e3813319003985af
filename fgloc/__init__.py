"""fgloc: factor-graph localization of sensor nodes and pan-tilt cameras from pan-tilt bearings.

The public API (survey in, result out; build the graph; add your own factors)::

    import fgloc
    survey = fgloc.read_survey("survey.json")          # or fgloc.paper_scenario(...)
    result = fgloc.solve_survey(survey)                 # closed-form start, LM, flags, marginals
    fgloc.write_result(result, "result.json")

    # Extending the graph: build it, add factors on its keys, solve.
    problem = fgloc.build_problem(survey, fgloc.initialize(survey))
    key = problem.node_keys["n007"]                     # gtsam key of a node (Point2 planar / Point3 3d)
    problem.add_factor(gtsam.PriorFactorPoint2(key, xy, gtsam.noiseModel.Isotropic.Sigma(2, 0.01)))
    result = fgloc.solve(problem)

Frames, units and conventions: ``shared/spec/survey-format.md`` (angles in radians,
positions in the gauge frame with the ground baseline as unit).
"""

from __future__ import annotations

import importlib
from typing import Any

# Public names and the module each lives in. Loaded on first use (PEP 562) so that
# importing a bottom-layer module (``fgloc.geometry``, ``fgloc.model``) from
# ``factors/`` does not pull in the solver, which imports ``factors/`` itself.
_PUBLIC = {
    "cramer_rao_bound": "fgloc.crlb",
    "read_result": "fgloc.files", "read_survey": "fgloc.files",
    "IncrementalLocalizer": "fgloc.incremental", "IncrementalParams": "fgloc.incremental",
    "write_result": "fgloc.files", "write_survey": "fgloc.files",
    "LocalizationProblem": "fgloc.joint_solver", "RobustKernel": "fgloc.joint_solver",
    "SolveError": "fgloc.joint_solver", "SolverOptions": "fgloc.joint_solver",
    "build_problem": "fgloc.joint_solver", "camera_key": "fgloc.joint_solver",
    "initialize": "fgloc.joint_solver", "node_key": "fgloc.joint_solver",
    "solve": "fgloc.joint_solver", "solve_survey": "fgloc.joint_solver",
    "CameraPose": "fgloc.model", "FglocError": "fgloc.model", "FlaggedObservation": "fgloc.model",
    "Gauge": "fgloc.model", "NodeEstimate": "fgloc.model", "NodeMode": "fgloc.model",
    "Observation": "fgloc.model", "Result": "fgloc.model", "SolveStats": "fgloc.model",
    "Survey": "fgloc.model", "Truth": "fgloc.model",
    "Score": "fgloc.scoring", "score": "fgloc.scoring",
    "PaperScenario": "fgloc.simulate", "RandomScene": "fgloc.simulate",
    "paper_scenario": "fgloc.simulate", "random_scene": "fgloc.simulate",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'fgloc' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
