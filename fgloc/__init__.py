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

Frames, units and conventions: ``docs/file-format.md`` (angles in radians, positions
in the gauge frame with the ground baseline as unit). The layers of the package are
described in ``docs/architecture.md``. ``import fgloc`` loads neither rerun, OpenCV,
matplotlib nor pyserial.
"""

from __future__ import annotations

import logging

from fgloc.core.errors import FglocError, FileFormatError
from fgloc.core.model import (
    CameraPose,
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
from fgloc.evaluate.crlb import cramer_rao_bound
from fgloc.evaluate.score import Score, score
from fgloc.files.survey_result import read_result, read_survey, write_result, write_survey
from fgloc.sim.scenes import PaperScenario, RandomScene, paper_scenario, random_scene
from fgloc.solve.incremental import IncrementalLocalizer, IncrementalParams
from fgloc.solve.joint import (
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

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "CameraPose", "FglocError", "FileFormatError", "FlaggedObservation", "Gauge", "IncrementalLocalizer",
    "IncrementalParams", "LocalizationProblem", "NodeEstimate", "NodeMode", "Observation", "PaperScenario",
    "RandomScene", "Result", "RobustKernel", "Score", "SolveError", "SolveStats", "SolverOptions", "Survey",
    "Truth", "build_problem", "camera_key", "cramer_rao_bound", "initialize", "node_key", "paper_scenario",
    "random_scene", "read_result", "read_survey", "score", "solve", "solve_survey", "write_result",
    "write_survey",
]
