"""A simulated rig whose cameras speak real VISCA bytes: one pty twin per camera.

Each camera of the rig gets a :class:`fgloc.drivers.twins.visca_camera.ViscaSerialTwin`
(the emulated camera on a pseudo-terminal, with the rig's fault rates) and is
opened with the real driver, :func:`fgloc.drivers.visca.head.open_serial_head`, through
pyserial. The emulator renders frames from the same scene as the in-process rig
(:func:`fgloc.drivers.inprocess_rig.frame_renderer`: ``spot`` or ``rendered`` per
``simulation.frames``), converting its head counts to spec
angles with the camera's :class:`~fgloc.drivers.ptz_units.PanTiltUnits` (model and
mounting from rig.json). The LEDs go through the real TinyOS serial driver
(:func:`fgloc.drivers.tinyos.network.open_mote_network`) to a base-station pty twin whose
motes light the scene's LEDs; dead nodes stay silent.

Faults per camera and on the base station: ``drop_rate`` and ``garble_rate``
per reply (seeded by the rig seed and the link), and for ``disconnect_camera`` one disconnect after
``disconnect_after`` requests, the port coming back ``reconnect_after`` seconds later. ``speedup`` compresses
time: heads move ``speedup`` times faster than the model's speed table.
"""

from __future__ import annotations

import zlib
from dataclasses import replace

from fgloc.drivers.inprocess_rig import FrameRenderer, build_scene, frame_renderer
from fgloc.drivers.ptz_units import PanTiltUnits, camera_model, mounting
from fgloc.drivers.tinyos.network import MoteNetwork, open_mote_network
from fgloc.drivers.twins.base_station import BaseStationSerialTwin, MoteFieldEmulator
from fgloc.drivers.twins.faults import FaultConfig
from fgloc.drivers.twins.visca_camera import HeadPose, ViscaCameraEmulator, ViscaSerialTwin
from fgloc.drivers.visca.head import HeadSettings, ViscaHead, open_serial_head
from fgloc.drivers.visca.session import Timeouts
from fgloc.files.rig_config import RigConfig


class ViscaTwinRig:
    """Scene + one VISCA pty twin per camera; ``open_head`` opens the real serial driver."""

    def __init__(self, rig: RigConfig, reconnect_after: float = 0.2, timeouts: Timeouts | None = None,
                 speedup: float = 100.0) -> None:
        self.rig = rig
        # The twin answers at once, so time-compressed timeouts only shorten the waits for
        # dropped replies; the retry logic is the driver's own.
        self.timeouts = timeouts or Timeouts(ack=0.03, inquiry=0.04, completion_margin=0.05)
        self.scene = build_scene(rig)
        self.base_station: BaseStationSerialTwin | None = None
        self.leds: MoteNetwork | None = None  # set once the base-station twin runs
        self.units: dict[str, PanTiltUnits] = {}
        self.twins: dict[str, ViscaSerialTwin] = {}
        self._blinks: object | None = None  # blinking-mote video (coded surveys), made when first asked
        sim = rig.simulation
        try:
            for i, cam in enumerate(rig.cameras):
                model = camera_model(cam.model)
                # Time compression: the twin's head and the driver's completion timeouts
                # both use the model's speed table, so scaling it keeps them consistent.
                model = replace(model, pan_speed_dps=tuple(v * speedup for v in model.pan_speed_dps),
                                tilt_speed_dps=tuple(v * speedup for v in model.tilt_speed_dps))
                units = PanTiltUnits(model, mounting(cam.mounting))
                frames = frame_renderer(self.scene, i, rig)

                def renderer(pose: HeadPose, units: PanTiltUnits = units, frames: FrameRenderer = frames):
                    pan, tilt = units.to_spec(pose.pan_counts, pose.tilt_counts)
                    return frames(pan, tilt)

                faults = FaultConfig(
                    drop_rate=sim.drop_rate,
                    garble_rate=sim.garble_rate,
                    disconnect_after=(sim.disconnect_after or None) if cam.id == sim.disconnect_camera else None,
                    reconnect_after=reconnect_after,
                    seed=zlib.crc32(f"{sim.seed}/{cam.id}".encode()),
                )
                emulator = ViscaCameraEmulator(units.model, address=cam.address, renderer=renderer, time_scale=1.0)
                self.units[cam.id] = units
                self.twins[cam.id] = ViscaSerialTwin(emulator, faults)
            # Motes: node k of node_ids is mote address k + 1.
            self.addresses = {n: k + 1 for k, n in enumerate(rig.node_ids)}
            node_of = {a: n for n, a in self.addresses.items()}

            def on_led(address: int, on: bool) -> None:
                with self.scene.lock:
                    (self.scene.lit.add if on else self.scene.lit.discard)(node_of[address])

            field = MoteFieldEmulator(nodes=self.addresses.values(),
                                      silent={self.addresses[n] for n in sim.dead_nodes}, on_led=on_led)
            self.base_station = BaseStationSerialTwin(field, FaultConfig(
                drop_rate=sim.drop_rate, garble_rate=sim.garble_rate, seed=zlib.crc32(f"{sim.seed}/motes".encode())))
            self.leds = open_mote_network(self.base_station.port, self.addresses, ack_timeout=0.03, retries=5,
                                          report_timeout=0.05, attempts=3)
        except BaseException:
            self.close()
            raise

    def open_head(self, camera_id: str) -> ViscaHead:
        """Open the camera's twin port with the real VISCA serial driver."""
        twin = self.twins[camera_id]
        cam = self.rig.cameras[self.rig.camera_ids.index(camera_id)]
        return open_serial_head(twin.port, self.units[camera_id], address=cam.address, timeouts=self.timeouts,
                                frames=twin.emulator.frame_source(), settings=HeadSettings())

    def record_blinks(self, camera_id: str, n_frames: int, t_start: float, key: str) -> list:
        """Coded surveys: ``n_frames`` frame periods of blinking-mote video from ``camera_id``,
        its head where the VISCA twin says it is (the motes run what the real TinyOS driver
        commanded through the base-station twin; :class:`fgloc.drivers.blink_scene.SceneBlinks`)."""
        from fgloc.drivers.blink_scene import SceneBlinks

        assert self.base_station is not None  # the constructor started it
        if self._blinks is None:
            mote_field = self.base_station.field
            self._blinks = SceneBlinks(self.scene, self.rig, self.addresses, mote_field.blink,
                                       lambda: list(mote_field.received))
        pose = self.twins[camera_id].emulator.pose()
        pan, tilt = self.units[camera_id].to_spec(pose.pan_counts, pose.tilt_counts)
        return self._blinks.record(camera_id, pan, tilt, n_frames, t_start, key)  # type: ignore[attr-defined]

    def injected(self) -> dict[str, int]:
        """Faults injected so far, summed over cameras."""
        total: dict[str, int] = {}
        injectors = [t.faults for t in self.twins.values()]
        if self.base_station is not None:
            injectors.append(self.base_station.faults)
        for faults in injectors:
            for k, v in faults.counts.items():
                total[k] = total.get(k, 0) + v
        return total

    def close(self) -> None:
        close = getattr(self.leds, "close", None)
        if callable(close):
            close()
        for twin in self.twins.values():
            twin.close()
        if self.base_station is not None:
            self.base_station.close()

    def __enter__(self) -> ViscaTwinRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
