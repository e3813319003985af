"""An in-process simulated survey rig: scene, pan-tilt heads, LED base station, faults.

This twin works at the level of :mod:`fgloc.core.hardware`'s protocols (no bytes): it lets
the survey runner be exercised end to end, fast and deterministically. The
byte-level twins (VISCA, TinyOS serial) replace it where the drivers are tested.

Scene (gauge frame, planar): nodes uniform in the unit square on z = 0, camera
0 above (0, 0), camera 1 above (1, 0), further cameras above points around the
square; heights from the rig's simulation section; base rotations with random
yaw and a few degrees of roll and pitch. Each (camera, node) pair carries a
fixed measurement error N(0, sigma) on pan and tilt (deterministic by seed), so
a camera always sees a node at the same apparent bearing: re-measuring after a
resume reproduces the same reading. Frames (``simulation.frames``) are either a
clean Gaussian blob (1.5 px) per lit, unoccluded LED on black (``spot``), or the
camera pipeline's rendering (``rendered``, :class:`RenderedFrames`: textured
background, a few static bright lights, sensor noise) with the LED spot at the
same apparent bearing. Heads quantize moves to 1/14.4 degree (the EVI-D100's count).

Head repeatability (rig.json ``head_repeatability_deg``, :attr:`RigConfig.head_repeatability`,
default 0): each time a head settles after a move to a new position, its true pointing differs
from the position it reports by a random (pan, tilt) error N(0, head_repeatability) per axis.
Every frame is drawn from the true pointing while the head reports the commanded (quantized)
angles, so all readings taken from one settle (a coded view's motes) share that error and a
sequential centring reading gets the error of its last settle. The error is seeded by (rig
seed, camera, the position's counts, how often that camera settled there before in this
rig's life), so runs and resumes are deterministic. The pairs' fixed errors then take the rest
of ``sigma``: N(0, sqrt(sigma^2 - head_repeatability^2)), so a reading's total noise stays
``sigma``. At 0 (the default) nothing changes: the same draws, readings and frames as before.

Head errors (``simulation.head_errors``, :mod:`fgloc.core.head_model`): a camera with
errors is an imperfect head. The pair's apparent bearing becomes a point at the node's
range along it, and every frame is drawn where the imperfect head at the current
encoder readings sees that point (:mod:`fgloc.drivers.imperfect_head`), so the head's
encoders read the imperfect head's (pan, tilt) when the LED is centred, in the
in-process heads and through the VISCA twins' bytes alike.

Faults: each head command may raise :class:`SimulatedLinkError` (a dropped or
a garbled reply, at the configured rates), and one camera's link goes down
after ``disconnect_after`` commands: every call raises ``ConnectionError`` until
the runner reopens the head. The LED controller drops acknowledgements at the
drop rate; dead nodes never acknowledge and never light.
"""

from __future__ import annotations

import math
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fgloc.camera.led_search import PinholePixelModel
from fgloc.core.errors import FglocError
from fgloc.core.geometry import FloatArray, pan_tilt_bearing, project_pan_tilt, wrap_angle
from fgloc.core.head_model import head_pan_tilt
from fgloc.core.model import CameraPose, NodeMode, Truth
from fgloc.drivers.imperfect_head import head_at_zoom, head_view, ideal_equivalent_directions
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera, RenderSettings
from fgloc.drivers.tinyos.blink import (
    BlinkBroadcast,
    BlinkCommand,
    BlinkField,
    BlinkPause,
    blink_broadcast,
    parse_blink_report,
)
from fgloc.drivers.tinyos.messages import AmPacket
from fgloc.files.rig_config import RigConfig
from fgloc.sim.scenes import random_base_rotation

COUNTS_PER_RAD = 14.4 * 180.0 / math.pi
BLOB_SIGMA_PX = 1.5
STATIC_LIGHTS = 3  #: always-on bright lights in a scene with rendered frames

#: (pan, tilt) radians of the head -> uint8 (H, W) frame
FrameRenderer = Callable[[float, float], np.ndarray]


class SimulatedLinkError(OSError):
    """A simulated lost or garbled reply."""


def _stable_seed(*parts: object) -> int:
    return zlib.crc32("/".join(str(p) for p in parts).encode())


@dataclass
class SimScene:
    """Truth of a simulated rig plus the lit-LED state shared by heads and motes."""

    camera_ids: list[str]
    cameras: list[CameraPose]
    node_ids: list[str]
    nodes: FloatArray  # (N, 3)
    visible: np.ndarray  # (n_cam, N) bool
    apparent: np.ndarray  # (n_cam, N, 2) pan, tilt in radians, noise included
    dead: set[str]
    lights: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3) static lights (rendered frames)
    heads: FloatArray | None = None  # (n_cam, 7) head errors (fgloc.core.head_model order); None: ideal heads
    #: camera index -> zoom -> lever arm (l_y, l_z) at that zoom (rig.json ``lever_by_zoom``)
    zoom_levers: dict[int, dict[float, tuple[float, float]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.lit: set[str] = set()
        self.lock = threading.Lock()
        #: (camera index, pan counts, tilt counts) -> settles there so far (head repeatability seeds)
        self.settles: dict[tuple[int, int, int], int] = {}
        #: each camera's zoom now (its head sets it; None: the survey zoom), for the lever arm of that zoom
        self.zoom: list[float | None] = [None] * len(self.cameras)
        #: (n_cam, N) pan the imperfect head reads for each pair (fgloc.core.head_model), NaN for ideal heads
        self.head_pan = np.full(self.visible.shape, np.nan)
        for i in range(len(self.cameras)):
            if self.has_head_errors(i):
                assert self.heads is not None
                self.head_pan[i] = head_pan_tilt(self._apparent_points(i, list(range(len(self.node_ids)))),
                                                 self.heads[i], jacobians=False)[0]

    def _apparent_points(self, index: int, nodes: list[int]) -> FloatArray:
        """Base-frame points at the nodes' ranges along the pairs' apparent bearings (K, 3)."""
        bearings = pan_tilt_bearing(self.apparent[index, nodes, 0], self.apparent[index, nodes, 1]).reshape(-1, 3)
        ranges = np.linalg.norm(self.nodes[nodes] - self.cameras[index].position, axis=-1)
        return np.asarray(bearings * ranges[:, None], dtype=float)

    def has_head_errors(self, index: int) -> bool:
        return self.heads is not None and (bool(np.any(self.heads[index])) or bool(self.zoom_levers.get(index)))

    def head(self, index: int) -> FloatArray:
        """Camera ``index``'s head errors (7,) at its zoom now (the lever arm of that zoom where listed)."""
        assert self.heads is not None
        return head_at_zoom(self.heads[index], self.zoom_levers.get(index), self.zoom[index])

    def led_directions(self, index: int, nodes: list[int], pan: float, tilt: float) -> FloatArray:
        """Base-frame directions (K, 3) at which an ideal head at encoder readings (pan, tilt)
        shows the LEDs of ``nodes`` as camera ``index``'s head shows them (unit length for an
        ideal head: the pairs' apparent bearings).

        The pan scale error acts on the wrapped pan (fgloc.core.head_model), so the model's
        reading jumps at the encoder's +-180 degrees; each LED is drawn as seen with the head
        at the encoder pan equivalent to ``pan`` (mod 360 degrees) nearest the LED's model
        reading, so a head looking across the cut reads the LED as the model does (mod 360
        degrees) instead of 360 x pan scale degrees off."""
        if not self.has_head_errors(index):
            return pan_tilt_bearing(self.apparent[index, nodes, 0], self.apparent[index, nodes, 1]).reshape(-1, 3)
        assert self.heads is not None
        if not nodes:
            return np.zeros((0, 3))
        points = self._apparent_points(index, nodes)
        out = np.empty((len(nodes), 3))
        for k, j in enumerate(nodes):
            model_pan = float(self.head_pan[index, j])
            branch_pan = model_pan + float(wrap_angle(pan - model_pan))  # = pan (mod 2 pi), nearest the LED's reading
            out[k] = ideal_equivalent_directions(self.head(index), branch_pan, tilt, points[k:k + 1])[0]
        return out

    def view_correction(self, index: int, pan: float, tilt: float) -> FloatArray | None:
        """Camera ``index``'s real camera frame relative to the ideal head's at (pan, tilt)
        (``M`` of :func:`fgloc.drivers.imperfect_head.head_view`), None for an ideal head."""
        if not self.has_head_errors(index):
            return None
        assert self.heads is not None
        return head_view(self.head(index), pan, tilt)[0]

    @property
    def truth(self) -> Truth:
        return Truth(cameras=dict(zip(self.camera_ids, self.cameras)),
                     nodes={n: self.nodes[j] for j, n in enumerate(self.node_ids)})

    def visible_pairs(self) -> set[tuple[str, str]]:
        """(camera, node) pairs a survey can observe: unoccluded, LED working."""
        return {(c, n) for i, c in enumerate(self.camera_ids) for j, n in enumerate(self.node_ids)
                if self.visible[i, j] and n not in self.dead}

    def field_search_boxes(self, margin_deg: float = 5.0) -> dict[str, dict[str, float]]:
        """Per camera, a rig.json ``cameras[].search`` box (degrees) holding every visible node's
        apparent bearing with ``margin_deg`` to spare: what a field team sets when it knows where
        the field lies from each camera. A camera whose visible nodes lie across the +-180 degree
        pan seam (encoder pans more than 180 degrees apart) gets a box that runs across it (its
        pans taken around their circular mean, so one limit lies beyond +-180 degrees: a head
        that pans without end turns there); one whose nodes span more than 180 degrees either
        way keeps every pan."""
        out = {}
        for i, c in enumerate(self.camera_ids):
            seen = self.visible[i] & np.array([n not in self.dead for n in self.node_ids])
            if not seen.any():
                continue
            pan, tilt = np.degrees(self.apparent[i, seen, 0]), np.degrees(self.apparent[i, seen, 1])
            box = {"tilt_min_deg": max(-90.0, float(tilt.min()) - margin_deg),
                   "tilt_max_deg": min(90.0, float(tilt.max()) + margin_deg)}
            centre = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(pan))))))
            around = np.remainder(pan - centre + 180.0, 360.0) - 180.0 + centre
            if float(pan.max() - pan.min()) <= 180.0:
                box |= {"pan_min_deg": max(-180.0, float(pan.min()) - margin_deg),
                        "pan_max_deg": min(180.0, float(pan.max()) + margin_deg)}
            elif float(around.max() - around.min()) <= 180.0:
                box |= {"pan_min_deg": float(around.min()) - margin_deg,
                        "pan_max_deg": float(around.max()) + margin_deg}
            out[c] = box
        return out


def pair_noise_sigma(rig: RigConfig) -> float:
    """Radians: the fixed per-(camera, node) error's sigma, ``sigma`` less the head's repeatability
    (in quadrature); exactly ``rig.sigma`` when the rig declares none."""
    if rig.head_repeatability <= 0.0:
        return rig.sigma
    return math.sqrt(rig.sigma**2 - rig.head_repeatability**2)


def build_scene(rig: RigConfig) -> SimScene:
    """The simulated scene of a rig (deterministic by ``rig.simulation.seed``)."""
    if rig.mode is not NodeMode.PLANAR:
        raise FglocError(f"{rig.path}: nodes: --simulate supports planar rigs only, got {rig.mode.value!r}")
    sim = rig.simulation
    rng = np.random.default_rng(sim.seed)
    ids = rig.camera_ids
    order = [rig.gauge.origin, rig.gauge.baseline] + [c for c in ids if c not in (rig.gauge.origin, rig.gauge.baseline)]
    ground = {order[0]: (0.0, 0.0), order[1]: (1.0, 0.0)}
    extra = [(0.0, 1.0), (1.0, 1.0), (0.5, -0.3), (0.5, 1.3), (-0.3, 0.5), (1.3, 0.5)]
    for k, cid in enumerate(order[2:]):
        ground[cid] = extra[k % len(extra)]
    cameras = [CameraPose(np.array([*ground[c], sim.heights[i]]), random_base_rotation(rng, 3.0))
               for i, c in enumerate(ids)]
    n = len(rig.node_ids)
    nodes = np.column_stack([rng.uniform(0.0, 1.0, size=(n, 2)), np.zeros(n)])
    visible = rng.uniform(size=(len(ids), n)) >= sim.occlusion
    apparent = np.empty((len(ids), n, 2))
    pair_sigma = pair_noise_sigma(rig)
    for i, cam in enumerate(cameras):
        pan, tilt = project_pan_tilt(cam.rotation, cam.position, nodes)
        apparent[i, :, 0] = pan + rng.normal(0.0, pair_sigma, n)
        apparent[i, :, 1] = tilt + rng.normal(0.0, pair_sigma, n)
    lights = np.zeros((0, 3))
    if sim.frames == "rendered":  # own generator: the rest of the scene is the same for either kind of frame
        lrng = np.random.default_rng(_stable_seed(sim.seed, "static-lights"))
        lights = np.column_stack([lrng.uniform(-0.2, 1.2, size=(STATIC_LIGHTS, 2)),
                                  lrng.uniform(0.0, 0.05, size=STATIC_LIGHTS)])
    heads = None
    if sim.head_errors or sim.head_zoom_levers:
        heads = np.array([sim.head_errors.get(c, (0.0,) * 7) for c in ids], dtype=float)
    levers = {ids.index(c): dict(v) for c, v in sim.head_zoom_levers.items()}
    return SimScene(list(ids), cameras, list(rig.node_ids), nodes, visible, apparent, set(sim.dead_nodes), lights,
                    heads, levers)


def render_frame(scene: SimScene, index: int, pixels: PinholePixelModel, pan: float, tilt: float) -> np.ndarray:
    """What camera ``index`` sees with its head at (pan, tilt): a Gaussian spot per lit LED."""
    k = pixels.intrinsics
    frame = np.zeros((k.height, k.width), dtype=np.uint8)
    with scene.lock:
        lit = [scene.node_ids.index(n) for n in scene.lit]
    shown = [j for j in lit if scene.visible[index, j]]
    for direction in scene.led_directions(index, shown, pan, tilt):
        px = pixels.bearing_to_pixel(pan, tilt, direction)
        if px is None:
            continue
        x, y = px
        r = 8
        x0, x1 = max(int(x) - r, 0), min(int(x) + r + 1, k.width)
        y0, y1 = max(int(y) - r, 0), min(int(y) + r + 1, k.height)
        if x0 >= x1 or y0 >= y1:
            continue
        ys, xs = np.mgrid[y0:y1, x0:x1]
        blob = 250.0 * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * BLOB_SIGMA_PX**2))
        frame[y0:y1, x0:x1] = np.maximum(frame[y0:y1, x0:x1], np.round(blob).astype(np.uint8))
    return frame


class RenderedFrames:
    """Camera ``index``'s frames through the camera pipeline's renderer (drivers/rendered_camera.py).

    The LED of every lit, unoccluded node is an integrated Gaussian spot (1500 DN, 1.2 px) at
    the pair's apparent bearing (``scene.apparent``: truth plus the pair's fixed N(0, sigma)
    error, exactly where the ``spot`` frames put it), drawn through the camera's intrinsics
    (distortion included) on a textured background fixed to base-frame directions (its own
    texture per camera), with the scene's static lights and Gaussian read + shot noise. The
    noise of a frame is seeded by (rig seed, camera, head angles, lit LEDs), so a frame is a
    pure function of the rig's state: the simulation stays deterministic, resumes included.
    Thread-safe for one head per camera.
    """

    def __init__(self, scene: SimScene, index: int, rig: RigConfig, settings: RenderSettings | None = None) -> None:
        self.scene = scene
        self.index = index
        self.intrinsics = rig.cameras[index].intrinsics
        self.seed = rig.simulation.seed
        self.camera_id = scene.camera_ids[index]
        settings = settings or RenderSettings(texture_seed=_stable_seed(self.seed, self.camera_id, "texture"))
        self.camera = RenderedCamera(scene.cameras[index], LedScene(positions={}, distractors=scene.lights), settings)

    def __call__(self, pan: float, tilt: float) -> np.ndarray:
        """The frame with the head at (pan, tilt) radians (spec convention): uint8 (H, W)."""
        scene = self.scene
        with scene.lock:
            lit = sorted(scene.lit)
        shown = [scene.node_ids.index(n) for n in lit]
        shown = [j for j in shown if scene.visible[self.index, j]]
        directions = scene.led_directions(self.index, shown, pan, tilt)
        rng = np.random.default_rng(_stable_seed(self.seed, self.camera_id, repr(float(pan)), repr(float(tilt)), *lit))
        return self.camera.render_directions(self.intrinsics, pan, tilt, rng, directions,
                                             correction=scene.view_correction(self.index, pan, tilt))


def frame_renderer(scene: SimScene, index: int, rig: RigConfig) -> FrameRenderer:
    """Camera ``index``'s frames, as ``rig.simulation.frames`` asks: ``spot`` or ``rendered``."""
    if rig.simulation.frames == "rendered":
        return RenderedFrames(scene, index, rig)
    pixels = PinholePixelModel(rig.cameras[index].intrinsics)
    return lambda pan, tilt: render_frame(scene, index, pixels, pan, tilt)


class SceneHead:
    """A simulated pan-tilt head (implements :class:`fgloc.core.hardware.PanTiltHead`).

    ``frames`` renders what the head sees (default: :func:`frame_renderer` for the rig)."""

    def __init__(self, scene: SimScene, index: int, rig: RigConfig, generation: int, faults: FaultPlan,
                 frames: FrameRenderer | None = None) -> None:
        self.scene = scene
        self.index = index
        self.frames = frames or frame_renderer(scene, index, rig)
        self.pan = 0.0
        self.tilt = 0.0
        #: (pan, tilt) radians: true pointing minus the reported angles since the last settle
        self.pointing_error = (0.0, 0.0)
        self.repeatability = rig.head_repeatability
        self.seed = rig.simulation.seed
        self._zoom = rig.cameras[index].zoom
        scene.zoom[index] = self._zoom
        self.time_scale = rig.simulation.time_scale
        self.faults = faults
        self.rng = np.random.default_rng(_stable_seed(rig.simulation.seed, rig.camera_ids[index], generation))
        self.closed = False

    def _command(self) -> None:
        if self.closed:
            raise ConnectionError("simulated head: port closed")
        self.faults.on_command(self.scene.camera_ids[self.index], self.rng)

    def move_to(self, pan: float, tilt: float) -> None:
        self._command()
        new_pan = round(pan * COUNTS_PER_RAD) / COUNTS_PER_RAD
        new_tilt = round(tilt * COUNTS_PER_RAD) / COUNTS_PER_RAD
        if self.time_scale > 0:
            time.sleep(self.time_scale * (0.002 + 0.01 * math.hypot(new_pan - self.pan, new_tilt - self.tilt)))
        if self.repeatability > 0 and (new_pan, new_tilt) != (self.pan, self.tilt):
            self.pointing_error = self._settle_error(new_pan, new_tilt)
        self.pan, self.tilt = new_pan, new_tilt

    concurrent_zoom = True  #: :meth:`move_and_zoom` stands for a head that runs both at once

    def move_and_zoom(self, pan: float, tilt: float, zoom: float) -> None:
        """Zoom to ``zoom`` (fraction of the optical range) and move to (pan, tilt) radians at once,
        as a VISCA head does in its two command sockets (two commands, one wait)."""
        self.set_zoom(zoom)
        self.move_to(pan, tilt)

    def _settle_error(self, pan: float, tilt: float) -> tuple[float, float]:
        """The pointing error of a settle at (pan, tilt): N(0, repeatability) per axis, seeded by
        the rig seed, the camera, the position's counts and the settles there before."""
        key = (self.index, round(pan * COUNTS_PER_RAD), round(tilt * COUNTS_PER_RAD))
        with self.scene.lock:
            visit = self.scene.settles[key] = self.scene.settles.get(key, -1) + 1
        rng = np.random.default_rng(_stable_seed(self.seed, self.scene.camera_ids[self.index], "settle", *key[1:],
                                                 visit))
        e = rng.normal(0.0, self.repeatability, 2)
        return float(e[0]), float(e[1])

    @property
    def pointing(self) -> tuple[float, float]:
        """(pan, tilt) radians the head truly points at (the reported angles plus the settle's error)."""
        if self.pointing_error == (0.0, 0.0):
            return self.pan, self.tilt
        return self.pan + self.pointing_error[0], self.tilt + self.pointing_error[1]

    def position(self) -> tuple[float, float]:
        self._command()
        return self.pan, self.tilt

    def set_zoom(self, zoom: float) -> None:
        self._command()
        self._zoom = zoom
        self.scene.zoom[self.index] = zoom  # the imperfect head's optical centre moves with zoom

    def zoom(self) -> float:
        self._command()
        return self._zoom

    def stop(self) -> None:
        self._command()

    def home(self) -> None:
        self.move_to(0.0, 0.0)

    def grab_frame(self) -> np.ndarray:
        self._command()
        return self.frames(*self.pointing)

    def close(self) -> None:
        self.closed = True


class FaultPlan:
    """Shared fault state of the simulated links (thread-safe)."""

    def __init__(self, rig: RigConfig) -> None:
        sim = rig.simulation
        self.drop_rate = sim.drop_rate
        self.garble_rate = sim.garble_rate
        self.disconnect_after = sim.disconnect_after
        self.disconnect_camera = sim.disconnect_camera
        self.commands: dict[str, int] = {}
        self.down: set[str] = set()
        self.disconnected_once = False
        self.injected = {"dropped": 0, "garbled": 0, "disconnects": 0}
        self.lock = threading.Lock()

    def on_command(self, camera: str, rng: np.random.Generator) -> None:
        with self.lock:
            if camera in self.down:
                raise ConnectionError(f"simulated head {camera}: link down")
            count = self.commands[camera] = self.commands.get(camera, 0) + 1
            if (self.disconnect_after and not self.disconnected_once and camera == self.disconnect_camera
                    and count >= self.disconnect_after):
                self.disconnected_once = True
                self.down.add(camera)
                self.injected["disconnects"] += 1
                raise ConnectionError(f"simulated head {camera}: link down")
        u = rng.uniform()
        if u < self.drop_rate:
            with self.lock:
                self.injected["dropped"] += 1
            raise SimulatedLinkError(f"simulated head {camera}: no reply (timeout)")
        if u < self.drop_rate + self.garble_rate:
            with self.lock:
                self.injected["garbled"] += 1
            raise SimulatedLinkError(f"simulated head {camera}: garbled reply")

    def reopen(self, camera: str) -> None:
        with self.lock:
            self.down.discard(camera)


class SceneLeds:
    """A simulated base station (implements :class:`fgloc.core.hardware.LedController`).

    Blink codes (coded surveys): :meth:`broadcast_codes` takes the same commands as
    :meth:`fgloc.drivers.tinyos.network.MoteNetwork.broadcast_codes`, encodes them as the
    real AM packet (:func:`fgloc.drivers.tinyos.blink.blink_broadcast`) and hands it to the
    motes' side (:class:`~fgloc.drivers.tinyos.blink.BlinkField`); node k of ``node_ids`` is
    mote address k + 1 (as on the VISCA twin rig), dead nodes stay silent, and each
    report is lost at the drop rate."""

    def __init__(self, scene: SimScene, rig: RigConfig) -> None:
        self.scene = scene
        self.drop_rate = rig.simulation.drop_rate
        self.time_scale = rig.simulation.time_scale
        self.rng = np.random.default_rng(_stable_seed(rig.simulation.seed, "motes"))
        self.acks_dropped = 0
        self.addresses = {n: k + 1 for k, n in enumerate(rig.node_ids)}
        self.blink = BlinkField(nodes=set(self.addresses.values()),
                                silent={self.addresses[n] for n in rig.simulation.dead_nodes})
        self.received: list[AmPacket] = []  # blink packets the motes received

    def broadcast_codes(self, command: BlinkBroadcast | BlinkCommand | BlinkPause, expect: set[int] | None = None,
                        wait: float = 0.0) -> dict[int, tuple[bool, int, int]]:
        """Broadcast a start by address or a stop; the blink reports (address -> (running,
        length, code)) that came back (``expect`` and ``wait`` as the real driver's, unused here)."""
        packet = blink_broadcast(command)
        with self.scene.lock:
            self.received.append(packet)
            reports = self.blink.handle(packet)
        out: dict[int, tuple[bool, int, int]] = {}
        for r in reports:
            rep = parse_blink_report(r)
            if rep is not None and self.rng.uniform() >= self.drop_rate:
                out[rep[0]] = rep[1:]
        return out

    def set_led(self, node_id: str, on: bool) -> bool:
        if self.time_scale > 0:
            time.sleep(self.time_scale * 0.005)
        if node_id in self.scene.dead or node_id not in self.scene.node_ids:
            return False
        with self.scene.lock:
            if on:
                self.scene.lit.add(node_id)
            else:
                self.scene.lit.discard(node_id)
        if self.rng.uniform() < self.drop_rate:
            self.acks_dropped += 1
            return False
        return True


class InProcessRig:
    """Opens simulated heads and the LED controller of a rig, sharing one scene."""

    def __init__(self, rig: RigConfig) -> None:
        self.rig = rig
        self.scene = build_scene(rig)
        self.faults = FaultPlan(rig)
        self.leds = SceneLeds(self.scene, rig)
        self.frames = {c: frame_renderer(self.scene, i, rig) for i, c in enumerate(rig.camera_ids)}
        self._generation: dict[str, int] = {}
        self.heads: dict[str, SceneHead] = {}  # the head last opened per camera
        self._blinks: object | None = None
        self.blink_zoom = True  # record_blinks renders at the head's zoom (coded refinement)
        self.blink_fields = True  # record_blinks renders interlaced fields on request (coded.video "fields")

    def record_blinks(self, camera_id: str, n_frames: int, t_start: float, key: str,
                      fields: bool = False) -> list[tuple[float, np.ndarray]]:
        """Coded surveys: ``n_frames`` frame periods of blinking-mote video from ``camera_id``'s
        head where it is now (:class:`fgloc.drivers.blink_scene.SceneBlinks`), timestamps from
        ``t_start`` (survey-clock seconds), seeded by ``key``; ``fields``: interlaced fields
        (:meth:`~fgloc.drivers.blink_scene.SceneBlinks.record`)."""
        from fgloc.drivers.blink_scene import SceneBlinks

        if self._blinks is None:
            self._blinks = SceneBlinks(self.scene, self.rig, self.leds.addresses, self.leds.blink,
                                       lambda: list(self.leds.received))
        head = self.heads[camera_id]
        return self._blinks.record(camera_id, *head.pointing, n_frames, t_start, key,  # type: ignore[attr-defined]
                                   head._zoom, fields)

    def open_head(self, camera_id: str) -> SceneHead:
        """Open (or reopen, after a disconnect) the head of ``camera_id``."""
        gen = self._generation[camera_id] = self._generation.get(camera_id, -1) + 1
        self.faults.reopen(camera_id)
        head = self.heads[camera_id] = SceneHead(self.scene, self.rig.camera_ids.index(camera_id), self.rig, gen,
                                                 self.faults, self.frames[camera_id])
        return head
