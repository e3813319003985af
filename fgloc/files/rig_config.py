"""rig.json: the description of a survey rig (cameras, mote base station, nodes, search).

See ``docs/survey.md`` for the documented format. Angles in rig.json are degrees
(people at a rig think in degrees); everything in memory is radians. Every
problem is a :class:`RigConfigError` naming ``file: field: problem (value)``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_search import SearchConfig
from fgloc.core.errors import FglocError
from fgloc.core.model import Gauge, NodeMode
from fgloc.files.camera_file import read_intrinsics
from fgloc.files.journal import rig_hash
from fgloc.files.json_io import load_json

RIG_FORMAT = "fgloc-rig"
CAMERA_DRIVERS = ("visca-serial", "visca-ip", "sony-cgi", "simulated")
MOTE_DRIVERS = ("tinyos-serial", "serial-forwarder", "simulated")
MOUNTINGS = ("upright", "ceiling")
MEASURE_METHODS = ("centre", "pixel-offset")
DETECTIONS = ("single", "on-off")
SIMULATION_TWINS = ("inprocess", "visca")
SIMULATION_FRAMES = ("spot", "rendered")


class RigConfigError(FglocError):
    """A rig.json that does not describe a usable rig."""


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
    """How hard to try before recording a failure."""

    led_attempts: int = 4
    head_attempts: int = 4
    reconnects: int = 3
    backoff_s: float = 0.05


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
    """

    seed: int = 0
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


@dataclass(frozen=True)
class RigConfig:
    """A whole rig. ``sigma`` in radians; ``path`` is where it was read from."""

    path: str
    mode: NodeMode
    sigma: float
    gauge: Gauge
    cameras: list[CameraConfig]
    motes: MotesConfig
    node_ids: list[str]
    repeats: int = 1
    search: SearchConfig = SearchConfig()
    retry: RetryConfig = RetryConfig()
    simulation: SimulationConfig = SimulationConfig()
    hash: str = ""
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def camera_ids(self) -> list[str]:
        return [c.id for c in self.cameras]


class _Fields:
    """rig.json's field checks (ranges, integers, choices), raising ``file: field: problem``."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, name: str, problem: str) -> RigConfigError:
        return RigConfigError(f"{self.path}: {name}: {problem}")

    def obj(self, value: Any, name: str) -> dict:
        if not isinstance(value, dict):
            raise self.fail(name, f"expected an object, got {json.dumps(value)[:60]}")
        return value

    def req(self, obj: dict, key: str, where: str) -> Any:
        if key not in obj:
            raise self.fail(f"{where}{key}", "missing required field")
        return obj[key]

    def string(self, value: Any, name: str, choices: tuple[str, ...] = ()) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(name, f"expected a non-empty string, got {json.dumps(value)[:60]}")
        if choices and value not in choices:
            raise self.fail(name, f"expected one of {', '.join(choices)}, got {value!r}")
        return value

    def number(self, value: Any, name: str, lo: float = -math.inf, hi: float = math.inf,
               integer: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(name, f"expected a finite number, got {json.dumps(value)[:60]}")
        if integer and value != int(value):
            raise self.fail(name, f"expected an integer, got {value!r}")
        if not lo <= value <= hi:
            raise self.fail(name, f"must lie in [{lo:g}, {hi:g}], got {value!r}")
        return float(value)


def _intrinsics(f: _Fields, value: Any, name: str, base: Path) -> CameraIntrinsics:
    """Inline ``{fx, fy, cx, cy, width, height[, k1, k2, p1, p2, k3]}`` or a camera.json path."""
    if isinstance(value, str):
        ipath = (base / value) if not os.path.isabs(value) else Path(value)
        if not ipath.exists():
            raise f.fail(name, f"intrinsics file not found: {str(ipath)!r}")
        try:
            return read_intrinsics(ipath)
        except FglocError as exc:
            raise f.fail(name, str(exc)) from None
    o = f.obj(value, name)
    return CameraIntrinsics(
        fx=f.number(f.req(o, "fx", f"{name}."), f"{name}.fx", lo=1e-6),
        fy=f.number(f.req(o, "fy", f"{name}."), f"{name}.fy", lo=1e-6),
        cx=f.number(f.req(o, "cx", f"{name}."), f"{name}.cx"),
        cy=f.number(f.req(o, "cy", f"{name}."), f"{name}.cy"),
        width=int(f.number(f.req(o, "width", f"{name}."), f"{name}.width", lo=8, integer=True)),
        height=int(f.number(f.req(o, "height", f"{name}."), f"{name}.height", lo=8, integer=True)),
        **{k: f.number(o[k], f"{name}.{k}") for k in ("k1", "k2", "p1", "p2", "k3") if k in o},
    )


def parse_rig(data: Any, path: str = "rig.json", base: Path | None = None) -> RigConfig:
    """Validate a parsed rig.json document."""
    f = _Fields(path)
    base = base if base is not None else Path(path).parent
    top = f.obj(data, "(top level)")
    if top.get("format", RIG_FORMAT) != RIG_FORMAT:
        raise f.fail("format", f"expected {RIG_FORMAT!r}, got {top.get('format')!r}")
    mode_value = top.get("nodes", "planar")
    if mode_value not in ("planar", "3d"):
        raise f.fail("nodes", f'expected "planar" or "3d", got {mode_value!r}')
    sigma = math.radians(f.number(top.get("sigma_deg", 0.1), "sigma_deg", lo=1e-9, hi=90))

    cams_raw = f.req(top, "cameras", "")
    if not isinstance(cams_raw, list) or len(cams_raw) < 2:
        raise f.fail("cameras", "expected a list of at least 2 cameras")
    cameras: list[CameraConfig] = []
    for i, c in enumerate(cams_raw):
        w = f"cameras[{i}]"
        o = f.obj(c, w)
        cid = f.string(f.req(o, "id", f"{w}."), f"{w}.id")
        if cid in {x.id for x in cameras}:
            raise f.fail(f"{w}.id", f"duplicate camera id {cid!r}")
        driver = f.string(f.req(o, "driver", f"{w}."), f"{w}.driver", CAMERA_DRIVERS)
        port = f.string(o.get("port", "sim"), f"{w}.port") if driver == "simulated" else f.string(
            f.req(o, "port", f"{w}."), f"{w}.port")
        cameras.append(CameraConfig(
            id=cid,
            driver=driver,
            port=port,
            model=f.string(o.get("model", "EVI-D100"), f"{w}.model"),
            mounting=f.string(o.get("mounting", "upright"), f"{w}.mounting", MOUNTINGS),
            intrinsics=_intrinsics(f, f.req(o, "intrinsics", f"{w}."), f"{w}.intrinsics", base),
            zoom=f.number(o.get("zoom", 0.0), f"{w}.zoom", lo=0.0, hi=1.0),
            address=int(f.number(o.get("address", 1), f"{w}.address", lo=1, hi=7, integer=True)),
            video=None if o.get("video") is None else str(f.string(str(o["video"]), f"{w}.video")),
        ))
        scheme = {"visca-serial": "", "visca-ip": "udp://", "sony-cgi": "http"}.get(driver)
        if scheme is not None and (port.startswith(scheme) if scheme else "://" not in port) is False:
            want = {"": "a serial device path", "udp://": "udp://HOST[:PORT]", "http": "http://HOST"}[scheme]
            raise f.fail(f"{w}.port", f"driver {driver} needs {want}, got {port!r}")
    ids = [c.id for c in cameras]

    g = f.obj(top.get("gauge", {"origin": ids[0], "baseline": ids[1]}), "gauge")
    origin = f.string(f.req(g, "origin", "gauge."), "gauge.origin")
    baseline = f.string(f.req(g, "baseline", "gauge."), "gauge.baseline")
    for name, cam in (("gauge.origin", origin), ("gauge.baseline", baseline)):
        if cam not in ids:
            raise f.fail(name, f"camera {cam!r} is not in cameras")
    if origin == baseline:
        raise f.fail("gauge.baseline", f"must differ from gauge.origin, both are {origin!r}")

    m = f.obj(f.req(top, "motes", ""), "motes")
    mdriver = f.string(f.req(m, "driver", "motes."), "motes.driver", MOTE_DRIVERS)
    if mdriver == "serial-forwarder" and not str(m.get("port", "")).startswith("tcp://"):
        raise f.fail("motes.port", f"driver serial-forwarder needs tcp://HOST[:PORT], got {m.get('port')!r}")
    if mdriver == "tinyos-serial" and "://" in str(m.get("port", "")):
        raise f.fail("motes.port", f"driver tinyos-serial needs a serial device path, got {m.get('port')!r}")
    addresses = None
    if "addresses" in m:
        amap = f.obj(m["addresses"], "motes.addresses")
        addresses = {str(k): int(f.number(v, f"motes.addresses.{k}", 0, 0xFFFE, True)) for k, v in amap.items()}
    motes = MotesConfig(
        driver=mdriver,
        port=f.string(m.get("port", "sim"), "motes.port") if mdriver == "simulated"
        else f.string(f.req(m, "port", "motes."), "motes.port"),
        addresses=addresses,
    )

    nodes_raw = f.req(top, "node_ids", "")
    if not isinstance(nodes_raw, list) or not nodes_raw:
        raise f.fail("node_ids", "expected a non-empty list of node ids")
    node_ids: list[str] = []
    for i, n in enumerate(nodes_raw):
        if isinstance(n, int) and not isinstance(n, bool):
            n = str(n)
        nid = f.string(n, f"node_ids[{i}]")
        if nid in node_ids:
            raise f.fail(f"node_ids[{i}]", f"duplicate node id {nid!r}")
        node_ids.append(nid)

    s = f.obj(top.get("search", {}), "search")
    d = SearchConfig()
    search = SearchConfig(
        pan_min=math.radians(f.number(s.get("pan_min_deg", math.degrees(d.pan_min)), "search.pan_min_deg", -360, 360)),
        pan_max=math.radians(f.number(s.get("pan_max_deg", math.degrees(d.pan_max)), "search.pan_max_deg", -360, 360)),
        tilt_min=math.radians(f.number(s.get("tilt_min_deg", math.degrees(d.tilt_min)), "search.tilt_min_deg", -90, 90)),
        tilt_max=math.radians(f.number(s.get("tilt_max_deg", math.degrees(d.tilt_max)), "search.tilt_max_deg", -90, 90)),
        overlap=f.number(s.get("overlap", d.overlap), "search.overlap", 0.1, 1.0),
        centre_tolerance_px=f.number(s.get("centre_tolerance_px", d.centre_tolerance_px), "search.centre_tolerance_px", 0.01),
        max_centre_steps=int(f.number(s.get("max_centre_steps", d.max_centre_steps), "search.max_centre_steps", 0, 100, True)),
        settle_s=f.number(s.get("settle_s", d.settle_s), "search.settle_s", 0, 60),
        led_wait_s=f.number(s.get("led_wait_s", d.led_wait_s), "search.led_wait_s", 0, 60),
        method=f.string(s.get("method", d.method), "search.method", MEASURE_METHODS),
        threshold=int(f.number(s.get("threshold", d.threshold), "search.threshold", 1, 255, True)),
        detection=f.string(s.get("detection", d.detection), "search.detection", DETECTIONS),
    )
    if search.pan_min >= search.pan_max:
        raise f.fail("search.pan_max_deg", f"must exceed pan_min_deg, got {math.degrees(search.pan_max):g}")
    if search.tilt_min >= search.tilt_max:
        raise f.fail("search.tilt_max_deg", f"must exceed tilt_min_deg, got {math.degrees(search.tilt_max):g}")

    r = f.obj(top.get("retry", {}), "retry")
    rd = RetryConfig()
    retry = RetryConfig(
        led_attempts=int(f.number(r.get("led_attempts", rd.led_attempts), "retry.led_attempts", 1, 100, True)),
        head_attempts=int(f.number(r.get("head_attempts", rd.head_attempts), "retry.head_attempts", 1, 100, True)),
        reconnects=int(f.number(r.get("reconnects", rd.reconnects), "retry.reconnects", 0, 100, True)),
        backoff_s=f.number(r.get("backoff_s", rd.backoff_s), "retry.backoff_s", 0, 60),
    )

    sim = f.obj(top.get("simulation", {}), "simulation")
    heights = sim.get("heights", [0.1] * len(cameras))
    if not isinstance(heights, list) or len(heights) != len(cameras):
        raise f.fail("simulation.heights", f"expected {len(cameras)} numbers (one per camera), got {json.dumps(heights)[:60]}")
    dead = sim.get("dead_nodes", [])
    if not isinstance(dead, list) or any(str(n) not in node_ids for n in dead):
        raise f.fail("simulation.dead_nodes", f"expected a list of node ids from node_ids, got {json.dumps(dead)[:60]}")
    dcam = sim.get("disconnect_camera", "")
    if dcam and dcam not in ids:
        raise f.fail("simulation.disconnect_camera", f"camera {dcam!r} is not in cameras")
    simulation = SimulationConfig(
        seed=int(f.number(sim.get("seed", 0), "simulation.seed", 0, 2**32, True)),
        heights=tuple(f.number(h, f"simulation.heights[{i}]", lo=1e-6) for i, h in enumerate(heights)),
        occlusion=f.number(sim.get("occlusion", 0.0), "simulation.occlusion", 0, 0.9),
        dead_nodes=tuple(str(n) for n in dead),
        drop_rate=f.number(sim.get("drop_rate", 0.0), "simulation.drop_rate", 0, 0.5),
        garble_rate=f.number(sim.get("garble_rate", 0.0), "simulation.garble_rate", 0, 0.5),
        disconnect_after=int(f.number(sim.get("disconnect_after", 0), "simulation.disconnect_after", 0, 1e9, True)),
        disconnect_camera=dcam or ids[0],
        time_scale=f.number(sim.get("time_scale", 0.0), "simulation.time_scale", 0, 10),
        twin=f.string(sim.get("twin", "inprocess"), "simulation.twin", SIMULATION_TWINS),
        frames=f.string(sim.get("frames", "spot"), "simulation.frames", SIMULATION_FRAMES),
    )
    return RigConfig(
        path=path,
        mode=NodeMode(mode_value),
        sigma=sigma,
        gauge=Gauge(origin=origin, baseline=baseline),
        cameras=cameras,
        motes=motes,
        node_ids=node_ids,
        repeats=int(f.number(top.get("repeats", 1), "repeats", 1, 100, True)),
        search=search,
        retry=retry,
        simulation=simulation,
        hash=rig_hash(top),
        raw=top,
    )


def load_rig(path: str | os.PathLike[str]) -> RigConfig:
    """Read and validate rig.json."""
    data = load_json(path, RigConfigError)
    return parse_rig(data, str(path), Path(path).parent)
