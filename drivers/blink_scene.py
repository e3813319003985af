"""Blinking-mote video of a simulated rig's scene: what a camera records in a coded survey.

The simulated rigs (:mod:`fgloc.drivers.inprocess_rig`, :mod:`fgloc.drivers.twin_rig`) hand
the motes' blink commands to a :class:`~fgloc.drivers.tinyos.blink.BlinkField` (the
firmware's behaviour: which address runs which word). :class:`SceneBlinks` renders the
frames one camera records with its head still, by :func:`fgloc.drivers.blink_frames.render_view`:

* every mote the field says is lit (running and not paused by a pause-by-bitmap) blinks its word, one bit per commanded bit period
  (the period of the last start command that covered its address), LED on for a 1 bit;
* it is drawn along the pair's **apparent** bearing (``scene.apparent``: truth plus the
  pair's fixed N(0, sigma) error), exactly where the sequential survey's frames put its LED,
  so both modes read the same scene; occluded pairs are not drawn; a camera whose head has
  errors (rig.json ``simulation.head_errors`` / ``head_zoom_levers``) shows each mote where its
  imperfect head at the view's encoder readings shows it (``SimScene.led_directions``: the
  head's errors and the lever arm of its zoom now), so off-centre readings carry the head
  errors the view model of :mod:`fgloc.core.head_model` predicts;
* each mote has its own crystal error (N(0, 50 ppm)) and start phase, seeded by the rig
  seed (``simulation.video_seed`` when given: another recording of the same scene) and the
  node, so motes drift against the camera and against each other;
* the background is the camera's texture (:class:`~fgloc.drivers.rendered_camera.RenderedCamera`,
  the same texture seed as the ``rendered`` frames) with the scene's static lights
  flickering at twice the mains frequency, plus the video faults of
  :class:`~fgloc.drivers.blink_frames.BlinkRenderConfig` (default: 5 % dropped frames,
  1 ms timestamp jitter, 0.05 px head jitter, 2 % ambient gain noise).

Frames are seeded by (rig seed or video seed, camera, ``key``): the survey passes the view's id and
attempt, so a resumed survey renders the same frames. Timestamps are seconds on the
survey clock (``t_start``: the camera lane's predicted field time when recording starts).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from fgloc.camera.blink_codes import bits_of
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.drivers.blink_frames import BlinkingMote, BlinkRenderConfig, render_view
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera, RenderSettings
from fgloc.drivers.tinyos.blink import BlinkBroadcast, BlinkCommand, BlinkField, parse_blink_command
from fgloc.drivers.tinyos.messages import AmPacket
from fgloc.files.rig_config import RigConfig

PPM_SD = 50.0  #: motes' crystal error, parts per million (Gaussian)


def _seed(*parts: object) -> int:
    return zlib.crc32("/".join(str(p) for p in parts).encode())


def bit_periods(packets: Sequence[AmPacket]) -> dict[int, float]:
    """Address -> bit period (s) of the last start command covering it (broadcasts by
    address and unicast starts, in the order received)."""
    out: dict[int, float] = {}
    for p in packets:
        cmd = parse_blink_command(p)
        if isinstance(cmd, BlinkBroadcast):
            for a in range(cmd.first, cmd.first + cmd.count):
                out[a] = cmd.bit_period_s
        elif isinstance(cmd, BlinkCommand) and cmd.start:
            out[p.dest] = cmd.bit_period_s
    return out


class SceneBlinks:
    """Renders the blinking views of one simulated rig (see the module docstring).

    ``scene`` is the rig's :class:`~fgloc.drivers.inprocess_rig.SimScene`, ``addresses`` maps
    node ids to mote addresses, ``field`` is the motes' blink state and ``packets()`` returns
    the AM packets the motes received so far (for the commanded bit periods)."""

    def __init__(self, scene, rig: RigConfig, addresses: dict[str, int], field: BlinkField,  # noqa: ANN001
                 packets: Callable[[], Sequence[AmPacket]], config: BlinkRenderConfig | None = None) -> None:
        self.scene = scene
        self.rig = rig
        self.node_of = {a: n for n, a in addresses.items()}
        self.field = field
        self.packets = packets
        self.config = config or BlinkRenderConfig()
        self.seed = rig.simulation.seed if rig.simulation.video_seed is None else rig.simulation.video_seed
        self.cameras = {  # the background belongs to the scene: its texture keeps the scene's seed
            cid: RenderedCamera(scene.cameras[i], LedScene(positions={}),
                                RenderSettings(texture_seed=_seed(rig.simulation.seed, cid, "texture")))
            for i, cid in enumerate(scene.camera_ids)
        }

    def motes(self, camera_id: str, pan: float | None = None, tilt: float | None = None) -> list[BlinkingMote]:
        """The motes blinking now that ``camera_id`` can see, at their apparent bearings.

        With the head's encoder readings (``pan``, ``tilt``, radians) and a camera whose head has
        errors (``scene.has_head_errors``), each mote is placed where the imperfect head at those
        readings shows it to an ideal head (``scene.led_directions``: its errors and its zoom's
        lever arm, the node's range included), so off-centre motes move as the head model of a
        view predicts (:func:`fgloc.core.head_model.head_view_pan_tilt`). Ideal heads (or no
        readings) draw the apparent bearings exactly as before."""
        i = self.scene.camera_ids.index(camera_id)
        cam = self.scene.cameras[i]
        periods = bit_periods(list(self.packets()))
        shown: list[tuple[str, int, int, int, int]] = []  # node, node index, address, length, word
        for address, (length, word) in sorted(self.field.lit().items()):  # paused motes stay dark
            node = self.node_of.get(address)
            if node is None or address not in periods:
                continue
            j = self.scene.node_ids.index(node)
            if not self.scene.visible[i, j] or node in self.scene.dead:
                continue
            shown.append((node, j, address, length, word))
        imperfect = pan is not None and tilt is not None and self.scene.has_head_errors(i)
        seen = np.zeros((0, 3))
        if imperfect and shown and pan is not None and tilt is not None:
            seen = self.scene.led_directions(i, [s[1] for s in shown], float(pan), float(tilt))
            seen = seen / np.linalg.norm(seen, axis=1, keepdims=True)
        out = []
        for k, (node, j, address, length, word) in enumerate(shown):
            d = seen[k] if imperfect else pan_tilt_bearing(*self.scene.apparent[i, j])
            position = np.asarray(cam.position, float) + np.asarray(cam.rotation, float) @ d  # base direction d
            rng = np.random.default_rng(_seed(self.seed, node, "crystal"))
            ppm, t0 = rng.normal(0.0, PPM_SD), -rng.uniform(0.0, 1.0)
            out.append(BlinkingMote(node, position, bits_of(word, length), periods[address] * (1.0 + 1e-6 * ppm), t0))
        return out

    def record(self, camera_id: str, pan: float, tilt: float, n_frames: int, t_start: float, key: str,
               zoom: float | None = None, fields: bool = False) -> list[tuple[float, np.ndarray]]:
        """``(timestamp s, uint8 frame)`` of ``n_frames`` frame periods recorded by ``camera_id``
        with its head truly pointing at (pan, tilt) radians (the in-process rig passes the
        reported angles plus the settle's pointing error, ``SceneHead.pointing``), from ``t_start`` on the survey clock (dropped frames
        missing). ``zoom`` other than the camera's survey zoom renders through the idealised
        :meth:`~fgloc.camera.intrinsics.CameraIntrinsics.at_zoom` model of its intrinsics.
        ``fields``: ``n_frames`` interlaced **fields** instead, as ``scripts/blink_montecarlo.py
        --fields`` renders them: every second row (half the height, ``fy`` and ``cy``, as
        :func:`fgloc.survey.coded_readings.field_intrinsics`), 59.94 Hz, half of each light's
        flux (the same spot shape in field pixels: the Monte Carlo's approximation)."""
        i = self.scene.camera_ids.index(camera_id)
        cam = self.rig.cameras[i]
        intr = cam.intrinsics if zoom is None or zoom == cam.zoom else cam.intrinsics.at_zoom(zoom)
        config = self.config
        if fields:  # one field: every second row (frame row 2r), twice the rate, half the light
            intr = replace(intr, fy=0.5 * intr.fy, cy=0.5 * intr.cy, height=intr.height // 2)
            config = replace(config, frame_rate_hz=2.0 * config.frame_rate_hz, led_flux=0.5 * config.led_flux,
                             static_flux=0.5 * config.static_flux,
                             glint_flux=(0.5 * config.glint_flux[0], 0.5 * config.glint_flux[1]))
        rng = np.random.default_rng(_seed(self.seed, camera_id, key, "blink-video"))
        statics = self.scene.lights if len(self.scene.lights) else None
        return render_view(self.cameras[camera_id], intr, pan, tilt, self.motes(camera_id, pan, tilt), n_frames, rng,
                           config, statics=statics, t_start=t_start)
