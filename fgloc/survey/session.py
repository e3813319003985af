"""A survey session: rig.json + output directory -> journal, runner, survey.json.

This is orchestration (the top of the stack): it is the one place in ``fgloc``
besides the CLI that opens drivers. Output directory layout:

* ``journal.jsonl`` - the append-only journal (the primary record);
* ``survey.json``   - derived from the journal after every run (atomic write);
* ``estimate.json`` - the last live estimate as a result.json (when one exists).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from fgloc.core.errors import FglocError
from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.core.model import Survey
from fgloc.files.journal import JournalHeader, JournalWriter, journal_to_survey, read_journal
from fgloc.files.rig_config import RigConfig
from fgloc.files.survey_result import write_result, write_survey
from fgloc.survey.runner import Estimator, LiveEstimate, Progress, SurveyRunner

JOURNAL_NAME = "journal.jsonl"
SURVEY_NAME = "survey.json"
ESTIMATE_NAME = "estimate.json"


@dataclass
class OpenedRig:
    """How to reach a rig's hardware (or its twins)."""

    open_head: Callable[[str], PanTiltHead]
    leds: LedController
    simulated: object | None = None  # the simulated rig, when simulating
    close: Callable[[], None] = lambda: None


def open_simulated(rig: RigConfig) -> OpenedRig:
    """The rig's simulated twin (scene built from ``rig.simulation``, cameras per ``twin``)."""
    if rig.simulation.twin == "visca":
        from fgloc.drivers.twin_rig import ViscaTwinRig

        twins = ViscaTwinRig(rig)
        assert twins.leds is not None  # the constructor started the base-station twin
        return OpenedRig(open_head=twins.open_head, leds=twins.leds, simulated=twins, close=twins.close)
    from fgloc.drivers.inprocess_rig import InProcessRig

    sim = InProcessRig(rig)
    return OpenedRig(open_head=sim.open_head, leds=sim.leds, simulated=sim)


def open_hardware(rig: RigConfig) -> OpenedRig:
    """The rig's real drivers (``fgloc.drivers.connect``): heads by port, frames from ``video``, motes."""
    from fgloc.drivers.connect import HeadOptions, open_head, open_leds

    if any(c.driver == "simulated" for c in rig.cameras) or rig.motes.driver == "simulated":
        raise FglocError(f"{rig.path}: cameras: a rig with simulated devices runs only with --simulate")
    by_id = {c.id: c for c in rig.cameras}

    def open_camera(camera_id: str) -> PanTiltHead:
        cam = by_id[camera_id]
        return open_head(cam.port, HeadOptions(camera_model=cam.model, mount=cam.mounting, address=cam.address,
                                               video=cam.video, reply_port=cam.reply_port))

    leds = open_leds(rig.motes.port, rig.motes.addresses)
    return OpenedRig(open_head=open_camera, leds=leds, close=getattr(leds, "close", lambda: None))


def start_journal(rig: RigConfig, out_dir: str | os.PathLike[str], resume: bool, simulated: object | None = None):
    """Create or reopen ``out_dir/journal.jsonl``; checks a resumed journal belongs to this rig."""
    path = Path(out_dir) / JOURNAL_NAME
    if resume and path.exists():
        try:
            writer, state = JournalWriter.open_existing(path)
        except FglocError as exc:
            if "no complete header" not in str(exc):
                raise
        else:
            if state.header.rig_hash != rig.hash:
                writer.close()
                raise FglocError(f"{path}: header.rig_hash: journal was recorded with a different {rig.path}")
            if simulated is not None and state.truth is None:  # killed before the truth record
                writer.truth(simulated.scene.truth)  # type: ignore[attr-defined]
                state.truth = simulated.scene.truth  # type: ignore[attr-defined]
            return writer, state
    elif path.exists() and path.stat().st_size > 0 and not resume:
        raise FglocError(f"{path}: journal already exists (use --resume to continue it, or another -o)")
    header = JournalHeader(rig.mode, rig.gauge, rig.sigma, rig.camera_ids, rig.node_ids, rig.hash,
                           {"rig": str(rig.path), "simulated": simulated is not None})
    writer = JournalWriter.create(path, header)
    if simulated is not None:
        writer.truth(simulated.scene.truth)  # type: ignore[attr-defined]
    return writer, read_journal(path)


def run_survey(
    rig: RigConfig,
    out_dir: str | os.PathLike[str],
    *,
    simulate: bool = False,
    resume: bool = False,
    estimator: Estimator | None = None,
    live_every: int = 1,
    on_estimate: Callable[[LiveEstimate], None] | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    opened: OpenedRig | None = None,
) -> tuple[Survey, SurveyRunner]:
    """Run (or resume) a survey and write ``survey.json``; returns it and the runner.

    What goes wrong along the way (LED or camera failures, failed live estimates) is logged
    on the ``fgloc.survey.runner`` logger; ``on_progress`` is called before the first node
    and after every node."""
    own = opened is None
    opened = opened or (open_simulated(rig) if simulate else open_hardware(rig))
    try:
        writer, state = start_journal(rig, out_dir, resume, opened.simulated)
        try:
            runner = SurveyRunner(rig, opened.open_head, opened.leds, writer, state, estimator=estimator,
                                  live_every=live_every, on_estimate=on_estimate, on_progress=on_progress)
            survey = runner.run()
        finally:
            writer.close()
    finally:
        if own:
            opened.close()
    write_survey(survey, Path(out_dir) / SURVEY_NAME)
    if runner.latest is not None:
        try:
            write_result(runner.latest.result, Path(out_dir) / ESTIMATE_NAME)
        except ValueError:  # non-finite solver statistics (e.g. an incremental solver's NaN costs)
            write_result(replace(runner.latest.result, stats=None), Path(out_dir) / ESTIMATE_NAME)
    return survey, runner


def journal_survey(out_dir_or_journal: str | os.PathLike[str]) -> Survey:
    """The survey recorded in a journal file or a survey directory."""
    p = Path(out_dir_or_journal)
    return journal_to_survey(read_journal(p / JOURNAL_NAME if p.is_dir() else p))
