"""Coded identification: a survey that reads many motes per view by their blink codes.

``"identification": "coded"`` in rig.json (or ``fgloc survey --identify coded``) runs,
instead of the node loop of :mod:`fgloc.survey.runner` (docs/survey.md, "Coded identification"):

1. **Start.** One broadcast start by address through the mote driver
   (:class:`~fgloc.drivers.tinyos.blink.BlinkBroadcast`, ``MoteNetwork.broadcast_codes``):
   the mote with address ``first + k`` runs word k of the code book
   (:func:`fgloc.camera.blink_codes.code_book`), one bit per frame period. Sent again (up
   to :attr:`CodedSettings.start_attempts`) while some mote has not confirmed.
2. **Views, every camera in parallel.** Each camera's views cover the rig's search box
   (:func:`fgloc.survey.view_planner.plan_views`; every direction lies at least 8 px inside
   some view). Per view: the head slews there (the camera worker's retries and
   reconnects), its position is read back, ``3L + 2`` frames are recorded (the simulated
   rigs' ``record_blinks``; on hardware ``grab_frame`` with host timestamps) and decoded
   (:func:`fgloc.camera.blink_decoder.decode_view`). Each decoded LED's centroid is
   re-measured on its mean lit minus mean dark frame
   (:func:`~fgloc.survey.coded_views.on_off_centroid`) and becomes (pan, tilt) by
   :func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt` at the read-back angles
   (:func:`~fgloc.survey.coded_views.coded_observation`). With a head repeatability
   (rig.json ``head_repeatability_deg``) each reading also carries its total sigma and the
   view's shared one, and survey.json names its view (``views``: the readings of one
   settle share the head's pointing error; the solver estimates one per view). A camera takes at most
   ``repeats`` readings of a mote. A view with curable refusals (a word read with
   conflicts or gaps, a duplicate ID) is recorded once more at once.
3. **Refinement** (rigs whose ``record_blinks`` renders other zooms: ``blink_zoom``).
   Blobs no reading explains (:func:`~fgloc.survey.coded_views.unexplained_blob`) are
   recorded again in tiles at the next zoom of :attr:`CodedSettings.levels` until none is
   left. The head zooms back to the survey zoom on its lane if that ends no later than the
   longest lane, else only before its next operation (a fallback search, priced there; else
   after the survey's last reading, not priced: the survey ends at its last recording).
   Refused blobs are journaled and logged, never guessed.
   ``ladder "focus"`` (:mod:`fgloc.survey.coded_ladder`): a blob at a reading of the camera
   is that mote; a rung hands on only blobs near what it chased; lamps go to the fallback.
4. **Stop**, one broadcast.
5. **Fallback.** For each node a camera has not read: a camera whose views left no blob
   unexplained journals ``not_found`` without a search; otherwise the node is measured the
   sequential way (:meth:`SurveyRunner.run_node`: its LED alone) with that camera looking
   only at the directions of its unexplained blobs (the full grid for motes that never
   confirmed their code, or after a failed view). Nodes every camera read are journaled
   ``node_done`` without lighting them.

Levers (:class:`CodedSettings`, chosen by rig.json ``"coded"`` or ``fgloc survey --coded``,
:mod:`fgloc.survey.coded_levers`). A new survey's defaults are the measured fastest:
``retry "continue"`` (a retry goes on recording L frames, decoded in sliding windows),
``probe "on"`` (a recording stops after L + 2 frames showing no blob), ``fallback
"predicted"`` (:mod:`fgloc.survey.coded_fallback`), ``pairs "groups"`` and ``ladder "focus"``; the procedure above
is ``retry "burst"``, ``probe "off"``, ``fallback "blobs"``, ``pairs "off"``, ``ladder "climb"``
(:data:`~fgloc.survey.coded_levers.LEGACY`). Not by default: ``separate "radio"`` (colour
classes paused by bitmap between the wide pass and the refinement,
:mod:`fgloc.survey.coded_separation`; by default short rounds labelled against the lit
class, :mod:`fgloc.survey.coded_rounds`, in view-major order,
:mod:`fgloc.survey.coded_view_major`; every camera's wide pass, the rounds (class-major:
each round), then the refinement are barriers) and ``video "fields"``. The journal's header records the levers a
survey started with (``coded``); ``--resume`` runs with them
(:func:`~fgloc.survey.coded_levers.coded_settings`).

Crash safety: a view's readings are committed together, as one ``view`` journal record
(:meth:`fgloc.files.journal.JournalWriter.view`); a kill during a view loses only that
view. ``--resume`` re-plans the same views (a function of the rig and, for refinement
rungs, of the journaled views), skips every view with a record, records the rest, and
never takes a reading twice.

Field time (:mod:`fgloc.survey.clock`): each camera lane is priced from its plan (slew
from the previous view, settle, position read, the frames of each recording; the second
recordings as journaled), the lanes run in parallel, plus the radio; fallback nodes are
priced from the operations their heads performed (:mod:`fgloc.survey.coded_clock`) and
journaled per node. A resumed survey reports the uninterrupted survey's field time (the
move back to where it stopped is not priced). Angles radians, times seconds.
"""

from __future__ import annotations

import functools
import logging
import queue
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from fgloc.camera.blink_codes import CodeBook, code_book
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.errors import FglocError
from fgloc.core.hardware import PanTiltHead
from fgloc.core.model import Survey
from fgloc.files.journal import journal_to_survey
from fgloc.files.rig_config import RigConfig
from fgloc.survey.clock import (
    CameraTiming,
    FieldTime,
    Frames,
    Op,
    PositionRead,
    Settle,
    Slew,
    Zoom,
    parallel,
    price,
    sum_times,
)
from fgloc.survey.coded_clock import SequentialClock
from fgloc.survey.coded_epipolar import EpipolarBand
from fgloc.survey.coded_ladder import (
    CROWD_READINGS,
    SEPARATION_PX,
    Blob,
    focused,
    light_before,
    may_record_again,
    never_dark,
    read_before,
    resolved_elsewhere,
    retry_helps,
    unread,
    unseen,
)
from fgloc.survey.coded_radio import pause_motes, start_codes, stop_codes
from fgloc.survey.coded_readings import field_intrinsics
from fgloc.survey.coded_recording import Frame, record_view
from fgloc.survey.coded_rounds import RoundCandidates, retry_wanted
from fgloc.survey.coded_settings import CodedSettings, CodedStats
from fgloc.survey.coded_views import (
    distinct_directions,
    into_search_box,
    needs_second_recording,
    unexplained_blob,
)
from fgloc.survey.field_plans import frames_for
from fgloc.survey.runner import CameraFailed, Progress, SurveyRunner
from fgloc.survey.view_planner import box_targets, plan_views

logger = logging.getLogger(__name__)


CLUSTER_SPREAD_PX = 6.0  #: refinement tiles also cover this far (px of the coarser view) around a blob


class CodedSurvey:
    """The coded identification phase of one run (see the module docstring)."""

    def __init__(self, rig: RigConfig, open_head: Callable[[str], PanTiltHead], leds: object,
                 recorder: object | None = None, settings: CodedSettings | None = None) -> None:
        from fgloc.drivers.tinyos.messages import node_address

        self.rig = rig
        from fgloc.survey.coded_levers import coded_settings

        self.settings = settings or coded_settings(rig)
        self.recorder = getattr(recorder, "record_blinks", None)
        if not callable(getattr(leds, "broadcast_codes", None)):
            raise FglocError(f"{rig.path}: identification: the base station ({rig.motes.driver}) cannot "
                             "broadcast blink codes; use \"sequential\"")
        amap = getattr(leds, "addresses", None) or getattr(leds, "address_map", None) or rig.motes.addresses
        try:
            self.addresses = {n: node_address(n, amap) for n in rig.node_ids}
        except Exception as exc:  # noqa: BLE001 - MoteError names the node
            raise FglocError(f"{rig.path}: motes.addresses: {exc}") from None
        self.first = min(self.addresses.values())
        count = max(self.addresses.values()) - self.first + 1
        self.book: CodeBook = code_book(count)
        self.node_of_code = {a - self.first: n for n, a in self.addresses.items()}
        self.frames = frames_for(self.book.length, self.settings.periods)
        self.fields = self.settings.video == "fields"
        self.camera = CameraTiming().at_field_rate() if self.fields else CameraTiming()
        # the runner's heads and LEDs: fallback nodes are priced as a sequential survey's nodes are
        self.clock = SequentialClock(rig, open_head, leds)  # type: ignore[arg-type]
        self.open_head, self.leds, self.timing = self.clock.open_head, self.clock.leds, self.clock.timing
        #: the camera lanes' clock (the fallback's sequential nodes keep ``timing``: whole frames)
        self.lane_timing = {c: replace(t, camera=self.camera) for c, t in self.timing.items()}
        if self.fields and not getattr(recorder, "blink_fields", False):
            raise FglocError(f"{rig.path}: coded.video: \"fields\" needs a rig that records interlaced fields "
                             "(the in-process rig); use \"frames\"")
        if self.fields and not all(t.head.interlaced for t in self.timing.values()):
            raise FglocError(f"{rig.path}: coded.video: \"fields\" needs heads with interlaced video "
                             f"({', '.join(c.model for c in rig.cameras)}); use \"frames\"")
        self.stats = CodedStats()
        self.lanes: dict[str, list[Op]] = {c: [] for c in rig.camera_ids}
        self.radio_s = 0.0
        self.fallback = FieldTime({})
        self._events: queue.Queue[str] = queue.Queue()
        self.survey_zoom = {c.id: c.zoom for c in rig.cameras}
        # refinement needs frames at other zooms: the simulated rigs that render them say so
        self.levels = self.settings.levels if getattr(recorder, "blink_zoom", False) else ()
        self.remaining: dict[str, int] = {}  # camera -> unexplained blobs and failed views after its last rung
        self.blobs: dict[str, list[tuple[float, float]] | None] = {}  # their directions (None: a view failed)
        self._continue_at: dict[tuple[str, str], float] = {}  # (camera, view) -> clock s its recording ends
        self._head_at: dict[str, tuple[float, float] | None] = {}  # camera -> read-back head of its last view
        self.final_blobs: dict[str, np.ndarray] = {}  # camera -> (M, 2) directions of its unexplained blobs
        self.final_lamps: dict[str, np.ndarray] = {}  # camera -> (K, 2) those of them the ladder took for lamps
        #: camera -> (K,) the angle (radians) two LEDs merge within around each lamp: the decoder's
        #: separation (coded_ladder.SEPARATION_PX) at the zoom of the recording that handed it
        self.final_lamp_radii: dict[str, np.ndarray] = {}
        #: camera -> node one other camera read -> where it can lie (fallback looks, lever ``looks``),
        #: and the bands' measured scale (radians; None: unmeasured): set with the fallback's prediction
        self.bands: dict[str, dict[str, EpipolarBand]] = {}
        self.across_scale: float | None = None
        self.here: dict[str, tuple[float, float]] = {}  # camera -> head (pan, tilt) after its last view
        self._zooms_while_moving: dict[str, bool] = {}  # camera -> zooms during its moves (zooms_while_moving)
        self.wide_records: dict[str, list[dict[str, Any] | None]] = {}
        self._done_views = 0
        self._never_dark: set[tuple[str, Blob]] = set()  # (camera, blob) of unexplained blobs that never went dark
        self._merged: set[tuple[str, Blob]] = set()  # (camera, blob) of blobs refused as two or more LEDs merged
        self.owed_zoom: dict[str, float] = {}  # camera -> the zoom its head was left at (zoom back owed)
        self.stages = FieldTime({})  # barrier stages done (radio separation: wide pass, rounds), in series

    # ----- plan and clock
    def plan(self, camera: str) -> list[tuple[float, float]]:
        """The camera's views (head pan, tilt), in visiting order: a function of the rig only."""
        s = self.rig.search_for(camera)
        cam = self.rig.cameras[self.rig.camera_ids.index(camera)]
        step = self.settings.target_step * self.settings.margin_px / max(cam.intrinsics.fx, cam.intrinsics.fy)
        targets = box_targets(s.pan_min, s.pan_max, s.tilt_min, s.tilt_max, step)
        home = (0.0, 0.5 * (s.tilt_min + s.tilt_max))
        views = plan_views(cam.intrinsics, targets, self.settings.margin_px, start=home,
                           tilt_limits=(s.tilt_min, s.tilt_max), minimal=self.settings.tiling == "minimal")
        return [into_search_box(p, t, s.pan_min, s.pan_max, s.tilt_min, s.tilt_max) for p, t in views]

    def _lane_start(self, camera: str) -> float:
        """Survey-clock seconds at which the camera's next operation starts."""
        return self.radio_s + self.stages.total + price(self.lanes[camera], self.lane_timing[camera]).total

    def field_time(self) -> FieldTime:
        """Predicted field time so far: radio, the longest camera lane, the fallback nodes."""
        lanes = [price(ops, self.lane_timing[c]) for c, ops in self.lanes.items()]
        radio = FieldTime({"radio": self.radio_s})
        return sum_times([radio, self.stages, parallel(lanes), FieldTime({"fallback": self.fallback.total})])

    # ----- one camera
    def _record(self, runner: SurveyRunner, camera: str, vid: str, attempt: int, target: tuple[float, float],
                head: tuple[float, float], zoom: float, t_start: float,
                before: list[Frame] | None = None,
                candidates: RoundCandidates | None = None) -> tuple[dict[str, Any], list[Frame]]:
        """One recording of a view and its journal record (:func:`fgloc.survey.coded_recording.record_view`)."""
        return record_view(self, runner, camera, vid, attempt, target, head, zoom, t_start, before, candidates)

    def _commit(self, runner: SurveyRunner, record: dict[str, Any]) -> None:
        """Journal one view (the commit of all its readings), then apply it to the state."""
        from fgloc.files.journal import view_observation

        with runner._state_lock:
            runner.journal.view(record)
            runner.state.views[(record["camera"], record["view"], record["attempt"])] = {"type": "view"} | record
            for r in record["readings"]:
                runner.state.add_observation(view_observation(record["camera"], record["view"], r,
                                                              float(record["head"][0]), record.get("zoom"),
                                                              float(record["head"][1])))
        s = self.stats
        s.recordings += 1
        s.second_recordings += record["attempt"] > 0
        s.readings += len(record["readings"])
        runner.stats.observations += len(record["readings"])
        for r in record["refused"]:
            setattr(s, r["kind"], getattr(s, r["kind"]) + 1)
            logger.info(f"{record['camera']} view {record['view']} ({record['attempt']}): {r['kind']} blob at "
                        f"({r['u']:.1f}, {r['v']:.1f}) px: {r['reason']}")

    def zooms_while_moving(self, runner: SurveyRunner, camera: str) -> bool:
        """Lever ``zoom_moves "together"``: does ``camera`` zoom during its moves? Its head model
        must zoom while moving (:attr:`fgloc.survey.clock.HeadModel.zoom_while_moving`, priced so)
        and its driver must run both at once: a ``move_and_zoom`` method and ``concurrent_zoom``
        true (the VISCA head over a serial line sends the zoom and the move to the camera's two
        command sockets; over IP it runs them one after the other)."""
        if camera not in self._zooms_while_moving:
            if self.settings.zoom_moves != "together" or not self.lane_timing[camera].head.zoom_while_moving:
                self._zooms_while_moving[camera] = False
                return False
            worker = runner.workers[camera]
            try:
                if worker.head is None:  # first asked at the camera's first view, before it owes anything
                    worker.call(lambda h: None)  # opens the head
            except CameraFailed:
                return False  # its views fail too; asked again if it comes back
            self._zooms_while_moving[camera] = (callable(getattr(worker.head, "move_and_zoom", None))
                                                and bool(getattr(worker.head, "concurrent_zoom", False)))
        return self._zooms_while_moving[camera]

    def _visit(self, runner: SurveyRunner, camera: str, vid: str, target: tuple[float, float], zoom: float,
               here: tuple[float, float] | None, extra: dict[str, Any] | None = None,
               candidates: RoundCandidates | None = None,
               head: tuple[float, float] | None = None, dzoom: float = 0.0) -> dict[str, Any] | None:
        """Record one view (and its second recording when needed) unless journaled; prices it
        on the camera's lane. Returns the view's last record (None: the camera failed).
        ``candidates``: a short round view (:mod:`fgloc.survey.coded_rounds`). ``here`` None:
        the head is already at ``target`` (view-major rounds: the same view, another class),
        ``head`` its read-back angles if this process read them (None: read them on recording).
        ``dzoom``: the zoom travel (fraction of the optical range) to ``zoom`` that runs during
        the move here (a camera that :meth:`zooms_while_moving`), priced with the move."""
        worker, lane = runner.workers[camera], self.lanes[camera]
        together = self.zooms_while_moving(runner, camera)
        if here is not None:
            lane += [Slew.between(here, target, dzoom), Settle(),
                     PositionRead()]
            head = None
        self._head_at[camera] = head
        last = None
        video: list[Frame] | None = None  # this process's frames of the view (a resumed view has none)
        for attempt in range(1 + self.settings.retries):
            rec = runner.state.views.get((camera, vid, attempt))
            if rec is not None and ([float(x) for x in rec.get("target", [])] != list(target)
                                    or float(rec.get("zoom", self.survey_zoom[camera])) != zoom):
                rec = None  # another plan (the search box changed): record this view anew
            if rec is None:
                try:
                    if head is None:
                        def go(h: PanTiltHead) -> None:  # in one call: a reconnect resets the survey zoom
                            if together:
                                h.move_and_zoom(*target, zoom)  # type: ignore[attr-defined]
                            else:
                                h.set_zoom(zoom)
                                h.move_to(*target)

                        worker.call(go)
                        got = worker.call(lambda h: h.position())
                        head = (float(got[0]), float(got[1]))  # type: ignore[index]
                        self._head_at[camera] = head
                    # a short round view always goes on recording (the candidates label any sample count)
                    goes_on = self.settings.retry == "continue" or candidates is not None
                    cont = video if goes_on and attempt > 0 else None
                    rec, video = self._record(runner, camera, vid, attempt, target, head, zoom,
                                              self._lane_start(camera), cont, candidates)
                except CameraFailed as exc:
                    self.stats.failed_views.append(f"{camera}/{vid}")
                    logger.warning(f"{camera} view {vid}: camera error, view not recorded: {exc}")
                    return None
                self._commit(runner, rec := rec | (extra or {}))
                self._events.put(camera)
            else:
                video = None  # journaled before a resume: its video is gone, a retry is a new burst
            lane.append(Frames(int(rec.get("frames", self.frames)), "frames", bool(rec.get("continued"))))
            last = rec
            if not (retry_wanted(rec) if candidates is not None else needs_second_recording(rec)):
                break
            if not may_record_again(vid, self.settings.retries_at):
                break  # a view the lever retries_at records once (coded_ladder.may_record_again)
            if candidates is None and self.settings.ladder == "focus" and not self._retry_helps(runner, camera, rec):
                break  # every blob it leaves unexplained is a mote this camera read (coded_ladder.retry_helps)
        return last

    def unexplained(self, records: Sequence[dict[str, Any] | None]) -> list[Blob]:
        """The blobs no reading explains (:func:`unexplained_blob`) in ``records``: pixel, the
        recording's head (pan, tilt) and zoom."""
        out = []
        for rec in records:
            if rec is None:
                continue
            zoom = float(rec.get("zoom", self.survey_zoom[rec["camera"]]))
            head = (float(rec["head"][0]), float(rec["head"][1]))
            for r in rec["refused"]:
                if unexplained_blob(r) and "u" in r:
                    out.append(blob := ((float(r["u"]), float(r["v"])), head, zoom))
                    if never_dark(r):
                        self._never_dark.add((rec["camera"], blob))
                    if r.get("kind") == "ambiguous":
                        self._merged.add((rec["camera"], blob))
        return out

    def _dark(self, camera: str, blobs: list[Blob]) -> list[bool]:
        """Which of ``blobs`` (of :meth:`unexplained`) never went dark (:func:`fgloc.survey.coded_ladder.never_dark`)."""
        return [(camera, b) in self._never_dark for b in blobs]

    def _retry_helps(self, runner: SurveyRunner, camera: str, rec: dict[str, Any]) -> bool:
        """Whether recording ``rec``'s view again may read a mote the camera has not read
        (:func:`fgloc.survey.coded_ladder.retry_helps`; readings of the views before it only)."""
        with runner._state_lock:
            read = read_before(runner.state.views, camera, 0, str(rec["view"]), int(rec["attempt"]))
        return retry_helps(rec, read, lambda z: self.intrinsics_at(camera, z), self.survey_zoom[camera])

    def _unread(self, runner: SurveyRunner, camera: str, blobs: list[Blob], rung: int) -> list[Blob]:
        """``blobs`` but those at a reading of the camera's views up to refinement ``rung``
        (:func:`fgloc.survey.coded_ladder.unread`) and, with ``explain "views"`` or ``"crowds"``,
        between two refinement rungs, those another of those recordings resolved
        (:func:`fgloc.survey.coded_ladder.resolved_elsewhere`). From the wide pass only with
        ``"crowds"``, and only where that recording read a crowd (:data:`CROWD_READINGS`): with one
        reading enough, motes the first tiles read were lost (docs/blink-codes.md, "Blobs another
        view resolved", "Crowds another wide view read apart"). Not for the fallback: no gain
        measured there."""
        at = functools.partial(self.intrinsics_at, camera)
        explain = self.settings.explain
        with runner._state_lock:
            read = read_before(runner.state.views, camera, rung)
            kept = [blobs[k] for k in unread(blobs, read, at, [(camera, b) in self._merged for b in blobs])]
            between = explain in ("views", "crowds") and 1 <= rung < len(self.levels)
            if between or (explain == "crowds" and rung == 0):
                done = resolved_elsewhere(kept, runner.state.views, camera, rung, at, self.survey_zoom[camera],
                                          min_readings=1 if between else CROWD_READINGS)
                kept = [b for b, d in zip(kept, done) if not d]
        return kept

    def blob_directions(self, camera: str, blobs: list[Blob], spread_px: float = 0.0) -> np.ndarray:
        """(M, 2) (pan, tilt) of ``blobs``; with ``spread_px`` each blob also gives the 8
        directions ``spread_px`` (pixels of its own recording) around it, so tiles cover every
        member of a cluster that merged into it."""
        out = []
        steps = (-spread_px, 0.0, spread_px) if spread_px else (0.0,)
        for (u, v), head, zoom in blobs:
            intr = self.intrinsics_at(camera, zoom)
            for du in steps:
                for dv in steps:
                    p, t = pixel_to_pan_tilt(intr, np.array([u + du, v + dv]), *head)
                    out.append((float(p), float(t)))
        return np.array(out, dtype=float).reshape(-1, 2)

    def intrinsics_at(self, camera: str, zoom: float) -> CameraIntrinsics:
        """The camera's intrinsics at ``zoom`` (its own at the survey zoom; else the idealised
        :meth:`~fgloc.camera.intrinsics.CameraIntrinsics.at_zoom` model, as the simulator renders);
        with fields, those of one field (:func:`~fgloc.survey.coded_readings.field_intrinsics`)."""
        intr = self.rig.cameras[self.rig.camera_ids.index(camera)].intrinsics
        intr = intr if zoom == self.survey_zoom[camera] else intr.at_zoom(zoom)
        return field_intrinsics(intr) if self.fields else intr

    def run_camera(self, runner: SurveyRunner, camera: str, views: list[tuple[float, float]]) -> None:
        """The wide pass (:meth:`run_wide`), then the zoom refinement of its unexplained blobs."""
        self.run_wide(runner, camera, views)
        recs = self.wide_records[camera]
        self.run_refine(runner, camera, self.unexplained(recs), any(r is None for r in recs))

    def run_wide(self, runner: SurveyRunner, camera: str, views: list[tuple[float, float]]) -> None:
        """Record every view of ``camera`` that has no journal record yet (in plan order)."""
        here, zoom0 = runner.workers[camera].home, self.survey_zoom[camera]
        last: list[dict[str, Any] | None] = []
        for k, target in enumerate(views):
            last.append(self._visit(runner, camera, f"w{k:03d}", target, zoom0, here))
            here = target
        self.stats.views += len(views)
        self.here[camera], self.wide_records[camera] = here, last

    def run_refine(self, runner: SurveyRunner, camera: str, blobs: list[Blob], failed: bool,
                   keep: list[Blob] | None = None) -> None:
        """The refinement rungs: tiles over ``blobs`` (unexplained so far) at the next zoom of the
        ladder, then over what those tiles left unexplained, until none is left or the ladder
        ends; the zoom back to the survey zoom is owed (:meth:`owe_zoom_back`). ``failed``: a view
        failed (its blobs are unknown; the fallback covers this camera). ``keep``: blobs the
        fallback must still search even when every rung explains its own."""
        here, zoom0 = self.here[camera], self.survey_zoom[camera]
        zoom = zoom0
        s = self.rig.search_for(camera)
        handed: list[Blob] = []  # ladder "focus": static lamps the fallback searches instead of the next rung
        fresh: list[Blob] = []  # ladder "focus": light no coarser recording showed, away from what a rung chased
        focus = self.settings.ladder == "focus"
        for rung, level in enumerate(self.levels, start=1):
            if failed:
                break
            if focus:  # blobs at a mote this camera read are that mote (coded_ladder.unread)
                blobs = self._unread(runner, camera, blobs, rung - 1)
            pts = self.blob_directions(camera, blobs, spread_px=CLUSTER_SPREAD_PX)
            if not len(pts):
                break
            minimal = self.settings.tiling == "minimal"  # a blob's directions stay in one tile
            tiles = [into_search_box(p, t, s.pan_min, s.pan_max, s.tilt_min, s.tilt_max) for p, t in plan_views(
                self.intrinsics_at(camera, level), pts, self.settings.margin_px, start=here,
                tilt_limits=(s.tilt_min, s.tilt_max), minimal=minimal,
                groups=np.repeat(np.arange(len(blobs)), len(pts) // len(blobs)) if minimal else None)]
            together = bool(tiles) and self.zooms_while_moving(runner, camera)
            if not together:
                self.lanes[camera].append(Zoom(level - zoom))
            dzoom, zoom, last = level - zoom, level, []
            for k, target in enumerate(tiles):  # a head that zooms while moving zooms on its way to the first tile
                last.append(self._visit(runner, camera, f"r{rung}-{k:03d}", target, level, here,
                                        dzoom=dzoom if together and k == 0 else 0.0))
                here = target
            self.stats.views += len(tiles)
            chased, failed, blobs = blobs, any(r is None for r in last), self.unexplained(last)
            if focus:
                at = functools.partial(self.intrinsics_at, camera)
                with runner._state_lock:
                    seen = light_before(runner.state.views, camera, rung, at, zoom0)
                found = blobs
                blobs, lamps = focused(chased, self._dark(camera, chased), found, self._dark(camera, found), at)
                handed += lamps
                fresh += [b for b in unseen(found, seen, at) if b not in blobs and b not in lamps]
        if focus and not failed:
            blobs = self._unread(runner, camera, blobs + fresh, len(self.levels))
        blobs = blobs + handed + (keep or [])
        self.remaining[camera] = int(failed) + len(blobs)
        fov = min(runner.workers[camera].locator.pixels.field_of_view())  # at the survey zoom
        self.final_blobs[camera] = self.blob_directions(camera, blobs)
        self.final_lamps[camera] = self.blob_directions(camera, handed)
        lamp_intrinsics = [self.intrinsics_at(camera, z) for _uv, _head, z in handed]
        self.final_lamp_radii[camera] = np.array([SEPARATION_PX / max(i.fx, i.fy) for i in lamp_intrinsics])
        self.blobs[camera] = None if failed else distinct_directions(self.final_blobs[camera], 0.25 * fov)
        self.here[camera] = here
        if zoom != zoom0:
            self.owe_zoom_back(runner, camera, zoom)

    def owe_zoom_back(self, runner: SurveyRunner, camera: str, zoom: float) -> None:
        """The head, left at ``zoom`` by the refinement, zooms back to the survey zoom on its lane
        when that fits before the longest lane ends (:meth:`zoom_back_in_slack`), else just before
        its next operation: a fallback search (priced in that node's field time), the repeats, or
        the end of the survey (:meth:`settle_heads`, after the last reading: not priced). The
        camera that finishes last so ends its lane at its last recording."""
        zoom0 = self.survey_zoom[camera]

        def back(head: PanTiltHead) -> None:
            head.set_zoom(zoom0)  # first: a zoom that fails is retried (on a reopened head), priced once
            self.clock.sink.add(camera, Zoom(zoom0 - zoom))  # recorded only inside a priced node

        runner.workers[camera].before_next = back
        self.owed_zoom[camera] = zoom

    def zoom_back_in_slack(self, runner: SurveyRunner) -> None:
        """After every lane's last recording: a camera owing its zoom back whose lane, the zoom
        back included, still ends no later than the longest lane zooms back now, priced on its
        lane (it would have zoomed back while another camera still recorded, at no cost to the
        survey); the others keep owing it."""
        ends = {c: price(ops, self.lane_timing[c]).total for c, ops in self.lanes.items()}
        longest = max(ends.values(), default=0.0)
        for camera, zoom in sorted(self.owed_zoom.items()):
            back = Zoom(self.survey_zoom[camera] - zoom)
            worker = runner.workers[camera]
            if worker.before_next is None or ends[camera] + price([back], self.lane_timing[camera]).total > longest:
                continue
            self.lanes[camera].append(back)
            worker.before_next = None
            zoom0 = self.survey_zoom[camera]
            try:
                worker.call(lambda h: h.set_zoom(zoom0))  # noqa: B023 - called at once
            except CameraFailed as exc:
                logger.warning(f"{camera}: could not zoom back to the survey zoom: {exc}")

    def settle_heads(self, runner: SurveyRunner) -> None:
        """Zoom back every head still owing it (the survey's readings are all taken)."""
        for camera, worker in runner.workers.items():
            if worker.before_next is not None:
                try:
                    worker.call(lambda _h: None)
                except CameraFailed as exc:
                    logger.warning(f"{camera}: could not zoom back to the survey zoom: {exc}")

    # ----- the whole phase
    def start_codes(self, runner: SurveyRunner) -> None:
        start_codes(self, runner)

    def pause(self, paused: set[int]) -> None:
        """Pause the motes at ``paused`` addresses, resume the others (:func:`fgloc.survey.coded_radio.pause_motes`)."""
        pause_motes(self, paused)

    def stop_codes(self, runner: SurveyRunner) -> None:
        stop_codes(self, runner)

    def progress(self, runner: SurveyRunner, views_done: int, views_total: int, t0: float) -> Progress:
        st, cams = runner.state, self.rig.camera_ids
        done = sum(1 for n in self.rig.node_ids
                   if n in st.done or all(st.camera_finished(n, c, self.rig.repeats) for c in cams))
        eta = None
        if views_done:
            eta = (views_total - views_done) * (time.perf_counter() - t0) / views_done
        failures = len(st.not_found) + len(st.led_failed)
        return Progress(done, len(self.rig.node_ids), len(st.observations), failures, eta, self.field_time().total)

    def pump(self, runner: SurveyRunner, futures: list[Future[None]], total: int, t0: float) -> None:
        """Wait for the camera threads' ``futures``, with live estimates and progress per view."""
        emit = runner.on_progress or (lambda _p: None)
        since = 0
        while not all(f.done() for f in futures) or not self._events.empty():
            try:
                self._events.get(timeout=0.05)
            except queue.Empty:
                continue
            self._done_views, since = self._done_views + 1, since + 1
            if since >= runner.live_every:
                since = 0
                runner.estimate(nodes_done=self._finished_nodes(runner))
            emit(self.progress(runner, min(self._done_views, total), total, t0))
        for f in futures:
            f.result()

    def next_stage(self) -> None:
        """A barrier: every camera's lane so far is done before anything after it starts."""
        self.stages = self.stages + parallel([price(ops, self.lane_timing[c]) for c, ops in self.lanes.items()])
        self.lanes = {c: [] for c in self.rig.camera_ids}

    def _finished_nodes(self, runner: SurveyRunner) -> int:
        st = runner.state
        return sum(1 for n in self.rig.node_ids
                   if all(st.camera_finished(n, c, self.rig.repeats) for c in self.rig.camera_ids))

    def run(self, runner: SurveyRunner) -> Survey:
        """Run (or resume) the coded survey on ``runner``'s journal; returns the recorded survey."""
        plans = {c: self.plan(c) for c in self.rig.camera_ids}
        total = sum(len(v) for v in plans.values())
        self.fallback = sum_times(FieldTime({k: float(v) for k, v in r["phases"].items()})
                                  for r in runner.state.field_times if r.get("scope") in ("fallback_node", "fallback_group", "fallback_pair"))
        # the motes blink until the stop, which follows the last view: without a journaled stop
        # (first run, or killed during the views) they are started (again; the codes need no sync)
        todo = not any(r.get("action") == "stop" for r in runner.state.codes)
        t0 = time.perf_counter()
        emit = runner.on_progress or (lambda _p: None)
        emit(self.progress(runner, 0, total, t0))
        try:
            with ThreadPoolExecutor(max_workers=len(self.rig.camera_ids), thread_name_prefix="camera") as pool:
                if todo:
                    self.start_codes(runner)
                radio = self.settings.separate == "radio"
                self._done_views = sum(1 for key in runner.state.views if key[2] == 0)
                self.pump(runner, [pool.submit(self.run_wide if radio else self.run_camera, runner, c, v)
                                   for c, v in plans.items()], total, t0)
                if radio:
                    from fgloc.survey.coded_separation import run_separation

                    run_separation(self, runner, pool, lambda fs: self.pump(runner, fs, total, t0))
                self.zoom_back_in_slack(runner)
                if self.settings.fallback == "round":
                    from fgloc.survey.coded_fallback_round import run_fallback_round

                    run_fallback_round(self, runner, pool, lambda fs: self.pump(runner, fs, total, t0), todo)
                self.stop_codes(runner)
                self.run_fallback(runner, pool, total, t0)
                if self.rig.repeat_budget > 0:
                    from fgloc.survey.repeats import run_repeats

                    run_repeats(runner, pool)
                runner.estimate(nodes_done=len(runner.state.done))
                self.settle_heads(runner)
        finally:
            for w in runner.workers.values():
                try:
                    w.close()
                except Exception:  # noqa: BLE001 - closing a dead link must not lose the survey
                    pass
        s = self.stats
        if s.ambiguous or s.duplicate or s.unassigned:
            logger.warning(f"refused blobs: {s.ambiguous} ambiguous (LEDs closer than the detector separates), "
                           f"{s.duplicate} duplicate IDs, {s.unassigned} codes no mote runs; never guessed "
                           f"(recorded again zoomed in where the rig can; {s.fallback_nodes} nodes measured "
                           "the sequential way)")
        ft = self.field_time()
        runner.journal.field_time("survey", dict(ft.phases))
        runner.field_time = ft
        emit(self.progress(runner, total, total, t0))
        return journal_to_survey(runner.state)

    def run_fallback(self, runner: SurveyRunner, pool: ThreadPoolExecutor, total: int, t0: float) -> None:
        """Finish every node some camera has not read (:func:`fgloc.survey.coded_fallback.run_fallback`)."""
        from fgloc.survey.coded_fallback import run_fallback

        run_fallback(self, runner, pool, total, t0)
