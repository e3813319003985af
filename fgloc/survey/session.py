"""A survey session: rig.json + output directory -> journal, runner, survey.json.

This is orchestration (the top of the stack): it is the one place in ``fgloc``
besides the CLI that opens drivers. Output directory layout:

* ``journal.jsonl`` - the append-only journal (the primary record);
* ``survey.json``   - derived from the journal after every run (atomic write);
* ``estimate.json`` - the last live estimate as a result.json (when one exists);
* ``survey.lock``   - held (``flock``) by the one process surveying into the directory.

A run, in order (docs/survey.md): lock the directory (:mod:`fgloc.survey.lock`; a second
survey is refused), remove temporary files of killed atomic writes, check the rig.json
alone (:func:`fgloc.survey.preflight.check_rig`), check that the journal may be started or
continued with this rig (:mod:`fgloc.survey.resume`), open the devices and check each one
without moving it (:func:`fgloc.survey.preflight.check_devices`), then survey.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from fgloc.core.errors import FglocError
from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.core.model import Survey
from fgloc.core.redact import redact_urls
from fgloc.files.journal import JournalHeader, JournalState, JournalWriter, journal_to_survey, read_journal
from fgloc.files.json_io import remove_stale_temps
from fgloc.files.rig_config import IDENTIFICATIONS, RigConfig, rig_meaning, rig_operational
from fgloc.files.survey_result import write_result, write_survey
from fgloc.survey.live import Estimator, LiveEstimate
from fgloc.survey.lock import SurveyLock
from fgloc.survey.preflight import PreflightError, check_devices, check_rig
from fgloc.survey.resume import resume_change
from fgloc.survey.runner import Progress, SurveyRunner, SurveyStopped

logger = logging.getLogger(__name__)

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
    check_devices: bool = False  # open, read and grab from every camera before the survey (preflight)


def open_simulated(rig: RigConfig) -> OpenedRig:
    """The rig's simulated twin (scene built from ``rig.simulation``, cameras per ``twin``)."""
    if rig.simulation.twin == "visca":
        from fgloc.drivers.twin_rig import ViscaTwinRig

        twins = ViscaTwinRig(rig)
        assert twins.leds is not None  # the constructor started the base-station twin
        return OpenedRig(open_head=twins.open_head, leds=twins.leds, simulated=twins, close=twins.close,
                         check_devices=True)
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

    try:
        leds = open_leds(rig.motes.port, rig.motes.addresses)
    except Exception as exc:  # noqa: BLE001 - any driver error is one line naming the base station
        text = " ".join(str(exc).split()) or type(exc).__name__
        raise PreflightError(f"{rig.path}: motes.port: base station ({rig.motes.driver}) cannot be opened: "
                             f"{type(exc).__name__}: {text}") from None
    return OpenedRig(open_head=open_camera, leds=leds, close=getattr(leds, "close", lambda: None),
                     check_devices=True)


def _existing_journal(rig: RigConfig, out_dir: str | os.PathLike[str], resume: bool) -> JournalState | None:
    """The journal to continue (None: start a new one); refuses a journal without --resume."""
    path = Path(out_dir) / JOURNAL_NAME
    if not path.exists() or path.stat().st_size == 0:
        return None
    if not resume:
        raise FglocError(f"{path}: journal already exists (use --resume to continue it, or another -o)")
    try:
        return read_journal(path)
    except FglocError as exc:
        if "no complete header" not in str(exc):
            raise
        return None  # killed while creating it: start over


def check_journal(rig: RigConfig, out_dir: str | os.PathLike[str], resume: bool, simulated: bool
                  ) -> JournalState | None:
    """Refuse, before any device is opened, what :func:`start_journal` would refuse; returns the
    journal to continue (None: a new one)."""
    state = _existing_journal(rig, out_dir, resume)
    if state is not None:
        resume_change(rig, state, Path(out_dir) / JOURNAL_NAME, simulated)
    return state


def start_journal(rig: RigConfig, out_dir: str | os.PathLike[str], resume: bool, simulated: object | None = None,
                  coded: dict[str, Any] | None = None):
    """Create or reopen ``out_dir/journal.jsonl``; a resumed journal must belong to this rig
    (operational rig.json changes are accepted and journaled, see :mod:`fgloc.survey.resume`).
    ``coded``: a new coded survey's levers, recorded in the header
    (:func:`fgloc.survey.coded_levers.settings_record`)."""
    path = Path(out_dir) / JOURNAL_NAME
    if _existing_journal(rig, out_dir, resume) is not None:
        writer, state = JournalWriter.open_existing(path)
        try:
            change = resume_change(rig, state, path, simulated is not None)
        except BaseException:
            writer.close()
            raise
        if change is not None:
            changed, operational = change
            writer.rig_changed(rig.hash, changed, operational)
            state.rig_changes.append({"type": "rig_changed", "rig_hash": rig.hash, "changed": changed,
                                      "rig_operational": operational})
            logger.warning(redact_urls(f"{rig.path}: resuming with changed {', '.join(changed)} (journaled)"))
        if simulated is not None and state.truth is None:  # killed before the truth record
            writer.truth(simulated.scene.truth)  # type: ignore[attr-defined]
            state.truth = simulated.scene.truth  # type: ignore[attr-defined]
        return writer, state
    header = JournalHeader(rig.mode, rig.gauge, rig.sigma, rig.camera_ids, rig.node_ids, rig.hash,
                           {"rig": str(rig.path), "simulated": simulated is not None},
                           rig_meaning(rig, simulated is not None), rig_operational(rig), coded)
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
    identification: str | None = None,
    coded_levers: Mapping[str, str] | None = None,
) -> tuple[Survey, SurveyRunner]:
    """Run (or resume) a survey and write ``survey.json``; returns it and the runner.

    ``identification`` (``"sequential"`` or ``"coded"``, default: the rig's) picks the node
    loop of :mod:`fgloc.survey.runner` or the blink-code survey of :mod:`fgloc.survey.coded`;
    ``coded_levers`` overrides rig.json's coded-survey levers (:func:`fgloc.survey.coded_levers.coded_settings`).

    What goes wrong along the way (LED or camera failures, failed live estimates) is logged
    on the ``fgloc.survey.runner`` logger; ``on_progress`` is called before the first node
    and after every node."""
    if identification not in (None, *IDENTIFICATIONS):
        raise FglocError(f"--identify: expected one of {', '.join(IDENTIFICATIONS)}, got {identification!r}")
    check_rig(rig, simulate)
    is_coded = (identification or rig.identification) == "coded"
    if is_coded:
        from fgloc.survey.coded_levers import coded_settings, settings_record

        coded_settings(rig, coded_levers)  # a bad lever is one line before anything is opened
    with SurveyLock(out_dir):
        remove_stale_temps(out_dir)
        own = opened is None
        previous = check_journal(rig, out_dir, resume, simulate if opened is None else opened.simulated is not None)
        # a resume runs with the levers its journal recorded (a disagreeing file or flag: one line, here)
        settings = coded_settings(rig, coded_levers, previous, Path(out_dir) / JOURNAL_NAME) if is_coded else None
        opened = opened or (open_simulated(rig) if simulate else open_hardware(rig))
        stopped: SurveyStopped | None = None
        try:
            if opened.check_devices:
                check_devices(rig, opened.open_head)
            writer, state = start_journal(rig, out_dir, resume, opened.simulated,
                                          None if settings is None else settings_record(settings))
            try:
                coded = None
                if settings is not None:
                    from fgloc.survey.coded import CodedSurvey

                    coded = CodedSurvey(rig, opened.open_head, opened.leds, opened.simulated, settings)
                    devices: Any = coded
                else:
                    from fgloc.survey.coded_clock import SequentialClock

                    devices = clock = SequentialClock(rig, opened.open_head, opened.leds)
                runner = SurveyRunner(rig, devices.open_head, devices.leds, writer, state,
                                      estimator=estimator, live_every=live_every, on_estimate=on_estimate,
                                      on_progress=on_progress, clock=None if coded else clock)
                try:
                    survey = coded.run(runner) if coded else runner.run()
                except SurveyStopped as exc:
                    stopped, survey = exc, journal_to_survey(runner.state)
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
    if stopped is not None:
        raise stopped
    return survey, runner


def journal_survey(out_dir_or_journal: str | os.PathLike[str]) -> Survey:
    """The survey recorded in a journal file or a survey directory."""
    p = Path(out_dir_or_journal)
    return journal_to_survey(read_journal(p / JOURNAL_NAME if p.is_dir() else p))
