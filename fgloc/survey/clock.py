"""Survey clock: the field time a survey spends on its devices (slews, settling, frames, radio).

A pure pricing model, no I/O and no sleeping. A survey is a sequence of
operations per camera lane (:class:`Slew`, :class:`Settle`, :class:`Frames`,
:class:`PositionRead`, :class:`Zoom`) plus radio operations on the shared mote
lane (:class:`Radio`); :func:`price` turns one lane into seconds per phase, and
:func:`parallel` combines lanes that run at the same time (cameras move in
parallel, the field time is the longest lane).

Units: seconds, radians (angles of :class:`Slew`), Hz (frame rates).

**Head motion** (:class:`AxisModel`): each axis follows a trapezoidal velocity
profile: accelerate at ``accel`` to ``max_speed``, cruise, decelerate. A move of
angle ``d`` lasts ``d / v + v / a`` when ``d >= v^2 / a`` (the ramp reaches top
speed) and ``2 sqrt(d / a)`` otherwise. Pan and tilt move at the same time, so a
slew lasts the longer of the two, plus the command round trip
(``HeadModel.command_s``: sending the absolute-move packet and receiving ACK and
Completion). Then the head settles (``settle_s``) before a frame is usable.

**Zoom** travels linearly in the zoom fraction (``zoom_full_s`` wide to tele). A head with
``zoom_while_moving`` (the EVI-D100: VISCA's two command sockets run a zoom and a pan-tilt move
at once, protocols.md 1.4) can zoom during a move (:class:`Slew` with ``dzoom``): the move
lasts the longer of the axes and the zoom, plus one command round trip (both commands are
sent before either Completion is awaited). Otherwise a zoom is its own :class:`Zoom`.

**Sources and assumptions** (all in ``docs/blink-codes.md``):

* EVI-D100 top speeds 300 deg/s pan and 125 deg/s tilt: Sony technical manual p.44
  (``shared/reference/protocols.md`` 1.8). The manual gives no acceleration; we
  assume each axis reaches top speed in 0.2 s (pan 1500 deg/s^2, tilt 625 deg/s^2),
  consistent with "~1 s for 200 deg at 300 deg/s plus ramps" (protocols.md 1.5).
  Settle: protocols.md 5.3 asks for at least two fields (33 ms); we assume 0.1 s
  (three frames) so the frame after a stop carries no motion blur. Commands: 15-byte
  packet at 9600 bit/s (16 ms) + ACK within one field + Completion within one field
  after the stop -> 0.05 s; a position inquiry ~0.04 s (protocols.md 1.5).
* SNC-RZ25N: the reference has no motion figures (its data sheet was not
  retrievable). **Assumed**: pan 300 deg/s and tilt 300 deg/s (the
  speed-byte range it shares with the D100), the same 0.2 s ramps, HTTP command
  round trip 0.1 s, position read by polling until two reads agree (0.2 s), settle
  0.1 s. Treat SNC-RZ25N figures as placeholders until measured.
* Camera frames: NTSC 29.97 frames/s (both heads are NTSC video). The EVI-D100's
  video is analog and interlaced, so a frame grabber delivers 59.94 fields/s, each
  exposed separately with every second row (``HeadModel.interlaced``,
  :meth:`CameraTiming.at_field_rate`); a coded survey may decode fields (half the
  vertical resolution). The SNC-RZ25N is read over the network as JPEG frames:
  **assumed** not field-decodable. A frame grabbed
  "now" is on average half a frame period away plus one period of grabber latency
  (``CameraTiming.grab_latency_s``), paid once per burst of consecutive frames; frames
  that continue a running recording (``Frames(continuous=True)``: a retry or an
  extension decoded in sliding windows) cost their frame periods only.
* Radio (MicaZ base station, protocols.md 3): one command = serial frame at 57600
  bit/s (~3 ms) + serial ACK + CSMA radio transmit and the node's report back; we
  assume 0.03 s per acknowledged command and 0.01 s per broadcast (no report).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

#: Phase names used in reports, in display order.
PHASES = ("slew", "settle", "centring", "frames", "position", "zoom", "radio", "led_wait", "separate")


@dataclass(frozen=True)
class AxisModel:
    """One head axis: top speed (rad/s) and acceleration = deceleration (rad/s^2)."""

    max_speed: float
    accel: float

    def move_time(self, angle: float) -> float:
        """Seconds to turn by ``angle`` radians (sign ignored) from rest to rest, trapezoidal profile."""
        d = abs(angle)
        if d == 0.0:
            return 0.0
        v, a = self.max_speed, self.accel
        if d >= v * v / a:
            return d / v + v / a
        return 2.0 * math.sqrt(d / a)


def _axis(deg_per_s: float, ramp_s: float) -> AxisModel:
    v = math.radians(deg_per_s)
    return AxisModel(max_speed=v, accel=v / ramp_s)


@dataclass(frozen=True)
class HeadModel:
    """Device time of one pan-tilt head (seconds). See the module docstring for sources."""

    name: str
    pan: AxisModel
    tilt: AxisModel
    settle_s: float  #: after a move, until a frame is free of motion blur
    command_s: float  #: absolute-move command round trip (packet, ACK, Completion)
    position_s: float  #: one position read-back
    zoom_full_s: float  #: wide <-> tele zoom travel (linear in the zoom fraction)
    interlaced: bool = False  #: video reaches the PC as interlaced fields (decodable at field rate)
    #: the head runs a zoom and a pan-tilt move at once (VISCA: two command sockets)
    zoom_while_moving: bool = False

    def slew_time(self, dpan: float, dtilt: float) -> float:
        """Seconds for an absolute move by (dpan, dtilt) radians: both axes at once + command."""
        return max(self.pan.move_time(dpan), self.tilt.move_time(dtilt)) + self.command_s

    def zoom_time(self, dzoom: float) -> float:
        """Seconds of zoom travel by ``dzoom`` (fraction of the optical range, sign ignored)."""
        return abs(dzoom) * self.zoom_full_s


EVI_D100 = HeadModel(
    name="EVI-D100", pan=_axis(300.0, 0.2), tilt=_axis(125.0, 0.2),
    settle_s=0.1, command_s=0.05, position_s=0.04, zoom_full_s=2.0, interlaced=True, zoom_while_moving=True,
)
SNC_RZ25N = HeadModel(
    name="SNC-RZ25N (assumed)", pan=_axis(300.0, 0.2), tilt=_axis(300.0, 0.2),
    settle_s=0.1, command_s=0.1, position_s=0.2, zoom_full_s=2.0,
)
HEAD_MODELS: dict[str, HeadModel] = {"EVI-D100": EVI_D100, "SNC-RZ25N": SNC_RZ25N}


@dataclass(frozen=True)
class CameraTiming:
    """Video timing: frame rate (Hz), exposure (s, <= frame period) and grabber latency (s)."""

    frame_rate_hz: float = 30000.0 / 1001.0
    exposure_s: float = 1.0 / 500.0
    grab_latency_s: float = 1001.0 / 30000.0

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.frame_rate_hz

    def at_field_rate(self) -> CameraTiming:
        """The same video decoded field by field (interlaced NTSC: two fields per frame, each
        with every second row): twice the rate, the grabber latency unchanged."""
        return replace(self, frame_rate_hz=2.0 * self.frame_rate_hz)

    def burst_time(self, frames: int) -> float:
        """Seconds to grab ``frames`` consecutive frames: wait half a period on average for the
        next frame start, the frames themselves, plus the grabber latency (0 for 0 frames)."""
        if frames <= 0:
            return 0.0
        return 0.5 * self.frame_period_s + frames * self.frame_period_s + self.grab_latency_s


@dataclass(frozen=True)
class RadioTiming:
    """Mote radio command cost (s): acknowledged unicast (with the node's report) and broadcast."""

    unicast_s: float = 0.03
    broadcast_s: float = 0.01


@dataclass(frozen=True)
class RigTiming:
    """Everything the clock needs about one rig: head and video per camera, and the radio."""

    head: HeadModel = EVI_D100
    camera: CameraTiming = field(default_factory=CameraTiming)
    radio: RadioTiming = field(default_factory=RadioTiming)


# ----- operations ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Slew:
    """Absolute move by (dpan, dtilt) radians; ``phase`` 'slew' (search/views) or 'centring'.
    ``dzoom``: a zoom by that fraction of the optical range run at the same time (a head with
    ``zoom_while_moving``): the move lasts the longer of the two, the zoom's excess over the
    move is reported in the 'zoom' phase."""

    dpan: float
    dtilt: float
    phase: str = "slew"
    dzoom: float = 0.0

    @classmethod
    def between(cls, start: tuple[float, float], end: tuple[float, float], dzoom: float = 0.0) -> Slew:
        """The slew from head (pan, tilt) ``start`` to ``end``, radians, pan the short way round,
        with a zoom by ``dzoom`` at the same time."""
        return cls(math.remainder(end[0] - start[0], 2 * math.pi), end[1] - start[1], dzoom=dzoom)


@dataclass(frozen=True)
class Settle:
    """Wait for the head to settle after a move (``phase`` 'settle')."""

    phase: str = "settle"


@dataclass(frozen=True)
class Frames:
    """A burst of ``count`` consecutive frames. ``continuous``: the frames continue a
    recording already running (no wait for a frame start, no second grabber latency):
    ``count`` frame periods."""

    count: int
    phase: str = "frames"
    continuous: bool = False


@dataclass(frozen=True)
class PositionRead:
    """Read the head's position back."""

    phase: str = "position"


@dataclass(frozen=True)
class Zoom:
    """Zoom travel by ``dzoom`` (fraction of the optical range)."""

    dzoom: float
    phase: str = "zoom"


@dataclass(frozen=True)
class Radio:
    """``unicast`` acknowledged mote commands and ``broadcast`` broadcasts."""

    unicast: int = 0
    broadcast: int = 0
    phase: str = "radio"


@dataclass(frozen=True)
class Wait:
    """A fixed wait of ``seconds`` (e.g. the LED settling after a command)."""

    seconds: float
    phase: str = "led_wait"


Op = Slew | Settle | Frames | PositionRead | Zoom | Radio | Wait


@dataclass(frozen=True)
class FieldTime:
    """Field time per phase (seconds) of one lane or of the critical path of parallel lanes."""

    phases: Mapping[str, float]

    @property
    def total(self) -> float:
        return float(sum(self.phases.values()))

    def __add__(self, other: FieldTime) -> FieldTime:
        keys = list(dict.fromkeys([*self.phases, *other.phases]))
        return FieldTime({k: self.phases.get(k, 0.0) + other.phases.get(k, 0.0) for k in keys})

    def describe(self) -> str:
        """``total 123.4 s (slew 12.0, settle 3.0, ...)`` with the non-zero phases."""
        parts = ", ".join(f"{k} {v:.1f}" for k, v in self.phases.items() if v > 0)
        return f"total {self.total:.1f} s ({parts})"


ZERO = FieldTime({})


def _zoom_excess(op: Slew, timing: RigTiming) -> float:
    """Seconds a zoom run with the move ``op`` outlasts the move's axes."""
    head = timing.head
    if not op.dzoom:
        return 0.0
    if not head.zoom_while_moving:
        raise ValueError(f"{head.name} does not zoom while it moves: price the zoom as its own Zoom")
    axes = max(head.pan.move_time(op.dpan), head.tilt.move_time(op.dtilt))
    return max(0.0, head.zoom_time(op.dzoom) - axes)


def op_time(op: Op, timing: RigTiming) -> float:
    """Seconds one operation takes on ``timing``."""
    if isinstance(op, Slew):
        return timing.head.slew_time(op.dpan, op.dtilt) + _zoom_excess(op, timing)
    if isinstance(op, Settle):
        return timing.head.settle_s
    if isinstance(op, Frames):
        return op.count * timing.camera.frame_period_s if op.continuous else timing.camera.burst_time(op.count)
    if isinstance(op, PositionRead):
        return timing.head.position_s
    if isinstance(op, Zoom):
        return timing.head.zoom_time(op.dzoom)
    if isinstance(op, Radio):
        return op.unicast * timing.radio.unicast_s + op.broadcast * timing.radio.broadcast_s
    if isinstance(op, Wait):
        return op.seconds
    raise TypeError(f"not a clock operation: {op!r}")


def price(ops: Iterable[Op], timing: RigTiming) -> FieldTime:
    """Field time per phase of operations executed one after the other."""
    phases = dict.fromkeys(PHASES, 0.0)
    for op in ops:
        if isinstance(op, Slew):  # a zoom run during the move reports what outlasts it as zoom
            phases["zoom"] += _zoom_excess(op, timing)
            phases[op.phase] = phases.get(op.phase, 0.0) + timing.head.slew_time(op.dpan, op.dtilt)
        else:
            phases[op.phase] = phases.get(op.phase, 0.0) + op_time(op, timing)
    return FieldTime(phases)


def parallel(lanes: Sequence[FieldTime]) -> FieldTime:
    """Lanes running at the same time: the field time is the longest lane (its phases reported)."""
    if not lanes:
        return ZERO
    return max(lanes, key=lambda lane: lane.total)


def sum_times(parts: Iterable[FieldTime]) -> FieldTime:
    """Phases of parts executed one after the other."""
    total = ZERO
    for p in parts:
        total = total + p
    return total
