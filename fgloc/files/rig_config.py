"""rig.json: the description of a survey rig (cameras, mote base station, nodes, search).

See ``docs/survey.md`` and ``docs/file-format.md`` for the documented format and
``schemas/rig.schema.json`` for its schema. Angles in rig.json are degrees (people
at a rig think in degrees); everything in memory is radians. Every problem is a
:class:`RigConfigError` naming ``file: field: problem (value)``.
"""

from __future__ import annotations

import math
import os
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import SearchConfig
from fgloc.core.errors import FglocError
from fgloc.core.model import Gauge, NodeMode
from fgloc.core.redact import redact_urls
from fgloc.files.camera_file import read_intrinsics
from fgloc.files.journal import rig_hash
from fgloc.files.json_io import check, load_json, show_value
from fgloc.sim.head_errors import parse_head_errors

RIG_FORMAT = "fgloc-rig"
CAMERA_DRIVERS = ("visca-serial", "visca-ip", "sony-cgi", "simulated")
MOTE_DRIVERS = ("tinyos-serial", "serial-forwarder", "simulated")
MOUNTINGS = ("upright", "ceiling")
MEASURE_METHODS = ("centre", "pixel-offset")
DETECTIONS = ("single", "on-off")
SIMULATION_TWINS = ("inprocess", "visca")
SIMULATION_FRAMES = ("spot", "rendered")
#: rig.json names of the head errors (``simulation.head_errors``): fgloc.core.head_model's
#: parameters with their rig.json unit (degrees, percent, baseline units).
HEAD_ERROR_FIELDS: dict[str, str] = {
    "tilt_index_deg": "tilt_index", "collimation_deg": "collimation", "trunnion_deg": "trunnion",
    "pan_scale_percent": "pan_scale", "tilt_scale_percent": "tilt_scale",
    "lever_y_baseline": "lever_y", "lever_z_baseline": "lever_z",
}
IDENTIFICATIONS = ("sequential", "coded")  #: one lit LED at a time, or blink codes (fgloc.survey.coded)


class RigConfigError(FglocError):
    """A rig.json that does not describe a usable rig. The message never shows a URL's user info."""

    def __init__(self, message: str) -> None:
        super().__init__(redact_urls(message))


@dataclass(frozen=True)
class CameraConfig:
    """One pan-tilt camera: how to reach it and how it is mounted.

    ``port`` is a serial device, ``udp://HOST:PORT`` or ``http://HOST`` depending on
    ``driver``; ``zoom`` is the survey zoom fraction (0 widest ... 1 optical tele).
    """

    id: str
    driver: str
    port: str
    model: str
    mounting: str
    intrinsics: CameraIntrinsics
    zoom: float
    address: int = 1
    video: str | None = None  # cv2.VideoCapture source for frames: device index ("0") or stream URL
    reply_port: int | None = None  # visca-ip: fixed controller UDP port the camera replies to (e.g. 52381)
    #: this camera's search box (rig.json ``cameras[].search``: any of pan_min_deg, pan_max_deg,
    #: tilt_min_deg, tilt_max_deg), the rig's ``search`` for the fields it leaves out; None: the rig's
    search: SearchConfig | None = None


@dataclass(frozen=True)
class MotesConfig:
    """The mote base station: driver kind and port (serial device or ``tcp://HOST:PORT``).

    ``addresses`` maps node ids to mote addresses (16-bit); None means the ids are the addresses.
    """

    driver: str
    port: str
    addresses: dict[str, int] | None = None


@dataclass(frozen=True)
class RetryConfig:
    """How hard to try before recording a failure, and when to give up on a camera.

    ``max_consecutive_misses``: a camera that finds nothing (``not_found``) for this many
    lit nodes in a row stops the survey (0 = never stop); see docs/survey.md.
    """

    led_attempts: int = 4
    head_attempts: int = 4
    reconnects: int = 3
    backoff_s: float = 0.05
    max_consecutive_misses: int = 25


@dataclass(frozen=True)
class SimulationConfig:
    """The simulated scene and twin faults used by ``fgloc survey --simulate``.

    Rates are per reply; ``disconnect_after`` is the number of head commands
    after which camera ``disconnect_camera`` drops its link once (0 = never);
    ``time_scale`` multiplies simulated motion and LED latency (0 = instant).
    ``twin`` picks the simulated cameras: ``inprocess`` (protocol-level, fast,
    deterministic) or ``visca`` (the real VISCA serial driver against a pty twin
    per camera; camera ``model`` and ``mounting`` must be known to fgloc.drivers.ptz_units).
    ``frames`` picks what the simulated cameras see, for either twin: ``spot`` (a clean
    Gaussian spot per lit LED on black) or ``rendered`` (the camera pipeline's renderer,
    drivers/rendered_camera.py: textured background, static bright lights, sensor noise).
    ``head_errors`` maps a camera id to its simulated head's errors, a 7-tuple in
    :data:`fgloc.core.head_model.HEAD_PARAMETERS` order and units (radians, unit-less
    scales, survey units); cameras not listed have ideal heads. ``head_zoom_levers`` (rig.json
    ``simulation.head_errors.<cam>.lever_by_zoom``) maps a camera id to zoom -> lever arm
    ``(l_y, l_z)`` (survey units): at a zoom listed the head's optical centre sits there
    instead (:data:`fgloc.sim.head_errors.ZoomLevers`).
    """

    seed: int = 0
    #: seeds the blink video (motes' crystal errors and start phases, frame noise) of a coded
    #: survey apart from the scene; None: the scene's ``seed`` (one scene, several recordings)
    video_seed: int | None = None
    heights: tuple[float, ...] = (0.1, 0.1)
    occlusion: float = 0.0
    dead_nodes: tuple[str, ...] = ()
    drop_rate: float = 0.0
    garble_rate: float = 0.0
    disconnect_after: int = 0
    disconnect_camera: str = ""
    time_scale: float = 0.0
    twin: str = "inprocess"
    frames: str = "spot"
    head_errors: dict[str, tuple[float, ...]] = field(default_factory=dict)
    head_zoom_levers: dict[str, dict[float, tuple[float, float]]] = field(default_factory=dict)


@dataclass(frozen=True)
class RigConfig:
    """A whole rig. ``sigma`` in radians; ``path`` is where it was read from.

    ``head_repeatability`` (radians, rig.json ``head_repeatability_deg``, default 0) is the
    part of ``sigma`` that is the head's pointing repeatability: after each move the head
    settles pointing this far (per axis, standard deviation) from the position it reports.
    Every reading taken from one settle shares that error: a coded survey declares it as
    each view's shared sigma (survey.json ``views``), the simulated in-process heads draw it
    per settle, and the rest of ``sigma``, ``sqrt(sigma^2 - head_repeatability^2)``, is a
    reading's own noise. It must be below ``sigma``.
    """

    path: str
    mode: NodeMode
    sigma: float
    gauge: Gauge
    cameras: list[CameraConfig]
    motes: MotesConfig
    node_ids: list[str]
    repeats: int = 1
    repeat_budget: int = 0  # readings re-measured after the node loop, chosen by fgloc.plan.repeat
    identification: str = "sequential"  # "sequential" or "coded" (blink codes, fgloc.survey.coded)
    search: SearchConfig = SearchConfig()
    retry: RetryConfig = RetryConfig()
    simulation: SimulationConfig = SimulationConfig()
    head_repeatability: float = 0.0
    hash: str = ""
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def search_for(self, camera_id: str) -> SearchConfig:
        """Where and how camera ``camera_id`` searches: its own box where rig.json gives one
        (``cameras[].search``), else the rig's ``search``."""
        cam = self.cameras[self.camera_ids.index(camera_id)]
        return cam.search or self.search


def _fail(path: str, name: str, problem: str) -> RigConfigError:
    return RigConfigError(f"{path}: {name}: {problem}")


def _intrinsics(value: str | dict, name: str, path: str, base: Path) -> CameraIntrinsics:
    """Schema-checked inline ``{fx, fy, cx, cy, width, height[, k1, k2, p1, p2, k3]}`` (pixels) or a camera.json path."""
    if isinstance(value, str):
        ipath = (base / value) if not os.path.isabs(value) else Path(value)
        if not ipath.exists():
            raise _fail(path, name, f"intrinsics file not found: {str(ipath)!r}")
        try:
            return read_intrinsics(ipath)
        except FglocError as exc:
            raise _fail(path, name, str(exc)) from None
    return CameraIntrinsics(
        fx=float(value["fx"]), fy=float(value["fy"]), cx=float(value["cx"]), cy=float(value["cy"]),
        width=int(value["width"]), height=int(value["height"]),
        k1=float(value.get("k1", 0.0)), k2=float(value.get("k2", 0.0)), p1=float(value.get("p1", 0.0)),
        p2=float(value.get("p2", 0.0)), k3=float(value.get("k3", 0.0)),
    )


_PORT_SCHEMES = {"visca-serial": ("", "a serial device path"), "visca-ip": ("udp://", "udp://HOST[:PORT]"),
                 "sony-cgi": ("http", "http://HOST")}


def _head_errors(section: dict[str, Any], ids: list[str], seed: int, path: str) -> dict[str, tuple[float, ...]]:
    """``simulation.head_errors`` (schema-checked): camera id -> ``"typical"`` or ``{name_unit: value}``.

    Parsed by :func:`fgloc.sim.head_errors.parse_head_errors` (the parser of ``fgloc simulate
    --head-errors``): degrees, percent, baseline units in, model units out. ``"typical"``
    draws the typical sizes with random signs, seeded by the rig seed and the camera id.
    """
    out: dict[str, tuple[float, ...]] = {}
    for cid, spec in section.items():
        if cid not in ids:
            raise _fail(path, f"simulation.head_errors.{cid}", f"camera {cid!r} is not in cameras")
        text = spec if isinstance(spec, str) else ",".join(
            f"{HEAD_ERROR_FIELDS[k]}={float(v)!r}" for k, v in spec.items() if k != "lever_by_zoom")
        rng = np.random.default_rng(zlib.crc32(f"{seed}/head-errors/{cid}".encode()))
        try:
            values = parse_head_errors(text, [cid], rng)[cid]
        except FglocError as exc:  # the schema admits only what the parser accepts; kept for safety
            raise _fail(path, f"simulation.head_errors.{cid}", str(exc)) from None
        out[cid] = tuple(float(v) for v in values)
    return out


def _zoom_levers(section: dict[str, Any], path: str) -> dict[str, dict[float, tuple[float, float]]]:
    """``simulation.head_errors.<cam>.lever_by_zoom`` (schema-checked): camera id -> zoom ->
    (l_y, l_z) in baseline units; a zoom listed twice is refused."""
    out: dict[str, dict[float, tuple[float, float]]] = {}
    for cid, spec in section.items():
        if not isinstance(spec, dict) or "lever_by_zoom" not in spec:
            continue
        levers: dict[float, tuple[float, float]] = {}
        for i, item in enumerate(spec["lever_by_zoom"]):
            zoom = float(item["zoom"])
            if zoom in levers:
                raise _fail(path, f"simulation.head_errors.{cid}.lever_by_zoom[{i}].zoom",
                            f"zoom {zoom:g} is listed twice")
            levers[zoom] = (float(item.get("lever_y_baseline", 0.0)), float(item.get("lever_z_baseline", 0.0)))
        out[cid] = levers
    return out


def _camera_search(box: dict[str, Any] | None, search: SearchConfig, name: str, path: str) -> SearchConfig | None:
    """A camera's own search box (degrees in ``box``) over the rig's ``search``; None without one."""
    if not box:
        return None
    deg = {k: math.radians(float(box[f"{k}_deg"])) for k in ("pan_min", "pan_max", "tilt_min", "tilt_max")
           if f"{k}_deg" in box}
    out = replace(search, pan_min=deg.get("pan_min", search.pan_min), pan_max=deg.get("pan_max", search.pan_max),
                  tilt_min=deg.get("tilt_min", search.tilt_min), tilt_max=deg.get("tilt_max", search.tilt_max))
    if out.pan_min >= out.pan_max:
        raise _fail(path, f"{name}.pan_max_deg", f"must exceed pan_min_deg ({math.degrees(out.pan_min):g}), "
                    f"got {math.degrees(out.pan_max):g}")
    if out.tilt_min >= out.tilt_max:
        raise _fail(path, f"{name}.tilt_max_deg", f"must exceed tilt_min_deg ({math.degrees(out.tilt_min):g}), "
                    f"got {math.degrees(out.tilt_max):g}")
    return out


def parse_rig(data: Any, path: str = "rig.json", base: Path | None = None) -> RigConfig:
    """Validate a parsed rig.json document (angles in degrees) against ``schemas/rig.schema.json``.

    Absent optional fields take the defaults of the config dataclasses; in memory
    every angle is radians. Intrinsics file paths are relative to ``base``
    (default: the directory of ``path``).
    """
    base = base if base is not None else Path(path).parent
    if isinstance(data, dict) and data.get("format", RIG_FORMAT) != RIG_FORMAT:
        raise _fail(path, "format", f"expected {RIG_FORMAT!r}, got {data.get('format')!r}")
    check(data, "rig", path, RigConfigError)
    top: dict[str, Any] = data

    cameras: list[CameraConfig] = []
    for i, o in enumerate(top["cameras"]):
        w = f"cameras[{i}]"
        if o["id"] in {c.id for c in cameras}:
            raise _fail(path, f"{w}.id", f"duplicate camera id {o['id']!r}")
        driver, port = o["driver"], o.get("port", "sim")
        scheme = _PORT_SCHEMES.get(driver)
        if scheme is not None and not (port.startswith(scheme[0]) if scheme[0] else "://" not in port):
            raise _fail(path, f"{w}.port", f"driver {driver} needs {scheme[1]}, got {port!r}")
        cameras.append(CameraConfig(
            id=o["id"], driver=driver, port=port,
            model=o.get("model", "EVI-D100"),
            mounting=o.get("mounting", "upright"),
            intrinsics=_intrinsics(o["intrinsics"], f"{w}.intrinsics", path, base),
            zoom=float(o.get("zoom", 0.0)),
            address=int(o.get("address", 1)),
            video=None if o.get("video") is None else str(o["video"]),
            reply_port=None if o.get("reply_port") is None else int(o["reply_port"]),
        ))
        if o.get("reply_port") is not None and driver != "visca-ip":
            raise _fail(path, f"{w}.reply_port", f"only for driver visca-ip, not {driver} ({o['reply_port']!r})")
    ids = [c.id for c in cameras]

    g = top.get("gauge", {"origin": ids[0], "baseline": ids[1]})
    origin, baseline = g["origin"], g["baseline"]
    for name, cam in (("gauge.origin", origin), ("gauge.baseline", baseline)):
        if cam not in ids:
            raise _fail(path, name, f"camera {cam!r} is not in cameras")
    if origin == baseline:
        raise _fail(path, "gauge.baseline", f"must differ from gauge.origin, both are {origin!r}")

    m = top["motes"]
    mdriver, mport = m["driver"], m.get("port", "sim")
    if mdriver == "serial-forwarder" and not mport.startswith("tcp://"):
        raise _fail(path, "motes.port", f"driver serial-forwarder needs tcp://HOST[:PORT], got {mport!r}")
    if mdriver == "tinyos-serial" and "://" in mport:
        raise _fail(path, "motes.port", f"driver tinyos-serial needs a serial device path, got {mport!r}")
    addresses = {str(k): int(v) for k, v in m["addresses"].items()} if "addresses" in m else None
    motes = MotesConfig(driver=mdriver, port=mport, addresses=addresses)

    node_ids: list[str] = []
    for i, n in enumerate(top["node_ids"]):
        nid = str(n)  # numbers are accepted and become strings
        if nid in node_ids:
            raise _fail(path, f"node_ids[{i}]", f"duplicate node id {nid!r}")
        node_ids.append(nid)

    s, d = top.get("search", {}), SearchConfig()
    search = SearchConfig(
        pan_min=math.radians(s["pan_min_deg"]) if "pan_min_deg" in s else d.pan_min,
        pan_max=math.radians(s["pan_max_deg"]) if "pan_max_deg" in s else d.pan_max,
        tilt_min=math.radians(s["tilt_min_deg"]) if "tilt_min_deg" in s else d.tilt_min,
        tilt_max=math.radians(s["tilt_max_deg"]) if "tilt_max_deg" in s else d.tilt_max,
        overlap=float(s.get("overlap", d.overlap)),
        centre_tolerance_px=float(s.get("centre_tolerance_px", d.centre_tolerance_px)),
        max_centre_steps=int(s.get("max_centre_steps", d.max_centre_steps)),
        settle_s=float(s.get("settle_s", d.settle_s)),
        led_wait_s=float(s.get("led_wait_s", d.led_wait_s)),
        method=s.get("method", d.method),
        threshold=int(s.get("threshold", d.threshold)),
        detection=s.get("detection", d.detection),
    )
    if search.pan_min >= search.pan_max:
        raise _fail(path, "search.pan_max_deg", f"must exceed pan_min_deg, got {math.degrees(search.pan_max):g}")
    if search.tilt_min >= search.tilt_max:
        raise _fail(path, "search.tilt_max_deg", f"must exceed tilt_min_deg, got {math.degrees(search.tilt_max):g}")
    cameras = [replace(c, search=_camera_search(top["cameras"][i].get("search"), search, f"cameras[{i}].search", path))
               for i, c in enumerate(cameras)]

    r, rd = top.get("retry", {}), RetryConfig()
    retry = RetryConfig(
        led_attempts=int(r.get("led_attempts", rd.led_attempts)),
        head_attempts=int(r.get("head_attempts", rd.head_attempts)),
        reconnects=int(r.get("reconnects", rd.reconnects)),
        backoff_s=float(r.get("backoff_s", rd.backoff_s)),
        max_consecutive_misses=int(r.get("max_consecutive_misses", rd.max_consecutive_misses)),
    )

    sim = top.get("simulation", {})
    heights = sim.get("heights", [0.1] * len(cameras))
    if len(heights) != len(cameras):
        raise _fail(path, "simulation.heights",
                    f"expected {len(cameras)} numbers (one per camera), got {show_value(heights)}")
    dead = sim.get("dead_nodes", [])
    if any(str(n) not in node_ids for n in dead):
        raise _fail(path, "simulation.dead_nodes", f"expected a list of node ids from node_ids, got {show_value(dead)}")
    dcam = sim.get("disconnect_camera", "")
    if dcam and dcam not in ids:
        raise _fail(path, "simulation.disconnect_camera", f"camera {dcam!r} is not in cameras")
    simulation = SimulationConfig(
        seed=int(sim.get("seed", 0)),
        video_seed=None if sim.get("video_seed") is None else int(sim["video_seed"]),
        heights=tuple(float(h) for h in heights),
        occlusion=float(sim.get("occlusion", 0.0)),
        dead_nodes=tuple(str(n) for n in dead),
        drop_rate=float(sim.get("drop_rate", 0.0)),
        garble_rate=float(sim.get("garble_rate", 0.0)),
        disconnect_after=int(sim.get("disconnect_after", 0)),
        disconnect_camera=dcam or ids[0],
        time_scale=float(sim.get("time_scale", 0.0)),
        twin=sim.get("twin", "inprocess"),
        frames=sim.get("frames", "spot"),
        head_errors=_head_errors(sim.get("head_errors", {}), ids, int(sim.get("seed", 0)), path),
        head_zoom_levers=_zoom_levers(sim.get("head_errors", {}), path),
    )
    repeat_budget = int(top.get("repeat_budget", 0))
    if repeat_budget and top.get("nodes", "planar") != "planar":
        raise _fail(path, "repeat_budget", f"repeat planning supports planar surveys only, got {repeat_budget} "
                    f"with nodes {show_value(top.get('nodes'))}")
    sigma = math.radians(top.get("sigma_deg", 0.1))
    repeatability = math.radians(float(top.get("head_repeatability_deg", 0.0)))
    if repeatability >= sigma:
        raise _fail(path, "head_repeatability_deg", f"the head's share of sigma_deg must be below sigma_deg "
                    f"({math.degrees(sigma):g}), got {show_value(top.get('head_repeatability_deg'))}")
    return RigConfig(
        path=path,
        mode=NodeMode(top.get("nodes", "planar")),
        sigma=sigma,
        head_repeatability=repeatability,
        gauge=Gauge(origin=origin, baseline=baseline),
        cameras=cameras,
        motes=motes,
        node_ids=node_ids,
        repeats=int(top.get("repeats", 1)),
        repeat_budget=repeat_budget,
        identification=str(top.get("identification", "sequential")),
        search=search,
        retry=retry,
        simulation=simulation,
        hash=rig_hash(top),
        raw=top,
    )


# -- what a resumed survey may change (docs/survey.md, "Resuming after a rig.json edit")
# ``repeat_budget`` is deliberately operational: it decides how many readings the repeat phase
# adds, never what a reading means (a repeat is an ordinary reading of a pair, index >= repeats).
# The repeat plan is greedy on the readings of the node loop alone, so a plan for budget B is a
# prefix of the plan for any larger budget: a resume with another budget extends or cuts the
# same list, and every reading already journaled stays valid.
_MEANING_TOP = ("format", "nodes", "sigma_deg", "gauge", "repeats", "node_ids", "head_repeatability_deg")
_MEANING_CAMERA = ("id", "model", "mounting", "zoom")
_SCENE = ("seed", "video_seed", "heights", "occlusion", "dead_nodes", "head_errors")
_INTRINSICS = ("fx", "fy", "cx", "cy", "width", "height", "k1", "k2", "p1", "p2", "k3")


def rig_meaning(rig: RigConfig, simulated: bool = False) -> dict[str, Any]:
    """What the readings of a survey on ``rig`` mean, flat by rig.json field name (JSON values).

    Cameras (ids in order; model, mounting, zoom and the intrinsics' values, wherever
    they come from), nodes (mode, ids in order, mote addresses), gauge, ``sigma_deg``,
    ``repeats`` and ``search.method``; for a ``simulated`` survey also the scene
    (``simulation.seed``, ``heights``, ``occlusion``, ``dead_nodes``), which fixes its truth,
    and ``simulation.head_errors`` when the rig has any (absent otherwise, so journals of
    rigs without it compare as before).
    A journal recorded with other values cannot be continued. Never holds credentials.
    """
    m: dict[str, Any] = {
        "nodes": rig.mode.value, "sigma_deg": math.degrees(rig.sigma), "gauge.origin": rig.gauge.origin,
        "gauge.baseline": rig.gauge.baseline, "repeats": rig.repeats, "node_ids": list(rig.node_ids),
        "cameras": list(rig.camera_ids), "motes.addresses": rig.motes.addresses, "search.method": rig.search.method,
    }
    for c in rig.cameras:
        w = f"cameras[{c.id}]"
        m |= {f"{w}.model": c.model.lower(), f"{w}.mounting": c.mounting, f"{w}.zoom": c.zoom}
        m |= {f"{w}.intrinsics.{k}": getattr(c.intrinsics, k) for k in _INTRINSICS}
    if simulated:
        sim = rig.simulation
        m |= {"simulation.seed": sim.seed, "simulation.heights": list(sim.heights),
              "simulation.occlusion": sim.occlusion, "simulation.dead_nodes": list(sim.dead_nodes)}
        if sim.video_seed is not None:  # absent without, so journals of rigs without it compare as before
            m["simulation.video_seed"] = sim.video_seed
        if sim.head_errors:
            m["simulation.head_errors"] = {c: list(v) for c, v in sim.head_errors.items()}
        if sim.head_zoom_levers:  # absent without, so journals of rigs without it compare as before
            m["simulation.head_errors.lever_by_zoom"] = {c: [[z, *lv] for z, lv in sorted(v.items())]
                                                         for c, v in sim.head_zoom_levers.items()}
    if rig.head_repeatability:  # absent at 0, so journals of rigs without it compare as before
        m["head_repeatability_deg"] = math.degrees(rig.head_repeatability)
    return m


def rig_operational(rig: RigConfig) -> dict[str, Any]:
    """Every rig.json field :func:`rig_meaning` leaves out, flat (``cameras[cam0].port``,
    ``retry.backoff_s``): how to reach and drive the rig. URL user info is redacted, so the
    values can be journaled; a credential change shows only in the full ``rig.hash``."""
    out: dict[str, Any] = {}

    def put(name: str, value: Any) -> None:
        if isinstance(value, dict) and value:
            for k, v in value.items():
                put(f"{name}.{k}", v)
        elif isinstance(value, list):
            out[name] = [redact_urls(v) if isinstance(v, str) else v for v in value]
        else:
            out[name] = redact_urls(value) if isinstance(value, str) else value

    for key, value in rig.raw.items():
        if key in _MEANING_TOP:
            continue
        if key == "cameras":
            for cam in value:
                w = f"cameras[{cam['id']}]"
                for k, v in cam.items():
                    if k not in _MEANING_CAMERA and not (k == "intrinsics" and isinstance(v, dict)):
                        put(f"{w}.{k}", v)
        elif isinstance(value, dict):
            for k, v in value.items():
                if not ((key, k) == ("motes", "addresses") or (key, k) == ("search", "method")
                        or (key == "simulation" and k in _SCENE)):
                    put(f"{key}.{k}", v)
        else:
            put(key, value)
    return out


def load_rig(path: str | os.PathLike[str]) -> RigConfig:
    """Read and validate rig.json."""
    data = load_json(path, RigConfigError)
    return parse_rig(data, str(path), Path(path).parent)
