"""What one recorded view of a coded survey yields: readings, refusals, and what to do next.

Pure functions used by :mod:`fgloc.survey.coded`: the on-off centroid of a decoded LED,
the one place a decoded reading becomes a survey reading (:func:`coded_observation`),
which refused blobs may hide a mote (:func:`unexplained_blob`), when a view is recorded a
second time (:func:`needs_second_recording`), whether a probe shows an empty view
(:func:`empty_view`), and thinning blob directions into looks.
Pixels OpenCV convention; angles radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fgloc.camera.blink_decoder import DecodedReading, DecoderConfig, sample_stack
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing
from fgloc.files.journal import JournalObservation

#: refusals a second recording of the same view can cure (a noisy read), by reason prefix
_NOT_RETRIED = ("too close to the image border", "never dark")


def coded_observation(camera: str, view: str, node: str, index: int, reading: DecodedReading,
                      intr: CameraIntrinsics, head: tuple[float, float],
                      centroid: tuple[float, float] | None = None, sigma: float | None = None,
                      view_sigma: float = 0.0) -> JournalObservation:
    """The one place a decoded reading becomes a survey reading: the LED's centroid (``centroid``,
    the on-off refined one, else the decoder's) through the exact pixel -> pan-tilt composition
    (:func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt`) at the head's read-back angles
    ``head``; pan wrapped to [-pi, pi], the id of the view it came from.

    ``view_sigma`` (radians, the rig's ``head_repeatability``): the head error every reading of
    the view shares. When > 0 the reading carries it (and the view's head pan) and its ``sigma``
    as its **total** noise (``sigma``, default the survey's, of which ``view_sigma`` is the
    shared part), so survey.json names the view and a reader that ignores views still sees the
    reading's full noise. At 0 the reading is as before: the survey's sigma, no shared part."""
    u, v = (reading.u, reading.v) if centroid is None else centroid
    pan, tilt = pixel_to_pan_tilt(intr, np.array([u, v]), head[0], head[1])
    shared = view_sigma > 0.0
    return JournalObservation(node, camera, index, math.remainder(float(pan), 2 * math.pi), float(tilt),
                              sigma if shared else None, view, view_sigma if shared else None,
                              float(head[0]) if shared else None)


def unexplained_blob(refused: dict[str, Any]) -> bool:
    """A refused blob that may be a mote nobody read: ambiguous, duplicate, a code no mote runs,
    or rejected for any reason but the image border (the planners' margins put every direction
    well inside another view). A blob that never goes dark may be a lamp or several motes
    merged (measured: two motes 6 px apart at 10x zoom made one such blob), so it counts."""
    return refused["kind"] != "rejected" or not str(refused.get("reason", "")).startswith(_NOT_RETRIED[0])


def distinct_directions(pan_tilt: np.ndarray, min_angle: float) -> list[tuple[float, float]]:
    """``pan_tilt`` (M, 2) radians thinned greedily (in order) to directions at least ``min_angle`` apart."""
    kept: list[tuple[float, float]] = []
    vecs: list[np.ndarray] = []
    for p, t in np.asarray(pan_tilt, float).reshape(-1, 2):
        b = pan_tilt_bearing(float(p), float(t))
        if all(float(b @ v) < math.cos(min_angle) for v in vecs):
            kept.append((float(p), float(t)))
            vecs.append(b)
    return kept


def needs_second_recording(record: dict[str, Any]) -> bool:
    """A journaled view whose refusals a second recording may cure (rejected or duplicate blobs,
    not those at the border or steady lights)."""
    return any(r["kind"] in ("rejected", "duplicate") and not str(r.get("reason", "")).startswith(_NOT_RETRIED)
               for r in record.get("refused", []))


def on_off_centroid(stack: np.ndarray, u: float, v: float, radius: int = 3) -> tuple[float, float] | None:
    """Sub-pixel centroid of the LED near (u, v) px from the **difference** of its mean lit and
    mean dark frame (the static background and static lights cancel, as in the sequential
    survey's on-off detection): frames are split by their aperture flux (two levels, lit above
    70 % of the way from dark to lit, dark below 30 %), the centroid is the intensity-weighted
    mean over a (2 radius + 1)^2 window of the positive difference. ``stack`` (N, H, W) holds
    the view's frames. None when the window leaves the image or either level has no frame."""
    cu, cv = int(round(u)), int(round(v))
    if stack.ndim != 3:
        return None
    h, w = stack.shape[1:]
    if not (radius <= cu < w - radius and radius <= cv < h - radius):
        return None
    win = stack[:, cv - radius: cv + radius + 1, cu - radius: cu + radius + 1].astype(np.float32)
    flux = win.reshape(len(win), -1).sum(axis=1)
    lo, hi = float(np.min(flux)), float(np.max(flux))
    lit, dark = flux >= lo + 0.7 * (hi - lo), flux <= lo + 0.3 * (hi - lo)
    if not lit.any() or not dark.any() or hi <= lo:
        return None
    diff = np.clip(win[lit].mean(axis=0) - win[dark].mean(axis=0), 0.0, None)
    total = float(diff.sum())
    if total <= 0.0:
        return None
    ys, xs = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return cu + float((diff * xs).sum()) / total, cv + float((diff * ys).sum()) / total


def reading_centroid(stack: np.ndarray, u: float, v: float, partner: int | None,
                     first_frames: int | None = None) -> tuple[float, float]:
    """Where a decoded LED lies in its view, pixels: its decoder's (u, v) for a pair-decoded
    LED (``partner``; its window holds both LEDs), else the on-off centroid
    (:func:`on_off_centroid`) of the view's frames ``stack``, of its first ``first_frames``
    only for a reading the first window's decode added (``first_window "kept"``: late light
    spoilt the whole recording's blob, and would pull the centroid); (u, v) when there is none."""
    if partner is not None:
        return u, v
    frames = stack if first_frames is None else stack[:first_frames]
    return on_off_centroid(frames, u, v) or (u, v)


def into_search_box(pan: float, tilt: float, pan_min: float, pan_max: float, tilt_min: float, tilt_max: float,
                    ) -> tuple[float, float]:
    """The head position nearest to (pan, tilt) inside the search box (pan wrapped first, as
    :meth:`fgloc.camera.led_search.LedLocator.clamp`). A planned view may be centred beyond the
    box (its tiles reach past it); moved back to the box edge it still covers every target it
    covered inside the box, and a head that enforces its range accepts it."""
    if pan_max - pan_min < 2 * math.pi - 1e-9:
        pan = pan_min + (pan - pan_min) % (2 * math.pi)
        if pan > pan_max:  # in the gap: the nearer limit
            pan = pan_max if pan - pan_max <= pan_min + 2 * math.pi - pan else pan_min
    else:
        pan = math.remainder(pan, 2 * math.pi)
    return pan, min(max(tilt, tilt_min), tilt_max)


def empty_view(frames: list[tuple[float, np.ndarray]], period: float, config: DecoderConfig) -> bool:
    """True when ``frames`` (a probe of at least L + 2 frames: every blinking mote's word has
    both bits in any L samples) show no blob at all: nothing the decoder's detector
    (:func:`fgloc.camera.led_detection.detect_led` on the per-pixel maximum and minimum over
    the delivered samples) finds or even rejects. Fewer than two delivered samples: not empty."""
    from fgloc.camera.led_detection import detect_led

    stack, valid = sample_stack(frames, period)
    good = stack[valid]
    if len(good) < 2:
        return False
    det = detect_led(good.max(axis=0), good.min(axis=0), config.detector)
    return not det.candidates and not det.rejected
