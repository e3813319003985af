"""A whole simulated rig at the byte level: camera twins + a base-station twin, opened through the real drivers.

For survey orchestration under ``--simulate`` with the real driver code in the
loop. A scene plugs in with two hooks in the **spec convention** (no counts):

* ``render(camera_id, pan, tilt, zoom) -> ndarray``: what camera ``camera_id`` sees
  with its head at spec (pan, tilt) radians and zoom fraction; the twin converts
  its device counts through the camera's :class:`~fgloc.drivers.ptz_units.PanTiltUnits`
  (model and mounting), so the scene never deals with signs or counts;
* ``on_led(node, on)``: called when a mote's LED changes; ``node`` is the fgloc node id
  when ``node_ids`` is given (mote address = the id's trailing number, and only those
  motes exist), else the 16-bit mote address. ``silent_nodes`` never answer.

With issue 6's renderer: ``render=lambda cid, pan, tilt, zoom: rendered[cid].render(
intrinsics[cid].at_zoom(zoom), pan, tilt, rng)`` and ``on_led=lambda n, on:
(scene.lit.add if on else scene.lit.discard)(n)``.

Example::

    with TwinRig([TwinCamera("cam0"), TwinCamera("cam1", transport="udp")], render=scene.render,
                 on_led=scene.set_led, faults=FaultConfig(drop_rate=0.05, seed=1)) as rig:
        head = rig.open_head("cam0")          # a ViscaHead on the pty, frames from the scene
        leds = rig.open_leds()                # a MoteNetwork on the base-station pty
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fgloc.core.hardware import PanTiltHead
from fgloc.drivers.frames import FrameSource
from fgloc.drivers.ptz_units import PanTiltUnits, camera_model, mounting
from fgloc.drivers.tinyos.messages import node_address
from fgloc.drivers.tinyos.network import MoteNetwork
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, MoteFieldEmulator, SerialForwarderTwin
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.sony_cgi_camera import SonyCgiTwin
from fgloc.drivers.twins.visca_camera import HeadPose, ViscaCameraEmulator, ViscaSerialTwin
from fgloc.drivers.twins.visca_ip_camera import ViscaIpTwin

SpecRenderer = Callable[[str, float, float, float], np.ndarray]


@dataclass(frozen=True)
class TwinCamera:
    """One simulated camera: id, transport (``serial``, ``udp``, ``http``), model name, mounting.

    ``reply_port`` (udp only): the twin sends every reply to that controller port (52381 on
    cameras that ignore the sender's port); ``open_head`` then receives there."""

    camera_id: str
    transport: str = "serial"
    model: str = "EVI-D100"
    mount: str = "desk"
    reply_port: int | None = None

    @property
    def units(self) -> PanTiltUnits:
        return PanTiltUnits(camera_model(self.model), mounting(self.mount))


class TwinRig:
    """Starts the twins; ``ports`` / ``mote_port`` are what a rig.json would name. Context manager."""

    def __init__(self, cameras: Iterable[TwinCamera], render: SpecRenderer | None = None,
                 on_led: Callable[[Any, bool], None] | None = None, motes: str = "serial",
                 faults: FaultConfig | None = None, camera_faults: Mapping[str, FaultConfig] | None = None,
                 mote_faults: FaultConfig | None = None, silent_nodes: Iterable[int | str] = (),
                 time_scale: float = 0.0, node_ids: Iterable[str] | None = None) -> None:
        self.cameras = {c.camera_id: c for c in cameras}
        self._render = render
        self.twins: dict[str, ViscaSerialTwin | ViscaIpTwin | SonyCgiTwin] = {}
        self.ports: dict[str, str] = {}
        self._opened: list = []
        try:
            for i, cam in enumerate(self.cameras.values()):
                f = (camera_faults or {}).get(cam.camera_id, faults)
                if f is not None:
                    f = replace(f, seed=f.seed + 1000 * i, script=list(f.script), error_script=list(f.error_script))
                emulator = ViscaCameraEmulator(cam.units.model, time_scale=time_scale,
                                               renderer=self._renderer_for(cam) if render else None)
                twin: ViscaSerialTwin | ViscaIpTwin | SonyCgiTwin
                if cam.transport == "serial":
                    twin = ViscaSerialTwin(emulator, f)
                    self.ports[cam.camera_id] = twin.port
                elif cam.transport == "udp":
                    twin = ViscaIpTwin(emulator, f, reply_port=cam.reply_port)
                    self.ports[cam.camera_id] = twin.url
                elif cam.transport == "http":
                    twin = SonyCgiTwin(emulator, f)
                    self.ports[cam.camera_id] = twin.url
                else:
                    raise ValueError(f"unknown transport {cam.transport!r}")
                self.twins[cam.camera_id] = twin
            self.node_ids = None if node_ids is None else list(node_ids)
            by_address = None if self.node_ids is None else {node_address(n): n for n in self.node_ids}
            led_hook = on_led
            if on_led is not None and by_address is not None:
                def by_node(address: int, on: bool) -> None:
                    on_led(by_address[address], on)

                led_hook = by_node
            self.field = MoteFieldEmulator(nodes=None if by_address is None else set(by_address),
                                           silent={node_address(n) for n in silent_nodes}, on_led=led_hook)
            mf = mote_faults if mote_faults is not None else faults
            if mf is not None:
                mf = replace(mf, seed=mf.seed + 999, script=list(mf.script), error_script=list(mf.error_script))
            if motes == "serial":
                self.base_station: BaseStationSerialTwin | SerialForwarderTwin = BaseStationSerialTwin(self.field, mf)
                self.mote_port = self.base_station.port
            elif motes == "tcp":
                self.base_station = SerialForwarderTwin(self.field, mf)
                self.mote_port = self.base_station.url
            else:
                raise ValueError(f"unknown mote transport {motes!r}")
        except BaseException:
            self.close()
            raise

    def _renderer_for(self, cam: TwinCamera) -> Callable[[HeadPose], np.ndarray]:
        units = cam.units
        render = self._render
        assert render is not None

        def renderer(pose: HeadPose) -> np.ndarray:
            pan, tilt = units.to_spec(pose.pan_counts, pose.tilt_counts)
            return render(cam.camera_id, pan, tilt, units.zoom_from_counts(pose.zoom_counts))

        return renderer

    def frame_source(self, camera_id: str) -> FrameSource:
        """The scene's view from ``camera_id``'s current (device-reported) pose."""
        return self.twins[camera_id].emulator.frame_source()

    def open_head(self, camera_id: str, timeout: float = 0.1, retries: int = 5,
                  completion_margin: float = 0.2) -> PanTiltHead:
        """The real driver for ``camera_id`` on its twin (frames from the scene when a renderer is set)."""
        from fgloc.drivers.connect import HeadOptions, open_head

        cam = self.cameras[camera_id]
        frames = self.frame_source(camera_id) if self._render else None
        head = open_head(self.ports[camera_id], HeadOptions(cam.model, cam.mount, timeout=timeout, retries=retries,
                                                                completion_margin=completion_margin,
                                                                http_timeout=max(3 * timeout, 0.2),
                                                                reply_port=cam.reply_port),
                         frames=frames)
        self._opened.append(head)
        return head

    def open_leds(self, timeout: float = 0.05, retries: int = 8, report_timeout: float = 0.1,
                  attempts: int = 5) -> MoteNetwork:
        """The real MoteNetwork on the base-station twin."""
        from fgloc.drivers.connect import open_leds

        net = open_leds(self.mote_port, None, timeout, retries, report_timeout, attempts)
        assert isinstance(net, MoteNetwork)
        self._opened.append(net)
        return net

    def close(self) -> None:
        for thing in getattr(self, "_opened", []):
            try:
                thing.close()
            except Exception:  # noqa: BLE001 - closing twins must not fail on a dead link
                pass
        for twin in list(getattr(self, "twins", {}).values()):
            twin.close()
        bs = getattr(self, "base_station", None)
        if bs is not None:
            bs.close()

    def __enter__(self) -> TwinRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
