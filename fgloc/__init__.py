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

from fgloc.crlb import cramer_rao_bound
from fgloc.files import read_result, read_survey, write_result, write_survey
from fgloc.joint_solver import (
    LocalizationProblem,
    RobustKernel,
    SolveError,
    SolverOptions,
    build_problem,
    camera_key,
    initialize,
    node_key,
    solve,
    solve_survey,
)
from fgloc.model import (
    CameraPose,
    FglocError,
    FlaggedObservation,
    Gauge,
    NodeEstimate,
    NodeMode,
    Observation,
    Result,
    SolveStats,
    Survey,
    Truth,
)
from fgloc.scoring import Score, score
from fgloc.simulate import PaperScenario, RandomScene, paper_scenario, random_scene

__all__ = [
    "CameraPose", "FglocError", "FlaggedObservation", "Gauge", "LocalizationProblem", "NodeEstimate",
    "NodeMode", "Observation", "PaperScenario", "RandomScene", "Result", "RobustKernel", "Score",
    "SolveError", "SolveStats", "SolverOptions", "Survey", "Truth", "build_problem", "camera_key",
    "cramer_rao_bound", "initialize", "node_key", "paper_scenario", "random_scene", "read_result",
    "read_survey", "score", "solve", "solve_survey", "write_result", "write_survey",
]
