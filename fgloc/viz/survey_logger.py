"""A live survey on the ``survey`` timeline (step = observation count)."""

from __future__ import annotations

import numpy as np
import rerun as rr

from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.model import CameraPose, Observation, Result, Survey
from fgloc.viz.entities import log_result
from fgloc.viz.style import ERROR_COLOR, LINE_RADIUS, VizOptions


class SurveyLogger:
    """Logs a live survey on the ``survey`` timeline (step = observation count).

    ``log_observation`` adds one text line and, when the camera pose is known,
    the new ray at ``world/survey/latest_ray``; ``log_estimates`` logs the
    current result on the same entity paths as :func:`log_result`, at the
    current step, so a person can scrub the survey.
    """

    def __init__(self, rec: rr.RecordingStream, survey: Survey | None = None,
                 options: VizOptions = VizOptions()) -> None:
        self.rec = rec
        self.survey = survey
        self.options = options

    def log_observation(self, step: int, observation: Observation, camera: CameraPose | None = None,
                        length: float = 1.5) -> None:
        """One observation at ``step``; ``length`` is the drawn ray length (gauge units)."""
        self.rec.set_time("survey", sequence=step)
        self.rec.log("survey/log", rr.TextLog(
            f"{observation.camera} sees {observation.node}: pan {np.degrees(observation.pan):.4f} deg, "
            f"tilt {np.degrees(observation.tilt):.4f} deg"))
        if camera is not None:
            b = np.asarray(camera.rotation, float) @ pan_tilt_bearing(observation.pan, observation.tilt)
            c = np.asarray(camera.position, float)
            self.rec.log("world/survey/latest_ray",
                         rr.LineStrips3D([np.stack([c, c + length * b])], colors=ERROR_COLOR, radii=LINE_RADIUS,
                                         labels=[f"{observation.camera} -> {observation.node}"]))

    def log_estimates(self, step: int, result: Result, survey: Survey | None = None) -> None:
        """The current estimates (cameras, nodes, ellipses, truth, rays, table) at ``step``."""
        self.rec.set_time("survey", sequence=step)
        log_result(self.rec, result, survey if survey is not None else self.survey, options=self.options,
                   static=False)
