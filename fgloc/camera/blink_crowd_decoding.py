"""Crowd routing: the view decoder's refused blobs tried as pairs and groups of three LEDs.

:func:`fgloc.camera.blink_decoder.decode_view` with ``pairs`` hands its refusals and its
single-LED readings to :func:`crowd_readings`, which tries them as two LEDs
(:func:`fgloc.camera.blink_pairs.decode_pair`) and, with ``PairConfig(max_group=3)``, as
three (:func:`fgloc.camera.blink_groups.decode_group`). Every label still comes from those
decoders (exact book words, uniqueness checked); this module only chooses where to look:

1. **Candidates.** Refusals that may be crowded LEDs (any reason but the image border and
   duplicates) within ``group_px`` of each other form one candidate, centred at their mean;
   none within ``single_px`` of a single-LED reading (that blob is one LED).
2. **Alone.** Each candidate is decoded as a pair at its centre, then as a group.
3. **With a neighbour.** Two LEDs 5-12 px apart are often seen as two blobs, each refused
   (the other's light falls in its aperture or ring), or one read and one refused. A
   candidate refused alone is decoded as a pair at the midpoint with its nearest reading
   or its nearest other candidate within ``neighbour_px`` (:func:`with_neighbour`; the
   aperture half-width widened to half their distance + 3 px). With a reading, the pair must
   contain that reading's LED (its code within ``same_px`` of it): one of the two words is
   confirmed independently.
4. **Groups with neighbours** (``max_group >= 3``): a candidate still refused is decoded as
   a group of three with its two nearest readings, both within ``neighbour_px``, which must
   both be LEDs of the group (:func:`group_with_neighbours`).
5. **One LED, one reading.** A reading whose code an earlier reading within ``same_px`` has
   is the same LED (a chain A-B-C decoded as pairs A-B and B-C reads B twice): the later
   replaces it (:func:`merge_reading`). The same code anywhere else is left to the view
   decoder, which refuses both as duplicates.
6. **Light left over.** A refused blob of a decoded candidate that lies more than
   ``explain_px`` from the decoded LEDs (the convex hull of their centroids, where a blob of
   those LEDs alone has its centroid) stays refused: it holds another LED's light. (A third
   LED 7 px beside a decoded pair was lost so: its blob counted as the pair's, the survey
   saw nothing left to chase.)
7. **Light off the LEDs.** A decoded candidate whose refused blobs step 6 dropped may still
   hold another LED, its blob's centroid pulled near the decoded ones: a peak of the lit image
   (max minus min over the samples) more than ``peak_px`` from every decoded LED (the crowd's
   and every reading's), at least a quarter as bright as the crowd's brightest pixel, is refused as an
   ambiguous blob for the survey to chase (:func:`leftover_peaks`). (At 3x in fields a third
   LED 5 px beside a decoded pair merged into one blob whose centroid lay 0.6 px from the
   pair; the zoom ladder saw nothing left, and the mote was never searched.)

Pixels: OpenCV convention (the view's).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgloc.camera.blink_codes import CodeBook
from fgloc.camera.blink_decoder import DecodedReading, RefusedBlob
from fgloc.camera.blink_groups import GroupResult, decode_group
from fgloc.camera.blink_pairs import PairConfig, PairResult, decode_pair
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pixel_to_pan_tilt

#: refusal reasons of blobs that may be two LEDs: all but the image border (a pair blinks
#: levels 0, 1, 2, which the one-LED split reads as a never-dark light, a weak LED, an
#: unknown or conflicting word, or varying lit frames)
PAIR_KINDS = ("unresolved blob", "lit frames vary", "samples one period apart", "never read cleanly",
              "no rotation of a book code", "on samples", "never dark", "on-off amplitude")


def merge_reading(readings: list[DecodedReading], rd: DecodedReading, same_px: float) -> None:
    """Add ``rd`` to ``readings`` in place: it replaces the first reading of its code within
    ``same_px`` px (the same LED, read again by a crowd decode), else it is appended."""
    for m, o in enumerate(readings):
        if o.index == rd.index and math.hypot(o.u - rd.u, o.v - rd.v) <= same_px:
            readings[m] = rd
            return
    readings.append(rd)


def _refused_pair(why: str, exclusive: tuple[int, int] = (0, 0)) -> PairResult:
    return PairResult(None, None, (math.nan, math.nan), exclusive, why)


def _confirms(index: tuple[int, ...], uv: tuple[tuple[float, float], ...], known: DecodedReading,
              same_px: float) -> bool:
    """One of the decoded LEDs (book ``index``, pixels ``uv``) is the ``known`` reading's LED."""
    return any(i == known.index and math.hypot(p[0] - known.u, p[1] - known.v) <= same_px for i, p in zip(index, uv))


def with_neighbour(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, u0: float, v0: float, book: CodeBook,
    noise_sigma: float, readings: list[DecodedReading], others: list[tuple[tuple[float, float], int]],
    cfg: PairConfig,
) -> tuple[PairResult, int | None]:
    """The refused candidate at (u0, v0) px decoded as a pair with a neighbour within
    ``cfg.neighbour_px``: the nearest reading and the nearest other candidate (``others``:
    (centre px, id)), nearer first; :func:`fgloc.camera.blink_pairs.decode_pair` at their
    midpoint, the aperture half-width ``cfg.radius_px`` or half their distance + 3 px, the
    larger. With a reading, accepted only when one LED of the pair is it (its code within
    ``cfg.same_px`` of it). Returns the result and the id of the candidate it took (None: a
    reading's, or refused)."""
    tries: list[tuple[float, float, float, DecodedReading | None, int | None]] = []
    near = sorted((math.hypot(rd.u - u0, rd.v - v0), m) for m, rd in enumerate(readings))
    if near and near[0][0] <= cfg.neighbour_px:
        rd = readings[near[0][1]]
        tries.append((near[0][0], rd.u, rd.v, rd, None))
    other = sorted((math.hypot(c[0] - u0, c[1] - v0), c, h) for c, h in others)
    if other and other[0][0] <= cfg.neighbour_px:
        d, c, h = other[0]
        tries.append((d, c[0], c[1], None, h))
    res = _refused_pair("no neighbour")
    for dist, un, vn, known, took in sorted(tries, key=lambda t: t[0]):
        wide = replace(cfg, radius_px=max(cfg.radius_px, math.ceil(0.5 * dist) + 3))
        res = decode_pair(stack, valid, positions, 0.5 * (u0 + un), 0.5 * (v0 + vn), book, noise_sigma, wide)
        if res.index is None or res.uv is None:
            continue
        if known is None:
            return res, took
        if _confirms(res.index, res.uv, known, cfg.same_px):
            return res, None
        res = _refused_pair("pair with a neighbour: neither LED is it", res.exclusive)
    return res, None


def group_with_neighbours(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, u0: float, v0: float, book: CodeBook,
    noise_sigma: float, readings: list[DecodedReading], cfg: PairConfig,
) -> GroupResult | None:
    """The refused candidate at (u0, v0) px decoded as a group of three with the two readings
    nearest it, both within ``cfg.neighbour_px`` (:func:`fgloc.camera.blink_groups.decode_group`
    at the three's mean, aperture half-width ``cfg.group_radius_px`` or the farthest of them
    + 3 px, the larger): accepted only when both readings are LEDs of the group (their codes,
    each within ``cfg.same_px`` of it). None otherwise."""
    near = sorted((math.hypot(rd.u - u0, rd.v - v0), m) for m, rd in enumerate(readings))[:2]
    if len(near) < 2 or near[1][0] > cfg.neighbour_px:
        return None
    known = [readings[m] for _, m in near]
    pts = [(u0, v0), (known[0].u, known[0].v), (known[1].u, known[1].v)]
    cu, cv = sum(p[0] for p in pts) / 3.0, sum(p[1] for p in pts) / 3.0
    reach = max(math.hypot(p[0] - cu, p[1] - cv) for p in pts)
    wide = replace(cfg, group_radius_px=max(cfg.group_radius_px, math.ceil(reach) + 3))
    grp = decode_group(stack, valid, positions, cu, cv, book, noise_sigma, wide)
    if grp.index is None or grp.uv is None or not all(_confirms(grp.index, grp.uv, k, cfg.same_px) for k in known):
        return None
    return grp


def _readings(index: tuple[int, ...], uv: tuple[tuple[float, float], ...], sigma: tuple[float, ...],
              exclusive: tuple[int, ...], intr: CameraIntrinsics, head_pan: float, head_tilt: float,
              ) -> list[DecodedReading]:
    """The readings of one decoded crowd (pair or group): each names the others."""
    out = []
    for k, ((u, v), s) in enumerate(zip(uv, sigma)):
        p_, t_ = pixel_to_pan_tilt(intr, np.array([u, v]), head_pan, head_tilt)
        rest = tuple(index[m] for m in range(len(index)) if m != k)
        out.append(DecodedReading(index[k], u, v, s, float(p_), float(t_), exclusive[k], rest[0],
                                  rest if len(index) > 2 else ()))
    return out


def crowd_readings(
    stack: np.ndarray, valid: np.ndarray, positions: np.ndarray, book: CodeBook, noise_sigma: float,
    refused: list[RefusedBlob], readings: list[DecodedReading], intr: CameraIntrinsics, head_pan: float,
    head_tilt: float, cfg: PairConfig,
) -> tuple[list[RefusedBlob], list[DecodedReading]]:
    """Steps 1-5 of the module docstring: (refusals left, every reading: the single-LED
    ``readings`` with crowd readings merged in). ``stack``, ``valid``, ``positions``: the view
    decoder's samples and fold positions; ``noise_sigma``: the detector's per-pixel noise of a
    frame difference (DN); (``head_pan``, ``head_tilt``) rad turn pixels into angles."""
    cand = [k for k, rf in enumerate(refused) if rf.kind != "duplicate" and any(s in rf.reason for s in PAIR_KINDS)]
    groups: list[list[int]] = []
    for k in cand:
        near = [g for g in groups if any(math.hypot(refused[k].u - refused[j].u, refused[k].v - refused[j].v)
                                         <= cfg.group_px for j in g)]
        groups = [g for g in groups if g not in near] + [[k] + [j for g in near for j in g]]
    centre = [(float(np.mean([refused[j].u for j in g])), float(np.mean([refused[j].v for j in g]))) for g in groups]
    singles = list(readings)
    every = list(readings)
    done: set[int] = set()

    def near_single(gi: int) -> bool:
        return any(math.hypot(rd.u - centre[gi][0], rd.v - centre[gi][1]) <= cfg.single_px for rd in singles)

    explained: dict[int, list[DecodedReading]] = {}  # candidate -> the crowd's readings

    def take(gi: int, got: list[DecodedReading], partner: int | None = None) -> None:
        done.add(gi)
        explained[gi] = got
        if partner is not None:
            explained[partner] = got
        for rd in got:
            merge_reading(every, rd, cfg.same_px)

    for gi in range(len(groups)):
        if gi in done or near_single(gi):
            continue
        u0, v0 = centre[gi]
        res = decode_pair(stack, valid, positions, u0, v0, book, noise_sigma, cfg)
        if (res.index is None or res.uv is None) and cfg.max_group >= 3:
            grp = decode_group(stack, valid, positions, u0, v0, book, noise_sigma, cfg)
            if grp.index is not None and grp.uv is not None:
                take(gi, _readings(grp.index, grp.uv, grp.sigma_px, grp.exclusive, intr, head_pan, head_tilt))
                continue
        if res.index is None or res.uv is None:
            others = [(centre[h], h) for h in range(len(groups)) if h != gi and h not in done]
            res, partner = with_neighbour(stack, valid, positions, u0, v0, book, noise_sigma, every, others, cfg)
            if res.index is not None and partner is not None:
                done.add(partner)
        else:
            partner = None
        if res.index is not None and res.uv is not None:
            take(gi, _readings(res.index, res.uv, res.sigma_px, res.exclusive, intr, head_pan, head_tilt), partner)
    if cfg.max_group >= 3:
        for gi in range(len(groups)):
            if gi in done or near_single(gi):
                continue
            grp3 = group_with_neighbours(stack, valid, positions, *centre[gi], book, noise_sigma, every, cfg)
            if grp3 is not None and grp3.index is not None and grp3.uv is not None:
                take(gi, _readings(grp3.index, grp3.uv, grp3.sigma_px, grp3.exclusive, intr, head_pan, head_tilt))
    # a refused blob off the decoded LEDs holds light of another LED: it stays refused (step 6)
    drop = {j for gi in done for j in groups[gi]
            if gi not in explained or hull_distance(refused[j].u, refused[j].v, explained[gi]) <= cfg.explain_px}
    left = [rf for k, rf in enumerate(refused) if k not in drop]
    if cfg.peak_px < math.inf:  # step 7: a peak of light off the decoded LEDs
        reach = cfg.group_radius_px + 2
        h, w = stack.shape[1:3]
        for gi in explained:
            if any(j in drop for j in groups[gi]):
                x0, y0 = max(int(round(centre[gi][0])) - reach, 0), max(int(round(centre[gi][1])) - reach, 0)
                crop = stack[:, y0:min(y0 + 2 * reach + 1, h), x0:min(x0 + 2 * reach + 1, w)][valid]
                lit = crop.max(axis=0).astype(float) - crop.min(axis=0)
                left += leftover_peaks(lit, centre[gi], every, left, noise_sigma, cfg, origin=(x0, y0))
    return left, every


def leftover_peaks(lit: np.ndarray, at: tuple[float, float], readings: list[DecodedReading],
                   refused: list[RefusedBlob], noise_sigma: float,
                   cfg: PairConfig, origin: tuple[int, int] = (0, 0)) -> list[RefusedBlob]:
    """Step 7: peaks of the lit-difference image ``lit`` (max minus min over the samples, DN;
    a crop whose top-left pixel is ``origin`` (u, v) of the view, the whole view by default)
    within ``cfg.group_radius_px`` of a decoded crowd's centre ``at`` that no decoded LED
    explains: each a local maximum over its 5 x 5 neighbourhood, at least ``cfg.peak_fraction``
    of the crowd's brightest pixel and ``cfg.peak_sigmas`` noise sigmas above the window's
    median, more than ``cfg.peak_px`` from every decoded LED (``readings``: the view's, the
    crowd's among them), and not beside a blob still refused. Each is returned as an ambiguous refused blob
    (at the peak pixel) for the survey to chase. Distances are to the LEDs themselves, not to
    their convex hull (step 6's test for a blob's centroid): two spots more than about two spot
    widths apart leave no peak between them, so a peak between two decoded LEDs is a third
    (at 3x, 1000 motes, a mote 2.4 px off the segment between a pair 11 px apart)."""
    r = cfg.group_radius_px
    h, w = lit.shape
    u0, v0 = int(round(at[0])) - origin[0], int(round(at[1])) - origin[1]
    y0, y1, x0, x1 = max(v0 - r, 0), min(v0 + r + 1, h), max(u0 - r, 0), min(u0 + r + 1, w)
    win = lit[y0:y1, x0:x1]
    if win.size == 0:
        return []
    floor = float(np.median(win))
    top = float(win.max()) - floor
    out: list[RefusedBlob] = []
    for j in range(y0, y1):
        for i in range(x0, x1):
            val = float(lit[j, i]) - floor
            if val < max(cfg.peak_fraction * top, cfg.peak_sigmas * noise_sigma):
                continue
            if lit[j, i] < lit[max(j - 2, 0):j + 3, max(i - 2, 0):i + 3].max():
                continue
            x, y = i + origin[0], j + origin[1]
            d = min(math.hypot(rd.u - x, rd.v - y) for rd in readings)
            if d <= cfg.peak_px or any(math.hypot(rf.u - x, rf.v - y) <= cfg.peak_px for rf in refused + out):
                continue
            out.append(RefusedBlob(float(x), float(y), "ambiguous",
                                   f"light {d:.1f} px from the LEDs decoded here (another LED?)"))
    return out


def hull_distance(u: float, v: float, leds: list[DecodedReading]) -> float:
    """Pixels from (u, v) to the convex hull of ``leds``' centroids (a point, a segment or a
    triangle; 0 inside): where a blob of those LEDs alone can have its centroid."""
    pts = [np.array([rd.u, rd.v], float) for rd in leds]
    x = np.array([u, v], float)
    if len(pts) >= 3:
        a, b, c = pts[:3]
        m = np.column_stack([b - a, c - a])
        if abs(np.linalg.det(m)) > 1e-9:
            s, t = np.linalg.solve(m, x - a)
            if s >= 0 and t >= 0 and s + t <= 1:
                return 0.0
    if len(pts) == 1:
        return float(np.linalg.norm(x - pts[0]))
    best = math.inf
    for i in range(len(pts)):
        for j in range(i + 1, len(pts)):
            a, d = pts[i], pts[j] - pts[i]
            t = float(np.clip((x - a) @ d / max(float(d @ d), 1e-12), 0.0, 1.0))
            best = min(best, float(np.linalg.norm(x - (a + t * d))))
    return best
