"""Device counts <-> the spec's pan/tilt convention, in ONE place.

Every PTZ driver converts through :class:`PanTiltUnits`; nothing else in the
code base knows about counts, signs, zero offsets or mounting.

Conventions
-----------
*Device frame* (what a Sony VISCA head reports, ``shared/reference/protocols.md``
1.8): counts are signed 16-bit, ``deg = counts / counts_per_deg``, positive pan
turns the image **right** (clockwise seen from above for an upright head),
positive tilt turns it **up**.

*Spec frame* (``docs/file-format.md``): radians, pan counter-clockwise
seen from above about the base z axis (zero along base x), tilt = elevation
above the base x-y plane, positive up. The base frame is the one the solver
estimates; we keep its z axis pointing to the world's up for both mountings so
planar surveys stay near-identity in roll/pitch.

*Mounting* maps one to the other: ``spec = sign * device + zero``.

* ``desk`` (upright head): pan_sign = -1 (device right = clockwise = spec
  negative), tilt_sign = +1.
* ``ceiling`` (head hung upside down, camera image flip OFF): the head is the
  desk head turned 180 degrees about its forward axis, so the device's "right"
  is counter-clockwise seen from the floor's above and its "up" points at the
  floor: pan_sign = +1, tilt_sign = -1. A camera whose firmware already flips
  the reported angles (Sony "image flip"/ceiling mode) is then ``desk`` again;
  verify once per installation by commanding +10 degrees and watching the image
  (protocols.md 1.8 and 2.2).
* custom signs and zero offsets (degrees) for anything else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fgloc.core.errors import FglocError


class PositionOutOfRangeError(FglocError):
    """A requested pan/tilt (or zoom) lies outside the head's mechanical range."""


@dataclass(frozen=True)
class CameraModel:
    """Per-model VISCA units and ranges (data, not code; protocols.md 1.8-1.9).

    Counts are signed device counts; speeds are VISCA speed bytes with their
    angular speeds in degrees/second (index 0 is speed byte 0x01).
    """

    name: str
    pan_counts_per_deg: float
    tilt_counts_per_deg: float
    pan_min: int
    pan_max: int
    tilt_min: int
    tilt_max: int
    max_pan_speed: int
    max_tilt_speed: int
    pan_speed_dps: tuple[float, ...]
    tilt_speed_dps: tuple[float, ...]
    zoom_optical_tele: int
    zoom_max: int
    pan_nibbles: int = 4
    hfov_wide_deg: float | None = None
    hfov_tele_deg: float | None = None
    verified: bool = True
    note: str = ""

    def pan_speed(self, speed_byte: int) -> float:
        """Pan speed in degrees/second for a VISCA pan speed byte."""
        return self.pan_speed_dps[max(1, min(speed_byte, len(self.pan_speed_dps))) - 1]

    def tilt_speed(self, speed_byte: int) -> float:
        """Tilt speed in degrees/second for a VISCA tilt speed byte."""
        return self.tilt_speed_dps[max(1, min(speed_byte, len(self.tilt_speed_dps))) - 1]

    def move_seconds(self, dpan_counts: int, dtilt_counts: int, pan_speed: int, tilt_speed: int) -> float:
        """Nominal time (s) of an absolute move of the given count deltas (axes move together)."""
        tp = abs(dpan_counts) / self.pan_counts_per_deg / self.pan_speed(pan_speed)
        tt = abs(dtilt_counts) / self.tilt_counts_per_deg / self.tilt_speed(tilt_speed)
        return max(tp, tt)


# EVI-D100 speed table, [D100] p.44 (degrees/second for bytes 0x01..0x18; tilt stops at 0x14).
_D100_SPEED = (2.0, 2.4, 3.0, 3.7, 4.7, 6.1, 7.4, 9.1, 11.0, 14.0, 18.0, 22.0,
               27.0, 34.0, 42.0, 52.0, 65.0, 81.0, 100.0, 125.0, 155.0, 190.0, 240.0, 300.0)


def _linear(lo: float, hi: float, n: int) -> tuple[float, ...]:
    return tuple(lo + (hi - lo) * i / (n - 1) for i in range(n))


EVI_D100 = CameraModel(
    name="EVI-D100", pan_counts_per_deg=14.4, tilt_counts_per_deg=14.4,
    pan_min=-1440, pan_max=1440, tilt_min=-360, tilt_max=360,
    max_pan_speed=0x18, max_tilt_speed=0x14,
    pan_speed_dps=_D100_SPEED, tilt_speed_dps=_D100_SPEED[:0x14],
    zoom_optical_tele=0x4000, zoom_max=0x7000, hfov_wide_deg=65.0, hfov_tele_deg=6.6,
    note="Sony technical manual; the D30/D31 mode switch must be OFF",
)
EVI_D30 = CameraModel(
    name="EVI-D30", pan_counts_per_deg=8.8, tilt_counts_per_deg=12.0,
    pan_min=-880, pan_max=880, tilt_min=-300, tilt_max=300,
    max_pan_speed=0x18, max_tilt_speed=0x14,
    pan_speed_dps=_linear(3.3, 80.0, 0x18), tilt_speed_dps=_linear(2.5, 50.0, 0x14),
    zoom_optical_tele=0x03FF, zoom_max=0x03FF, hfov_wide_deg=48.8, hfov_tele_deg=4.4,
    note="also the EVI-D31 and an EVI-D100 with its D30/D31 switch ON",
)
EVI_D70 = CameraModel(
    name="EVI-D70", pan_counts_per_deg=2267 / 170, tilt_counts_per_deg=2267 / 170,
    pan_min=-2267, pan_max=2267, tilt_min=-400, tilt_max=1200,
    max_pan_speed=0x18, max_tilt_speed=0x17,
    pan_speed_dps=_D100_SPEED, tilt_speed_dps=_D100_SPEED[:0x17],
    zoom_optical_tele=0x4000, zoom_max=0x7AC0, hfov_wide_deg=48.0, hfov_tele_deg=2.7,
    verified=False, note="ranges from the D70 manual (image flip off); speed table assumed like the D100",
)
EVI_D80 = CameraModel(
    name="EVI-D80", pan_counts_per_deg=7707 / 170, tilt_counts_per_deg=7707 / 170,
    pan_min=-7707, pan_max=7707, tilt_min=-907, tilt_max=4080,
    max_pan_speed=0x18, max_tilt_speed=0x17,
    pan_speed_dps=_D100_SPEED, tilt_speed_dps=_D100_SPEED[:0x17],
    zoom_optical_tele=0x4000, zoom_max=0x4000,
    verified=False, note="EVI-D80/D90 ranges from the D80 manual; speed table assumed like the D100",
)
SNC_RZ25N = CameraModel(
    name="SNC-RZ25N", pan_counts_per_deg=14.4, tilt_counts_per_deg=14.4,
    pan_min=-2448, pan_max=2448, tilt_min=-1296, tilt_max=360,
    max_pan_speed=0x18, max_tilt_speed=0x18,
    pan_speed_dps=_D100_SPEED, tilt_speed_dps=_D100_SPEED,
    zoom_optical_tele=0x4000, zoom_max=0x4000,
    verified=False,
    note="UNVERIFIED: 14.4 counts/deg and +-170 deg from the sibling SNC-RZ30N; sign may be flipped (protocols.md 2.2)",
)
VISCA_IP_GENERIC = CameraModel(
    name="VISCA-IP", pan_counts_per_deg=14.4, tilt_counts_per_deg=14.4,
    pan_min=-2448, pan_max=2448, tilt_min=-432, tilt_max=1296,
    max_pan_speed=0x18, max_tilt_speed=0x17,
    pan_speed_dps=_D100_SPEED, tilt_speed_dps=_D100_SPEED[:0x17],
    zoom_optical_tele=0x4000, zoom_max=0x4000,
    verified=False, note="SRG/BRC/PTZOptics class (third-party table); check per model",
)

CAMERA_MODELS: dict[str, CameraModel] = {
    m.name.lower(): m for m in (EVI_D100, EVI_D30, EVI_D70, EVI_D80, SNC_RZ25N, VISCA_IP_GENERIC)
}
CAMERA_MODELS["evi-d31"] = EVI_D30
CAMERA_MODELS["evi-d90"] = EVI_D80


def camera_model(name: str) -> CameraModel:
    """Look up a model by (case-insensitive) name, e.g. ``EVI-D100``."""
    try:
        return CAMERA_MODELS[name.lower()]
    except KeyError:
        known = ", ".join(sorted(CAMERA_MODELS))
        raise FglocError(f"--camera-model: unknown model {name!r} (known: {known})") from None


@dataclass(frozen=True)
class Mounting:
    """How the head is mounted: ``spec_deg = sign * device_deg + zero_deg`` per axis."""

    name: str
    pan_sign: int = -1
    tilt_sign: int = 1
    pan_zero_deg: float = 0.0
    tilt_zero_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.pan_sign not in (-1, 1) or self.tilt_sign not in (-1, 1):
            raise FglocError(f"mounting {self.name}: signs must be +1 or -1")


DESK = Mounting("desk", pan_sign=-1, tilt_sign=1)
CEILING = Mounting("ceiling", pan_sign=1, tilt_sign=-1)
MOUNTINGS: dict[str, Mounting] = {"desk": DESK, "upright": DESK, "ceiling": CEILING}


def mounting(name: str) -> Mounting:
    """Look up a mounting preset (``desk``/``upright`` or ``ceiling``)."""
    try:
        return MOUNTINGS[name.lower()]
    except KeyError:
        raise FglocError(f"--mount: unknown mounting {name!r} (known: ceiling, desk)") from None


@dataclass(frozen=True)
class PanTiltUnits:
    """Converter between device counts and spec radians for one camera model and mounting."""

    model: CameraModel = EVI_D100
    mount: Mounting = field(default=DESK)

    # ---- counts -> spec
    def to_spec(self, pan_counts: int, tilt_counts: int) -> tuple[float, float]:
        """Device counts -> spec (pan, tilt) in radians; pan wrapped into (-pi, pi]."""
        pan_dev = pan_counts / self.model.pan_counts_per_deg
        tilt_dev = tilt_counts / self.model.tilt_counts_per_deg
        pan = self.mount.pan_sign * pan_dev + self.mount.pan_zero_deg
        tilt = self.mount.tilt_sign * tilt_dev + self.mount.tilt_zero_deg
        return _wrap_rad(math.radians(pan)), math.radians(tilt)

    # ---- spec -> counts
    def to_counts(self, pan: float, tilt: float) -> tuple[int, int]:
        """Spec (pan, tilt) radians -> device counts; raises PositionOutOfRangeError outside limits."""
        if not (math.isfinite(pan) and math.isfinite(tilt)):
            raise PositionOutOfRangeError(f"pan/tilt must be finite, got ({pan}, {tilt})")
        pan_rel = _wrap_deg(math.degrees(pan) - self.mount.pan_zero_deg)
        tilt_rel = math.degrees(tilt) - self.mount.tilt_zero_deg
        pan_counts = round(self.mount.pan_sign * pan_rel * self.model.pan_counts_per_deg)
        tilt_counts = round(self.mount.tilt_sign * tilt_rel * self.model.tilt_counts_per_deg)
        m = self.model
        if not m.pan_min <= pan_counts <= m.pan_max:
            raise PositionOutOfRangeError(
                f"pan {math.degrees(pan):.2f} deg is outside the {m.name} range "
                f"({self._pan_limits_text()}, mount {self.mount.name})")
        if not m.tilt_min <= tilt_counts <= m.tilt_max:
            raise PositionOutOfRangeError(
                f"tilt {math.degrees(tilt):.2f} deg is outside the {m.name} range "
                f"({self._tilt_limits_text()}, mount {self.mount.name})")
        return pan_counts, tilt_counts

    def pan_resolution(self) -> float:
        """Size of one pan count in radians."""
        return math.radians(1.0 / self.model.pan_counts_per_deg)

    def tilt_resolution(self) -> float:
        """Size of one tilt count in radians."""
        return math.radians(1.0 / self.model.tilt_counts_per_deg)

    # ---- zoom
    def zoom_to_counts(self, fraction: float) -> int:
        """Zoom fraction of the optical range (0 wide ... 1 optical tele) -> zoom counts."""
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise PositionOutOfRangeError(f"zoom {fraction} is outside 0..1 (wide..optical tele)")
        return round(fraction * self.model.zoom_optical_tele)

    def zoom_from_counts(self, counts: int) -> float:
        """Zoom counts -> fraction of the optical range (may exceed 1 in the digital range)."""
        return counts / self.model.zoom_optical_tele

    def _pan_limits_text(self) -> str:
        a, _ = self.to_spec(self.model.pan_min, 0)
        b, _ = self.to_spec(self.model.pan_max, 0)
        lo, hi = sorted((math.degrees(a), math.degrees(b)))
        return f"{lo:.1f}..{hi:.1f} deg"

    def _tilt_limits_text(self) -> str:
        _, a = self.to_spec(0, self.model.tilt_min)
        _, b = self.to_spec(0, self.model.tilt_max)
        lo, hi = sorted((math.degrees(a), math.degrees(b)))
        return f"{lo:.1f}..{hi:.1f} deg"


def _wrap_deg(deg: float) -> float:
    """Wrap degrees into (-180, 180]."""
    w = math.fmod(deg + 180.0, 360.0)
    if w <= 0.0:
        w += 360.0
    return w - 180.0


def _wrap_rad(rad: float) -> float:
    """Wrap radians into (-pi, pi]."""
    w = math.fmod(rad + math.pi, 2 * math.pi)
    if w <= 0.0:
        w += 2 * math.pi
    return w - math.pi
