"""Append-only survey journal (JSON Lines) that survives being killed at any moment.

A journal is the primary record of a survey; ``survey.json`` is derived from it
(:func:`journal_to_survey`). Each line is one JSON object with a ``"type"``
(docs/file-format.md; header, observation and truth records are checked against
``schemas/journal.schema.json``):

* ``header`` (first line, exactly once): ``format``, ``version``, the survey's
  ``nodes`` mode, ``gauge``, ``sigma`` (radians), ``camera_ids``, ``node_ids``,
  ``rig_hash`` (sha256 of the rig configuration), free-form ``meta`` and, from
  surveys run by ``fgloc survey``, ``rig_meaning`` and ``rig_operational`` (the rig.json
  fields that fix what the readings mean, and the others with URL user info redacted);
  from coded surveys, ``coded``: the levers the survey started with (a resume runs with them).
* ``node_started`` ``{node}``: the node's LED is about to be lit.
* ``observation`` ``{node, camera, index, pan, tilt[, sigma]}``: one reading in
  radians (spec convention). ``(node, camera, index)`` is its identity:
  ``index`` counts a camera's readings of that node from 0.
* ``not_found`` ``{node, camera, reason}``: the camera gave up on the node.
* ``led_failed`` ``{node, reason}``: the node never acknowledged the LED command.
* ``node_done`` ``{node}``: every camera has a final outcome for the node.
* ``truth`` ``{cameras, nodes}``: ground truth of a simulated survey (gauge frame).
* ``rig_changed`` ``{rig_hash, changed, rig_operational}``: a resume accepted a rig.json
  whose operational fields differ (``changed`` names them); later resumes compare with it.
* ``survey_stopped`` ``{camera, misses, reason}``: a camera found nothing for too many
  nodes in a row and the run stopped (informational; a resume continues).
* ``view`` ``{camera, view, attempt, target, head, frames, erased, clock_s, readings,
  refused}`` (coded surveys, :mod:`fgloc.survey.coded`): one recording of one view and
  **every** reading decoded from it (``readings[]``: ``{node, index, pan, tilt[, sigma,
  code, u, v, partner]}``, the same identity as an ``observation``; lever fields ``zoom``,
  ``continued``, ``probe``, ``round``, ``lit``, docs/file-format.md). The record is the commit of the
  whole view: a kill during a view leaves no record of it, so a resumed survey records the
  view again and never holds half a view. Each reading keeps the view it came from
  (:attr:`JournalObservation.view`).
* ``codes`` ``{action, ...}``: the motes' coded blinking was started or stopped (informational).
* ``field_time`` ``{scope, phases[, node, total_s]}``: predicted field time per phase
  (seconds, :mod:`fgloc.survey.clock`) of one fallback node or of the whole survey.

Every record is written with one ``os.write`` of a complete line, then
``os.fsync``. A torn last line (power loss or kill mid-write) has no trailing
newline: readers ignore it and writers truncate it before appending, so earlier
records are never lost. Replay is idempotent: a repeated observation key, a
repeated ``not_found`` or ``node_done`` is ignored, so a survey killed between
recording an observation and marking its node done resumes without loss or
duplication. All records also carry ``t``, the wall-clock time (Unix seconds).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fgloc.core.errors import FglocError
from fgloc.core.model import Gauge, NodeMode, Observation, Survey, Truth
from fgloc.files.json_io import Bulk, check, field_name, find_nonfinite, is_number, is_vector3, parse_json, show_value
from fgloc.files.survey_result import truth_from_json

JOURNAL_FORMAT = "fgloc-journal"
JOURNAL_VERSION = 1


class JournalError(FglocError):
    """A journal that cannot be read or appended to as asked."""


@dataclass(frozen=True)
class JournalHeader:
    """Survey metadata recorded once at the top of a journal. ``sigma`` in radians."""

    mode: NodeMode
    gauge: Gauge
    sigma: float
    camera_ids: list[str]
    node_ids: list[str]
    rig_hash: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    rig_meaning: dict[str, Any] | None = None
    rig_operational: dict[str, Any] | None = None
    #: coded surveys: the levers the survey started with (``retry``, ``separate``, ``fallback``,
    #: ``video``, ``probe``, ``pairs``, ``levels``; :mod:`fgloc.survey.coded_levers`); None in
    #: sequential surveys and in journals written before levers were recorded
    coded: dict[str, Any] | None = None

    def to_record(self) -> dict[str, Any]:
        rig = {k: v for k, v in (("rig_meaning", self.rig_meaning), ("rig_operational", self.rig_operational),
                                 ("coded", self.coded)) if v is not None}
        return {
            "type": "header",
            "format": JOURNAL_FORMAT,
            "version": JOURNAL_VERSION,
            "nodes": self.mode.value,
            "gauge": {"origin": self.gauge.origin, "baseline": self.gauge.baseline},
            "sigma": self.sigma,
            "camera_ids": list(self.camera_ids),
            "node_ids": list(self.node_ids),
            "rig_hash": self.rig_hash,
            "meta": self.meta,
        } | rig


ObservationKey = tuple[str, str, int]  # (node, camera, index)


@dataclass(frozen=True)
class JournalObservation:
    """An observation with its identity within the survey."""

    node: str
    camera: str
    index: int
    pan: float
    tilt: float
    sigma: float | None = None
    view: str | None = None  #: coded surveys: id (in the camera's plan) of the view the reading was decoded in
    #: coded surveys with a head repeatability: the view's shared head sigma (radians, part of ``sigma``)
    view_sigma: float | None = None
    view_pan: float | None = None  #: radians, the head pan the view was read at (with ``view_sigma``)
    zoom: float | None = None  #: coded surveys: zoom of the view's recording (fraction of the optical range)
    view_tilt: float | None = None  #: coded surveys: radians, the head tilt the view was read at (off-centre reading)

    @property
    def key(self) -> ObservationKey:
        return (self.node, self.camera, self.index)

    def to_observation(self) -> Observation:
        """The survey reading; with ``view_sigma`` it names its view ``camera/view`` (unique
        across cameras) with that shared sigma and head pan (survey.json ``views``)."""
        shared = self.view is not None and self.view_sigma is not None
        return Observation(camera=self.camera, node=self.node, pan=self.pan, tilt=self.tilt, sigma=self.sigma,
                           view=f"{self.camera}/{self.view}" if shared else None,
                           view_sigma=self.view_sigma if shared else None,
                           view_pan=self.view_pan if shared or self.view_tilt is not None else None, zoom=self.zoom,
                           view_tilt=self.view_tilt)


@dataclass
class JournalState:
    """Everything a journal says, replayed idempotently (first record of a key wins)."""

    header: JournalHeader
    observations: dict[ObservationKey, JournalObservation] = field(default_factory=dict)
    started: list[str] = field(default_factory=list)  # nodes in order first started
    done: set[str] = field(default_factory=set)
    led_failed: dict[str, str] = field(default_factory=dict)
    not_found: dict[tuple[str, str], str] = field(default_factory=dict)  # (node, camera) -> reason
    truth: Truth | None = None
    rig_changes: list[dict[str, Any]] = field(default_factory=list)  # rig_changed records, in order
    views: dict[tuple[str, str, int], dict[str, Any]] = field(default_factory=dict)  # (camera, view, attempt) -> record
    field_times: list[dict[str, Any]] = field(default_factory=list)  # field_time records, in order
    codes: list[dict[str, Any]] = field(default_factory=list)  # codes records (coded surveys), in order
    records: int = 0
    torn_tail_bytes: int = 0
    duplicates_ignored: int = 0
    # Indexes kept by add_observation (constant-time lookups for long surveys).
    _by_pair: dict[tuple[str, str], list[JournalObservation]] = field(default_factory=dict, repr=False)
    _last: dict[str, JournalObservation] = field(default_factory=dict, repr=False)
    _cameras_of: dict[str, set[str]] = field(default_factory=dict, repr=False)

    def add_observation(self, obs: JournalObservation) -> bool:
        """Record a reading unless its key is known (replay is idempotent); True when added."""
        if obs.key in self.observations:
            self.duplicates_ignored += 1
            return False
        self.observations[obs.key] = obs
        self._by_pair.setdefault((obs.node, obs.camera), []).append(obs)
        self._last[obs.camera] = obs
        self._cameras_of.setdefault(obs.node, set()).add(obs.camera)
        return True

    def observations_of(self, node: str, camera: str) -> list[JournalObservation]:
        """This camera's readings of this node, by index."""
        return sorted(self._by_pair.get((node, camera), []), key=lambda o: o.index)

    def nodes_seen_by(self, n_cameras: int) -> int:
        """How many nodes have readings from at least ``n_cameras`` cameras."""
        return sum(1 for cams in self._cameras_of.values() if len(cams) >= n_cameras)

    def camera_finished(self, node: str, camera: str, repeats: int) -> bool:
        """True when the camera has a final outcome for the node (all readings or gave up)."""
        return (node, camera) in self.not_found or len(self.observations_of(node, camera)) >= repeats

    @property
    def rig_hash(self) -> str:
        """The rig hash the survey runs with now: the last ``rig_changed``'s, else the header's."""
        return str(self.rig_changes[-1]["rig_hash"]) if self.rig_changes else self.header.rig_hash

    @property
    def rig_operational(self) -> dict[str, Any] | None:
        """The operational rig fields in force now (last ``rig_changed``, else the header's)."""
        return self.rig_changes[-1]["rig_operational"] if self.rig_changes else self.header.rig_operational

    def last_observation(self, camera: str) -> JournalObservation | None:
        """The camera's most recent reading in journal order (None before the first)."""
        return self._last.get(camera)

    def ordered_observations(self) -> list[JournalObservation]:
        """Canonical order: node as in ``node_ids``, then camera as in ``camera_ids``, then index.

        Independent of thread timing and of how often the survey was resumed.
        """
        node_rank = {n: i for i, n in enumerate(self.header.node_ids)}
        cam_rank = {c: i for i, c in enumerate(self.header.camera_ids)}
        return sorted(self.observations.values(), key=lambda o: (node_rank[o.node], cam_rank[o.camera], o.index))


def rig_hash(config: Any) -> str:
    """sha256 of a JSON-serializable configuration in canonical form (sorted keys)."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


_TILT_LIMIT = 1.5707963277948966  # pi/2 + 1e-9, as survey.schema.json's observation tilt


def _plain_observation(rec: dict) -> bool:
    """Pre-accepts the common observation record; never laxer than ``$defs/observation``."""
    index, tilt, node, camera = rec.get("index"), rec.get("tilt"), rec.get("node"), rec.get("camera")
    return (type(index) is int and index >= 0 and is_number(rec.get("pan")) and is_number(tilt)
            and -_TILT_LIMIT <= tilt <= _TILT_LIMIT  # type: ignore[operator]
            and type(node) is str and node != "" and type(camera) is str and camera != ""
            and "sigma" not in rec)


_TRUTH_BULK: Bulk = {("nodes",): is_vector3}
_CHECKED = ("header", "observation", "truth", "rig_changed", "view", "field_time")  # record types with a definition in journal.schema.json
_NODE_RECORDS = ("node_started", "observation", "not_found", "led_failed", "node_done")


class _Replay:
    """Applies checked records to a :class:`JournalState`, naming ``file: line N`` on errors."""

    def __init__(self, path: str, header: JournalHeader) -> None:
        self.path = path
        self.state = JournalState(header=header)
        self.cams, self.nodes = set(header.camera_ids), set(header.node_ids)
        self.started: set[str] = set()

    def fail(self, line: int, problem: str) -> JournalError:
        return JournalError(f"{self.path}: line {line}: {problem}")

    def apply(self, rec: dict, line: int) -> None:
        state, kind = self.state, rec.get("type")
        node: Any = rec.get("node")
        if kind == "header":
            raise self.fail(line, "a second header record")
        if kind in _CHECKED and not (kind == "observation" and _plain_observation(rec)):
            check(rec, "journal", f"{self.path}: line {line}", JournalError, definition=str(kind), root=str(kind),
                  bulk=_TRUTH_BULK if kind == "truth" else None)
        if kind in _NODE_RECORDS and (type(node) is not str or node not in self.nodes):
            raise self.fail(line, f"{kind}.node: unknown node {show_value(node)}")
        camera: Any = rec.get("camera")
        if kind in ("observation", "not_found") and (type(camera) is not str or camera not in self.cams):
            raise self.fail(line, f"{kind}.camera: unknown camera {show_value(camera)}")
        if kind == "node_started":
            if node not in self.started:
                self.started.add(node)
                state.started.append(node)
        elif kind == "observation":
            sigma = rec.get("sigma")
            state.add_observation(JournalObservation(node, rec["camera"], int(rec["index"]), float(rec["pan"]),
                                                     float(rec["tilt"]), None if sigma is None else float(sigma)))
        elif kind == "not_found":
            state.not_found.setdefault((node, rec["camera"]), str(rec.get("reason", "")))
        elif kind == "led_failed":
            state.led_failed.setdefault(node, str(rec.get("reason", "")))
        elif kind == "node_done":
            state.done.add(node)
        elif kind == "rig_changed":
            state.rig_changes.append(rec)
        elif kind == "view":
            self.apply_view(rec, line)
        elif kind == "codes":
            state.codes.append(rec)
        elif kind == "field_time":
            if rec.get("node") is not None and rec["node"] not in self.nodes:
                raise self.fail(line, f"field_time.node: unknown node {show_value(rec['node'])}")
            state.field_times.append(rec)
        elif kind == "truth":
            state.truth = truth_from_json(rec, state.header.mode.value, self.cams, self.nodes,
                                          f"{self.path}: line {line}", JournalError)
        # Unknown record types are ignored (forward compatibility), like unknown fields.


    def apply_view(self, rec: dict, line: int) -> None:
        """A complete view: its readings become observations (first record of a key wins)."""
        camera = rec["camera"]
        if camera not in self.cams:
            raise self.fail(line, f"view.camera: unknown camera {show_value(camera)}")
        for i, r in enumerate(rec["readings"]):
            if r["node"] not in self.nodes:
                raise self.fail(line, f"view.readings[{i}].node: unknown node {show_value(r['node'])}")
        key = (camera, str(rec["view"]), int(rec["attempt"]))
        if key in self.state.views:
            self.state.duplicates_ignored += 1
            return
        self.state.views[key] = rec
        for r in rec["readings"]:
            self.state.add_observation(view_observation(camera, str(rec["view"]), r, _head_pan(rec), _zoom(rec),
                                                        _head_tilt(rec)))


def _head_pan(record: dict[str, Any]) -> float | None:
    """The read-back head pan (radians) of a ``view`` record, None without one."""
    head = record.get("head")
    return float(head[0]) if isinstance(head, list) and head else None


def _head_tilt(record: dict[str, Any]) -> float | None:
    """The read-back head tilt (radians) of a ``view`` record, None without one."""
    head = record.get("head")
    return float(head[1]) if isinstance(head, list) and len(head) > 1 else None


def _zoom(record: dict[str, Any]) -> float | None:
    """The zoom (fraction of the optical range) of a ``view`` record, None without one."""
    zoom = record.get("zoom")
    return None if zoom is None else float(zoom)


def view_observation(camera: str, view: str, reading: dict[str, Any],
                     head_pan: float | None = None, zoom: float | None = None,
                     head_tilt: float | None = None) -> JournalObservation:
    """The observation a ``view`` record's reading stands for (the reading keeps its view id;
    with a ``view_sigma`` also that shared sigma and the view's read-back ``head_pan``; the
    recording's ``zoom``, the head model's zoom group of the reading; with ``head_tilt`` the
    view's read-back angles (``view_pan``, ``view_tilt``) the off-centre reading was composed at)."""
    sigma, shared = reading.get("sigma"), reading.get("view_sigma")
    angles = head_pan is not None and head_tilt is not None
    return JournalObservation(reading["node"], camera, int(reading["index"]), float(reading["pan"]),
                              float(reading["tilt"]), None if sigma is None else float(sigma), view,
                              None if shared is None else float(shared),
                              None if (shared is None and not angles) or head_pan is None else float(head_pan), zoom,
                              float(head_tilt) if angles and head_tilt is not None else None)


def _header(rec: dict, path: str, line: int) -> JournalHeader:
    """The header record, checked against ``$defs/header`` (format and version first)."""
    where = f"{path}: line {line}"
    if rec.get("type") != "header":
        raise JournalError(f"{where}: first record must be the header, got type {rec.get('type')!r}")
    if rec.get("format") != JOURNAL_FORMAT:
        raise JournalError(f"{where}: format: expected {JOURNAL_FORMAT!r}, got {rec.get('format')!r}")
    if isinstance(rec.get("version"), bool) or rec.get("version") != JOURNAL_VERSION:
        raise JournalError(f"{where}: version: unsupported {rec.get('version')!r}")
    check(rec, "journal", where, JournalError, definition="header", root="header")
    # What survey.json's reader checks after its schema, so that the survey recorded here reads back.
    for name in ("camera_ids", "node_ids"):
        seen: set[str] = set()
        for i, v in enumerate(rec[name]):
            if v in seen:
                raise JournalError(f"{where}: header.{name}[{i}]: duplicate id {show_value(v)}")
            seen.add(v)
    gauge = rec["gauge"]
    for role in ("origin", "baseline"):
        if gauge[role] not in rec["camera_ids"]:
            raise JournalError(f"{where}: header.gauge.{role}: camera {show_value(gauge[role])} is not in camera_ids")
    if gauge["origin"] == gauge["baseline"]:
        raise JournalError(f"{where}: header.gauge.baseline: must differ from gauge.origin, "
                           f"both are {show_value(gauge['origin'])}")
    bad = find_nonfinite(rec.get("meta"))
    if bad is not None:
        raise JournalError(f"{where}: {field_name(bad, 'header.meta')}: expected a finite number")
    return JournalHeader(NodeMode(rec["nodes"]), Gauge(origin=rec["gauge"]["origin"], baseline=rec["gauge"]["baseline"]),
                         float(rec["sigma"]), list(rec["camera_ids"]), list(rec["node_ids"]),
                         str(rec.get("rig_hash", "")), dict(rec.get("meta") or {}), rec.get("rig_meaning"),
                         rec.get("rig_operational"), rec.get("coded"))


def _split_complete(data: bytes) -> tuple[list[bytes], int]:
    """Complete lines and the length in bytes of the torn tail (no trailing newline)."""
    end = data.rfind(b"\n") + 1
    return data[:end].splitlines(), len(data) - end


def read_journal(path: str | os.PathLike[str]) -> JournalState:
    """Replay a journal. A torn last line is ignored; any other bad line is a :class:`JournalError`."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise JournalError(f"{path}: file not found") from None
    except OSError as exc:
        raise JournalError(f"{path}: cannot read: {exc.strerror or exc}") from None
    lines, torn = _split_complete(data)
    replay: _Replay | None = None
    for number, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        try:
            rec = parse_json(raw)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise JournalError(f"{path}: line {number}: not valid JSON ({exc})") from None
        if not isinstance(rec, dict):
            raise JournalError(f"{path}: line {number}: record is not a JSON object")
        if replay is None:
            replay = _Replay(str(path), _header(rec, str(path), number))
        else:
            replay.apply(rec, number)
        replay.state.records += 1
    if replay is None:
        raise JournalError(f"{path}: no complete header record (empty or torn journal)")
    state = replay.state
    state.torn_tail_bytes = torn
    return state


def journal_to_survey(state: JournalState) -> Survey:
    """The survey a journal records: every distinct observation, in canonical order, plus truth."""
    h = state.header
    return Survey(
        mode=h.mode,
        gauge=h.gauge,
        sigma=h.sigma,
        camera_ids=list(h.camera_ids),
        node_ids=list(h.node_ids),
        observations=[o.to_observation() for o in state.ordered_observations()],
        truth=state.truth,
    )


class JournalWriter:
    """Appends records durably; thread-safe (camera threads share one writer).

    Open with :meth:`create` for a new survey or :meth:`open_existing` to resume.
    """

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self._fd = fd
        self._lock = threading.Lock()

    @classmethod
    def create(cls, path: str | os.PathLike[str], header: JournalHeader) -> JournalWriter:
        """Start a new journal; refuses to overwrite one that holds a header."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists() and p.stat().st_size > 0:
            try:
                read_journal(p)
            except JournalError:
                pass  # torn or garbage-only header from a kill during creation: start over
            else:
                raise JournalError(f"{p}: journal already exists (use --resume to continue it)")
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
        writer = cls(p, fd)
        writer.append(header.to_record())
        dir_fd = os.open(p.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
        return writer

    @classmethod
    def open_existing(cls, path: str | os.PathLike[str]) -> tuple[JournalWriter, JournalState]:
        """Replay a journal and open it for appending, cutting off a torn last line first."""
        p = Path(path)
        state = read_journal(p)
        fd = os.open(p, os.O_WRONLY | os.O_APPEND)
        if state.torn_tail_bytes:
            os.ftruncate(fd, p.stat().st_size - state.torn_tail_bytes)
            os.fsync(fd)
        return cls(p, fd), state

    def append(self, record: dict[str, Any]) -> None:
        """Write one record as a complete line, then fsync."""
        rec = {"t": round(time.time(), 3)} | record
        line = (json.dumps(rec, allow_nan=False, separators=(",", ":")) + "\n").encode("utf-8")
        with self._lock:
            view = memoryview(line)
            while view:
                written = os.write(self._fd, view)
                view = view[written:]
            os.fsync(self._fd)

    def node_started(self, node: str) -> None:
        self.append({"type": "node_started", "node": node})

    def observation(self, obs: JournalObservation) -> None:
        rec: dict[str, Any] = {"type": "observation", "node": obs.node, "camera": obs.camera,
                               "index": obs.index, "pan": obs.pan, "tilt": obs.tilt}
        if obs.sigma is not None:
            rec["sigma"] = obs.sigma
        self.append(rec)

    def not_found(self, node: str, camera: str, reason: str) -> None:
        self.append({"type": "not_found", "node": node, "camera": camera, "reason": reason})

    def led_failed(self, node: str, reason: str) -> None:
        self.append({"type": "led_failed", "node": node, "reason": reason})

    def node_done(self, node: str) -> None:
        self.append({"type": "node_done", "node": node})

    def view(self, record: dict[str, Any]) -> None:
        """One recording of a coded view with all its readings, in one durable line (the view's commit)."""
        self.append({"type": "view"} | record)

    def field_time(self, scope: str, phases: dict[str, float], node: str | None = None,
                   nodes: list[str] | None = None) -> None:
        """Predicted field time per phase (seconds) of one node (``node``: a sequential survey's;
        ``fallback_node``: a coded survey's), of a coded survey's motes no camera placed, searched
        lit at once (``fallback_group``), of its fallback ``nodes`` searched one per camera lit
        at once (``fallback_pair``), of the repeat phase (``repeats``) or of the whole survey
        (``survey``)."""
        rec: dict[str, Any] = {"type": "field_time", "scope": scope, "phases": dict(phases),
                               "total_s": float(sum(phases.values()))}
        if node is not None:
            rec["node"] = node
        if nodes is not None:
            rec["nodes"] = list(nodes)
        self.append(rec)

    def rig_changed(self, rig_hash_value: str, changed: list[str], operational: dict[str, Any]) -> None:
        """Record a resume's accepted operational rig.json change (values without credentials)."""
        self.append({"type": "rig_changed", "rig_hash": rig_hash_value, "changed": list(changed),
                     "rig_operational": operational})

    def truth(self, truth: Truth) -> None:
        self.append({
            "type": "truth",
            "cameras": {k: {"position": [float(x) for x in v.position],
                            "rotation": np.asarray(v.rotation, float).tolist()} for k, v in truth.cameras.items()},
            "nodes": {k: [float(x) for x in v] for k, v in truth.nodes.items()},
        })

    def close(self) -> None:
        with self._lock:
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> JournalWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def survey_to_journal(survey: Survey, path: str | os.PathLike[str], rig_hash_value: str = "") -> None:
    """Write a complete survey as a journal (every node started, observed and done).

    With :func:`journal_to_survey` this is the identity on surveys whose
    observations are in canonical order and hold at most one reading per
    (camera, node) index, i.e. the conversion is lossless.
    """
    header = JournalHeader(survey.mode, survey.gauge, survey.sigma, list(survey.camera_ids),
                           list(survey.node_ids), rig_hash_value)
    counts: dict[tuple[str, str], int] = {}
    with JournalWriter.create(path, header) as w:
        if survey.truth is not None:
            w.truth(survey.truth)
        by_node: dict[str, list[Observation]] = {}
        for o in survey.observations:
            by_node.setdefault(o.node, []).append(o)
        for node in survey.node_ids:
            w.node_started(node)
            for o in by_node.get(node, []):
                k = counts.get((o.node, o.camera), 0)
                counts[(o.node, o.camera)] = k + 1
                w.observation(JournalObservation(o.node, o.camera, k, o.pan, o.tilt, o.sigma))
            w.node_done(node)
