"""Run a survey: light each node's LED, let every camera find and measure it, journal it all.

Per node: ``node_started`` is journaled, the LED is lit (retried; a node that
never acknowledges is journaled ``led_failed``), every camera that has no final
outcome for the node yet locates it in parallel (one thread per camera) and
journals each reading the moment it is taken (fsynced, from the camera's
thread) or a ``not_found``; then the LED goes off and
``node_done`` is journaled. Nothing is ever rewritten: resuming replays the
journal and redoes only what has no record, so no reading is lost or duplicated
wherever the process was killed.

Each camera's search for a node starts where that camera's last journaled
reading points (or at pan 0 and mid tilt), so a resumed survey drives a
deterministic rig through exactly the same moves as an uninterrupted one.

Head errors are retried ``retry.head_attempts`` times with a back-off, then the
head is reopened (``open_head``) up to ``retry.reconnects`` times; a camera that
still fails is journaled ``not_found`` with the error for that node and tried
again on the next one.

A camera that finds nothing (``not_found``, for any reason) for
``retry.max_consecutive_misses`` lit nodes in a row stops the survey after that node:
a ``survey_stopped`` record is journaled and :class:`SurveyStopped` raised (the journal
stays resumable). 0 turns the rule off.

Live estimates: after each node (once at least five nodes are seen by two
cameras) an :class:`~fgloc.survey.live.Estimator` solves the journal so far; the
default is the batch joint solve. An incremental (iSAM2) estimator can be passed instead.

Repeat phase: with ``repeat_budget`` > 0, after the last node :mod:`fgloc.survey.repeats`
re-measures the readings the Cramér–Rao planner ranks most informative (resume-safe).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from fgloc.camera.led_search import LedLocator, PinholePixelModel
from fgloc.core.errors import FglocError
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.core.hardware import LedController, PanTiltHead
from fgloc.core.model import Survey
from fgloc.core.retry import RetryPolicy, linear
from fgloc.files.journal import JournalObservation, JournalState, JournalWriter, journal_to_survey
from fgloc.files.rig_config import RigConfig
from fgloc.survey.live import MIN_SHARED_NODES, Estimator, LiveEstimate

if TYPE_CHECKING:
    import numpy as np

    from fgloc.survey.clock import FieldTime
    from fgloc.survey.coded_clock import SequentialClock

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Progress:
    """Survey progress for a progress bar. ``eta_s`` is None until one node was timed;
    ``field_s`` is the predicted field time so far (survey clock), None when not priced."""

    nodes_done: int
    nodes_total: int
    observations: int
    failures: int
    eta_s: float | None
    field_s: float | None = None


class SurveyStopped(FglocError):
    """A camera found nothing for ``retry.max_consecutive_misses`` nodes in a row; the journal is resumable."""


class CameraFailed(Exception):
    """A camera kept failing after all retries and reconnects."""


class _LedNotConfirmed(Exception):
    """One LED attempt that the base station did not confirm (retried, then ``led_failed``)."""


@dataclass
class RunnerStats:
    """Counts of what happened during this run (this process only)."""

    nodes_measured: int = 0
    nodes_skipped: int = 0
    observations: int = 0
    not_found: int = 0
    led_failed: int = 0
    head_errors: int = 0
    reconnects: int = 0
    led_retries: int = 0
    estimates: int = 0
    estimate_errors: list[str] = field(default_factory=list)


class CameraWorker:
    """Owns one camera's head: retries, reconnects, and the LED locator."""

    def __init__(self, camera_id: str, open_head: Callable[[], PanTiltHead], rig: RigConfig,
                 stats: RunnerStats) -> None:
        self.camera_id = camera_id
        self.open_head = open_head
        self.retry = rig.retry
        self.stats = stats
        cam = rig.cameras[rig.camera_ids.index(camera_id)]
        search = rig.search_for(camera_id)
        self.locator = LedLocator(search, PinholePixelModel(cam.intrinsics))
        self.home = (0.0, 0.5 * (search.tilt_min + search.tilt_max))
        self.zoom = cam.zoom
        self.head: PanTiltHead | None = None
        self.lock = threading.Lock()
        #: an operation the head owes before its next one (a coded survey's zoom back to the
        #: survey zoom after its refinement, done only when the head is needed again)
        self.before_next: Callable[[PanTiltHead], object] | None = None

    def _reopen(self) -> None:
        old, self.head = self.head, None
        close = getattr(old, "close", None)
        if callable(close):
            try:
                close()
            except Exception:  # noqa: BLE001 - a broken link may fail to close; we are replacing it
                pass
        head = self.open_head()
        # an owed operation (the coded survey's zoom back) stays owed: it still runs, and is
        # priced, before the next operation (a resumed survey opens its heads anew)
        try:
            head.set_zoom(self.zoom)  # the zoom the intrinsics were calibrated at
        except BaseException:
            close = getattr(head, "close", None)
            if callable(close):
                close()
            raise
        self.head = head

    def call(self, op: Callable[[PanTiltHead], object]) -> object:
        """Run one head operation with retries (``retry.head_attempts``, linear back-off), then reconnects."""
        retry = self.retry
        self.locator.resting_at = None  # the locator sets it again after its own operations

        def try_op(_attempt: int) -> object:
            try:
                if self.before_next is not None:
                    self.before_next(self.head)  # type: ignore[arg-type]
                    self.before_next = None
                return op(self.head)  # type: ignore[arg-type]
            except Exception:
                self.stats.head_errors += 1
                raise

        # any driver error is retried on this head; a ConnectionError goes straight to a reconnect
        on_head = RetryPolicy(retry.head_attempts, lambda exc: not isinstance(exc, ConnectionError),
                              linear(retry.backoff_s))

        def round_(n: int) -> object:
            if n > 0 or self.head is None:
                self._reopen()  # any driver failure to open is retried like a failed operation
            return on_head.call(try_op)

        def reconnecting(_failures: int, exc: BaseException) -> None:
            self.stats.reconnects += 1
            logger.warning(f"{self.camera_id}: reconnecting after: {exc}")

        try:
            return RetryPolicy(retry.reconnects + 1, Exception, retry.backoff_s).call(round_, reconnecting)
        except Exception as exc:  # noqa: BLE001 - drivers raise their own error types
            raise CameraFailed(f"{type(exc).__name__}: {exc}") from exc

    def measure(self, node: str, indices: list[int], start: tuple[float, float] | None,
                record: Callable[[int, float, float], None],
                blink: Callable[[Callable[[], object]], tuple] | None = None,
                ignore: Sequence[np.ndarray] = ()) -> str | None:
        """Take the readings ``indices`` of the lit node, handing each to ``record(index, pan, tilt)``
        the moment it is taken; returns None, or the reason the camera gave up. ``blink`` grabs
        an (LED-on, LED-off) frame pair for on-off detection; ``ignore``: bearings of other lit
        LEDs (:attr:`~fgloc.camera.led_search.LedLocator.ignore`)."""
        self.locator.blink = blink  # type: ignore[assignment]
        self.locator.ignore = list(ignore)
        try:
            for k, index in enumerate(indices):
                if k:
                    self.locator.resting_at = None  # a repeat points the head anew: its own settle
                found = self.locator.locate(self.call, start or self.home)
                if found is None:
                    return "not in view anywhere in the search pattern"
                record(index, found[0], found[1])
                start = found
        except CameraFailed as exc:
            return f"camera error: {exc}"
        finally:
            self.locator.ignore = []
        return None

    def close(self) -> None:
        close = getattr(self.head, "close", None)
        if callable(close):
            close()


class SurveyRunner:
    """Drives a rig through a survey, appending everything to a journal."""

    def __init__(
        self,
        rig: RigConfig,
        open_head: Callable[[str], PanTiltHead],
        leds: LedController,
        journal: JournalWriter,
        state: JournalState,
        estimator: Estimator | None = None,
        live_every: int = 1,
        on_estimate: Callable[[LiveEstimate], None] | None = None,
        on_progress: Callable[[Progress], None] | None = None,
        clock: SequentialClock | None = None,
    ) -> None:
        """``clock`` prices each node on the survey clock (its ``open_head`` and ``leds`` must be
        the ones passed here); the coded survey prices itself and passes none."""
        if state.header.camera_ids != rig.camera_ids or state.header.node_ids != rig.node_ids:
            raise FglocError(f"{journal.path}: header: cameras or node ids differ from {rig.path}")
        self.rig = rig
        self.leds = leds
        self.journal = journal
        self.state = state
        self.estimator = estimator
        self.live_every = max(1, live_every)
        self.on_estimate = on_estimate
        self.on_progress = on_progress
        self.stats = RunnerStats()
        self.workers = {c: CameraWorker(c, functools.partial(open_head, c), rig, self.stats) for c in rig.camera_ids}
        self.latest: LiveEstimate | None = None
        self._state_lock = threading.Lock()
        self._led_lock = threading.Lock()
        self._node_seconds: list[float] = []
        self.misses: dict[str, int] = {c: 0 for c in rig.camera_ids}  # consecutive not_found per camera
        self._last_miss: dict[str, str] = {}
        self.clock = clock
        self.field_time: FieldTime | None = None  # predicted field time (survey clock), set at the end

    # -- journal helpers: every record also updates the in-memory state the same way replay would
    def _record_observation(self, obs: JournalObservation) -> None:
        """Journal one reading at once (called from the camera threads)."""
        with self._state_lock:
            self.journal.observation(obs)
            self.state.add_observation(obs)
            self.stats.observations += 1

    def _set_led(self, node: str, on: bool) -> bool:
        def attempt(_n: int) -> bool:
            try:
                confirmed = self.leds.set_led(node, on)
            except Exception as exc:  # noqa: BLE001 - base-station driver errors are retried
                logger.warning(f"{node}: LED {'on' if on else 'off'} failed: {exc}")
                confirmed = False
            if not confirmed:
                self.stats.led_retries += 1
                raise _LedNotConfirmed(node)
            return True

        policy = RetryPolicy(self.rig.retry.led_attempts, _LedNotConfirmed, linear(self.rig.retry.backoff_s))
        try:
            return policy.call(attempt)
        except _LedNotConfirmed:
            return False

    def _blink(self, nodes: Sequence[str], grab: Callable[[], object]) -> tuple[object, object]:
        """(LED-on, LED-off) frames of one camera with ``nodes`` lit; cameras take turns so no frame sees a blink."""
        with self._led_lock:
            try:
                for node in nodes:
                    self._set_led(node, False)
                off = grab()
            finally:
                for node in nodes:
                    self._set_led(node, True)
            return grab(), off

    def look_with_all_lit(self, nodes: Sequence[str], pool: ThreadPoolExecutor,
                          start_at: Mapping[str, tuple[float, float] | None]) -> tuple[list[str], set[str]]:
        """Light every node of ``nodes`` at once, let each camera of ``start_at`` search its pattern
        once (from ``start_at[camera]``; None: its previous reading's place) recording nothing,
        then switch them off. Returns the nodes whose LED confirmed and the cameras that saw
        light: a camera that saw none has none of the lit nodes in view anywhere in its pattern.
        Journals nothing (but an LED that does not go off)."""
        lit: list[str] = []
        seen: set[str] = set()
        try:
            lit = [node for node in nodes if self._set_led(node, True)]
            if lit:
                if self.rig.search.led_wait_s > 0:
                    time.sleep(self.rig.search.led_wait_s)
                blink = (lambda grab: self._blink(lit, grab)) if self.rig.search.detection == "on-off" else None

                def saw(cam: str) -> Callable[[int, float, float], None]:
                    return lambda _index, _pan, _tilt: seen.add(cam)

                pending = {cam: pool.submit(self.workers[cam].measure, lit[0], [0], start or self._start_for(cam),
                                              saw(cam), blink)
                           for cam, start in start_at.items()}
                for cam, future in pending.items():
                    reason = future.result()
                    if reason is not None and reason.startswith("camera error"):
                        seen.add(cam)  # no answer is not an absence: the nodes are searched one by one
        finally:
            for node in lit:
                self.switch_off(node)
        return lit, seen

    def switch_off(self, node: str) -> None:
        """Switch the node's LED off; a node that does not acknowledge is journaled ``led_off_failed``."""
        if not self._set_led(node, False):
            self.journal.append({"type": "led_off_failed", "node": node})
            logger.warning(f"{node}: LED did not acknowledge switching off")

    def _start_for(self, camera: str) -> tuple[float, float] | None:
        last = self.state.last_observation(camera)
        return None if last is None else (last.pan, last.tilt)

    def run_node(self, node: str, pool: ThreadPoolExecutor, check_misses: bool = True,
                 start_at: Mapping[str, tuple[float, float]] | None = None) -> None:
        """Measure one node with every camera that still needs it (``check_misses``: apply
        ``retry.max_consecutive_misses``; off for a coded survey's fallback nodes). A camera's
        search starts at its previous reading, or at ``start_at[camera]`` (pan, tilt) when given."""
        self.run_together({cam: node for cam in self.rig.camera_ids}, pool, start_at)
        if check_misses:
            self._check_misses(node)

    def run_together(self, searches: Mapping[str, str], pool: ThreadPoolExecutor,
                     start_at: Mapping[str, tuple[float, float]] | None = None) -> None:
        """Measure each camera's node of ``searches`` (camera -> the node it searches; the same
        node for every camera is :meth:`run_node`) with all of them lit at once, the cameras in
        parallel. A camera searching its node while another node is lit masks that node's light
        where it read it (:attr:`~fgloc.camera.led_search.LedLocator.ignore`), and on-off
        detection blinks only the camera's own node: the caller lights together only nodes the
        camera read, far from where it looks for its own (:mod:`fgloc.survey.coded_fallback`).
        Each node is journaled started, its readings or ``not_found``, then ``node_done``. A node
        started and not done that is not in ``searches`` (a partner lit when the survey was
        killed) is switched off first, so its light never meets another node's search."""
        st = self.state
        nodes = list(dict.fromkeys(searches.values()))
        for node in [n for n in st.started if n not in st.done and n not in nodes and n not in st.led_failed]:
            self.switch_off(node)  # lit when the survey was killed mid-batch (a pair's partner): dark first
        lit: list[str] = []
        for node in nodes:
            if node not in st.started:
                self.journal.node_started(node)
                st.started.append(node)
            if node in st.led_failed:
                continue
            if self._set_led(node, True):
                lit.append(node)
                continue
            led_reason = f"no acknowledgement after {self.rig.retry.led_attempts} attempts"
            self.journal.led_failed(node, led_reason)
            st.led_failed[node] = led_reason
            self.stats.led_failed += 1
            logger.warning(f"{node}: LED failed: {led_reason}")
        if lit:
            if self.rig.search.led_wait_s > 0:
                time.sleep(self.rig.search.led_wait_s)
            jobs = []  # decided before any camera starts recording into the state
            for cam, node in searches.items():
                if node not in lit or st.camera_finished(node, cam, self.rig.repeats):
                    continue
                have = {o.index for o in st.observations_of(node, cam)}
                indices = [k for k in range(self.rig.repeats) if k not in have]
                ignore = [pan_tilt_bearing(o.pan, o.tilt) for other in lit if other != node
                          for o in st.observations_of(other, cam)]
                jobs.append((cam, node, indices, (start_at or {}).get(cam) or self._start_for(cam), ignore))

            def recorder(cam: str, node: str) -> Callable[[int, float, float], None]:
                return lambda index, pan, tilt: self._record_observation(JournalObservation(node, cam, index, pan, tilt))

            def blinker(node: str) -> Callable[[Callable[[], object]], tuple] | None:
                return (lambda grab: self._blink([node], grab)) if self.rig.search.detection == "on-off" else None

            pending = {
                (cam, node): pool.submit(self.workers[cam].measure, node, indices, start, recorder(cam, node),
                                         blinker(node), ignore)
                for cam, node, indices, start, ignore in jobs
            }
            for (cam, node), future in pending.items():
                reason = future.result()
                self.misses[cam] = 0 if reason is None else self.misses[cam] + 1
                if reason is not None:
                    self._last_miss[cam] = reason
                    self.journal.not_found(node, cam, reason)
                    st.not_found[(node, cam)] = reason
                    self.stats.not_found += 1
                    # An occluded pair is an ordinary outcome; a camera that kept failing is not.
                    level = logging.WARNING if reason.startswith("camera error") else logging.INFO
                    logger.log(level, f"{node}: not found by {cam}: {reason}")
            for node in lit:
                self.switch_off(node)
        for node in nodes:
            self.journal.node_done(node)
            st.done.add(node)

    def _check_misses(self, node: str) -> None:
        """Stop the survey when a camera reached ``retry.max_consecutive_misses`` misses in a row."""
        limit = self.rig.retry.max_consecutive_misses
        for cam in self.rig.camera_ids:
            if limit and self.misses[cam] >= limit:
                reason = self._last_miss.get(cam, "")
                self.journal.append({"type": "survey_stopped", "camera": cam, "misses": self.misses[cam],
                                     "reason": reason})
                short = " ".join(reason.split())
                short = short if len(short) <= 120 else short[:117] + "..."
                raise SurveyStopped(
                    f"{self.rig.path}: retry.max_consecutive_misses: camera {cam} found nothing for "
                    f"{self.misses[cam]} nodes in a row (last: {short}); survey stopped after node {node}, "
                    "journal kept: fix the camera, then run again with --resume")

    def estimate(self, nodes_done: int | None = None) -> LiveEstimate | None:
        """Solve the journal so far (None until MIN_SHARED_NODES nodes are seen by two cameras);
        ``nodes_done`` is what the estimate reports as done (default: nodes with ``node_done``)."""
        if self.estimator is None or self.state.nodes_seen_by(2) < MIN_SHARED_NODES:
            return None
        with self._state_lock:  # camera threads of a coded survey may be recording
            survey = journal_to_survey(self.state)
        t0 = time.perf_counter()
        try:
            result = self.estimator.update(survey)
        except Exception as exc:  # noqa: BLE001 - a live estimate is advisory; the survey must go on
            message = " ".join(str(exc).split())  # GTSAM's messages span lines
            self.stats.estimate_errors.append(message)
            logger.warning(f"live estimate failed: {message[:200]}")
            return None
        if result is None:
            return None
        live = LiveEstimate(len(self.state.done) if nodes_done is None else nodes_done, survey, result,
                            time.perf_counter() - t0)
        self.latest = live
        self.stats.estimates += 1
        if self.on_estimate is not None:
            self.on_estimate(live)
        return live

    def progress(self) -> Progress:
        remaining = sum(1 for n in self.rig.node_ids if n not in self.state.done)
        eta = None
        if self._node_seconds:
            recent = self._node_seconds[-20:]
            eta = remaining * sum(recent) / len(recent)
        failures = len(self.state.not_found) + len(self.state.led_failed)
        field_s = self.priced().total if self.clock is not None else None
        return Progress(len(self.state.done), len(self.rig.node_ids), len(self.state.observations), failures, eta,
                        field_s)

    def priced(self) -> FieldTime:
        """Predicted field time of the nodes and repeat phase journaled so far (this run and earlier ones)."""
        from fgloc.survey.clock import FieldTime, sum_times

        return sum_times(FieldTime(r["phases"]) for r in self.state.field_times if r.get("scope") in ("node", "repeats"))

    def _priced_node(self, node: str, pool: ThreadPoolExecutor) -> None:
        """:meth:`run_node`, priced on the survey clock when there is one."""
        if self.clock is None:
            self.run_node(node, pool)
            return
        self.clock.begin()
        try:
            self.run_node(node, pool)
        finally:
            cost = self.clock.end()
            if node in self.state.done:
                self._journal_field_time("node", dict(cost.phases), node)

    def _journal_field_time(self, scope: str, phases: dict[str, float], node: str | None = None) -> None:
        self.journal.field_time(scope, phases, node=node)
        rec: dict[str, object] = {"type": "field_time", "scope": scope, "phases": phases}
        if node is not None:
            rec["node"] = node
        self.state.field_times.append(rec)

    def run(self) -> Survey:
        """Survey every node not yet done; returns the survey recorded in the journal."""
        todo = [n for n in self.rig.node_ids if n not in self.state.done]
        self.stats.nodes_skipped = len(self.rig.node_ids) - len(todo)
        if self.on_progress is not None:
            self.on_progress(self.progress())
        try:
            with ThreadPoolExecutor(max_workers=len(self.rig.camera_ids), thread_name_prefix="camera") as pool:
                for k, node in enumerate(todo):
                    t0 = time.perf_counter()
                    try:
                        self._priced_node(node, pool)
                    finally:
                        self.stats.nodes_measured += node in self.state.done
                    self._node_seconds.append(time.perf_counter() - t0)
                    if (k + 1) % self.live_every == 0 or k + 1 == len(todo):
                        self.estimate()
                    if self.on_progress is not None:
                        self.on_progress(self.progress())
                if self.rig.repeat_budget > 0:  # the repeat phase, fgloc.survey.repeats (docs/survey.md)
                    from fgloc.survey.repeats import run_repeats

                    if self.clock is not None:
                        self.clock.begin()
                    took = run_repeats(self, pool)
                    if self.clock is not None:
                        self._journal_field_time("repeats", dict(self.clock.end().phases))
                    if took:
                        self.estimate()
        finally:
            for w in self.workers.values():
                try:
                    w.close()
                except Exception:  # noqa: BLE001 - closing a dead link must not lose the survey
                    pass
        if self.clock is not None:
            self.field_time = self.priced()
            self.journal.field_time("survey", dict(self.field_time.phases))
        return journal_to_survey(self.state)


def format_progress(p: Progress, width: int = 24) -> str:
    """One progress line: a bar, nodes done, observations, failures and time left."""
    frac = p.nodes_done / p.nodes_total if p.nodes_total else 1.0
    filled = int(round(frac * width))
    eta = "--:--" if p.eta_s is None else f"{int(p.eta_s // 60):02d}:{int(p.eta_s % 60):02d}"
    return (f"[{'#' * filled}{'.' * (width - filled)}] {p.nodes_done}/{p.nodes_total} nodes  "
            f"{p.observations} obs  {p.failures} failed  left {eta}")
