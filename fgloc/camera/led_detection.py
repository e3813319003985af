"""Find one blinking LED in a pair of frames (LED on, LED off) with a sub-pixel centroid.

Method:

1. ``diff = on - off`` (float, grayscale). Static scene content, ambient light
   and static bright spots cancel; only what changed remains.
2. Noise: the median difference (a global ambient change) is removed. The
   difference's noise grows with brightness (shot noise), so a robust sigma
   (1.4826 x MAD) is measured per band of the LED-off frame's intensity,
   interpolated between bands and extrapolated with the fitted shot-noise slope
   to bright static lights too few to measure alone. A pixel is a candidate when
   ``diff > threshold_sigma * sigma(off)``. Saturated LED-off pixels are ignored.
3. 8-connected components of candidate pixels. Blobs are rejected when they
   are too small (noise), too large (a light switched, a person walked by),
   too elongated (motion, edges), too weak at their peak, or cut by the image
   border (their centroid would be biased).
4. Centroid: intensity-weighted mean of the *unclipped* difference in a square
   window centred on the blob, iterated twice (unbiased for a symmetric spot;
   zero-mean noise adds no bias). Pixel convention as OpenCV: the centre of
   the top-left pixel is (0, 0).
5. Exactly one surviving blob: FOUND. None: NOT_FOUND. More than one:
   AMBIGUOUS with all candidates listed; the detector never picks one.

Each detection carries a confidence in [0, 1] and a centroid standard
deviation (pixels) propagated from the noise estimate.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import cv2
import numpy as np

from fgloc.core.errors import FglocError


class DetectionInputError(FglocError):
    """Frames that cannot be compared (shape or type mismatch)."""


class DetectionStatus(str, enum.Enum):
    """Outcome of looking for one LED."""

    FOUND = "found"
    NOT_FOUND = "not_found"
    AMBIGUOUS = "ambiguous"


@dataclass(frozen=True)
class DetectorConfig:
    """Detection thresholds. Pixel units; ``*_sigma`` in multiples of the local noise sigma."""

    threshold_sigma: float = 6.0  #: per-pixel candidate threshold
    min_peak_sigma: float = 10.0  #: a blob's brightest difference pixel must exceed this
    min_area: int = 3  #: fewest candidate pixels in a blob
    max_area: int = 400  #: most candidate pixels in a blob
    max_elongation: float = 3.0  #: largest ratio of the blob's principal standard deviations
    min_fill: float = 0.3  #: smallest ratio of blob area to its bounding-box area
    window_sigmas: float = 2.5  #: centroid window half-size in spot standard deviations
    noise_floor: float = 0.4  #: lower bound for the noise sigma (uint8 quantisation ~0.29 DN)
    noise_bands: int = 8  #: intensity bands for the noise model
    saturation: float = 254.5  #: LED-off pixels at or above this (DN) are ignored
    max_blobs: int = 50  #: more changed regions than this means the view changed: nothing is reported


@dataclass(frozen=True)
class LedDetection:
    """One LED blob: centroid ``(u, v)`` in pixels, its standard deviation ``sigma_px``,
    blob ``area`` (pixels), ``peak`` and ``flux`` (summed difference, DN), ``snr``
    (flux over its noise) and ``confidence`` in [0, 1]."""

    u: float
    v: float
    sigma_px: float
    area: int
    peak: float
    flux: float
    snr: float
    confidence: float

    @property
    def uv(self) -> tuple[float, float]:
        return (self.u, self.v)


@dataclass(frozen=True)
class RejectedBlob:
    """A blob that passed the pixel threshold but not the shape tests, with the reason."""

    u: float
    v: float
    area: int
    reason: str


@dataclass(frozen=True)
class DetectionResult:
    """The answer to "where is the LED?": status, the detection when FOUND, every plausible
    candidate (several when AMBIGUOUS), rejected blobs, and the noise sigma (DN) at the dark end."""

    status: DetectionStatus
    detection: LedDetection | None
    candidates: tuple[LedDetection, ...]
    rejected: tuple[RejectedBlob, ...]
    noise_sigma: float

    @property
    def found(self) -> bool:
        return self.status is DetectionStatus.FOUND


def to_gray(frame: np.ndarray) -> np.ndarray:
    """Grayscale float32 view of a (H, W) or (H, W, 3) BGR frame."""
    a = np.asarray(frame)
    if a.ndim == 3 and a.shape[2] == 3:
        a = cv2.cvtColor(a.astype(np.float32), cv2.COLOR_BGR2GRAY)
    elif a.ndim != 2:
        raise DetectionInputError(f"frame: expected (H, W) or (H, W, 3), got shape {a.shape}")
    return a.astype(np.float32, copy=False)


def noise_model(diff: np.ndarray, off: np.ndarray, config: DetectorConfig) -> tuple[float, np.ndarray]:
    """Robust offset (DN) and per-pixel noise sigma (DN) of ``diff`` given the LED-off intensity.

    The offset is the median difference (a global ambient change between the two frames).
    Sigma is 1.4826 x MAD measured per band of (3x3-smoothed) ``off`` intensity, made
    non-decreasing and interpolated between band centres, held constant below the darkest
    band, and extrapolated above the brightest band with the shot-noise slope
    ``d sigma^2 / d off`` fitted across the bands, so it covers bright static lights too
    few to be measured on their own.
    """
    step = max(1, int(math.sqrt(diff.size / 20_000)))  # ~20k samples suffice for medians
    level = cv2.blur(off, (3, 3))
    d = diff[::step, ::step].ravel()
    o = level[::step, ::step].ravel()
    offset = float(np.median(d))
    d = d - offset
    edges = np.unique(np.quantile(o, np.linspace(0.0, 1.0, config.noise_bands + 1)))
    band = np.clip(np.searchsorted(edges, o, side="right") - 1, 0, max(edges.size - 2, 0))
    centres, sigmas, weights = [], [], []
    for b in range(max(edges.size - 1, 1)):
        sel = band == b
        if np.count_nonzero(sel) < 50:
            continue
        centres.append(float(np.median(o[sel])))
        sigmas.append(max(1.4826 * float(np.median(np.abs(d[sel]))), config.noise_floor))
        weights.append(float(np.count_nonzero(sel)))
    if not centres:
        sig = max(1.4826 * float(np.median(np.abs(d))), config.noise_floor)
        return offset, np.full(diff.shape, sig, dtype=np.float32)
    c = np.array(centres)
    sg = np.maximum.accumulate(np.array(sigmas))
    slope = 0.0
    if c.size >= 2 and np.ptp(c) > 1.0:
        w = np.array(weights)
        cm = np.average(c, weights=w)
        vm = np.average(sg**2, weights=w)
        slope = max(float(np.sum(w * (c - cm) * (sg**2 - vm)) / np.sum(w * (c - cm) ** 2)), 0.0)
    sigma = np.interp(level, c, sg).astype(np.float32)
    above = level > c[-1]
    if slope > 0.0 and np.any(above):
        sigma[above] = np.sqrt(sg[-1] ** 2 + slope * (level[above] - c[-1]))
    return offset, sigma


def _centroid(diff: np.ndarray, u0: float, v0: float, half: int) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    """Weighted centroid in a (2 half + 1)^2 window centred on round(u0, v0), clipped to the image."""
    h, w = diff.shape
    cu, cv = int(round(u0)), int(round(v0))
    r0, r1 = max(cv - half, 0), min(cv + half + 1, h)
    c0, c1 = max(cu - half, 0), min(cu + half + 1, w)
    win = diff[r0:r1, c0:c1].astype(np.float64)
    total = float(win.sum())
    jj = np.arange(c0, c1, dtype=np.float64)
    ii = np.arange(r0, r1, dtype=np.float64)
    if total <= 0.0:
        return u0, v0, total, jj, ii
    u = float((win.sum(axis=0) * jj).sum() / total)
    v = float((win.sum(axis=1) * ii).sum() / total)
    return u, v, total, jj, ii


def detect_led(on: np.ndarray, off: np.ndarray, config: DetectorConfig | None = None) -> DetectionResult:
    """Locate the single LED lit in ``on`` and dark in ``off`` (same camera pose and exposure)."""
    cfg = config or DetectorConfig()
    on_g, off_g = to_gray(on), to_gray(off)
    if on_g.shape != off_g.shape:
        raise DetectionInputError(f"frames: LED-on shape {on_g.shape} differs from LED-off shape {off_g.shape}")
    diff = on_g - off_g
    offset, sigma_map = noise_model(diff, off_g, cfg)
    diff -= offset
    diff[off_g >= cfg.saturation] = 0.0  # nothing can be seen in front of a saturated static spot
    snr_map = diff / sigma_map
    mask = (snr_map > cfg.threshold_sigma).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    candidates: list[LedDetection] = []
    rejected: list[RejectedBlob] = []
    dark_sigma = float(sigma_map.min())
    sizeable = int(np.count_nonzero(stats[1:, cv2.CC_STAT_AREA] >= cfg.min_area))
    if sizeable > cfg.max_blobs:
        why = f"{sizeable} changed regions > {cfg.max_blobs}: the scene or the camera moved between the frames"
        blob = RejectedBlob(u=math.nan, v=math.nan, area=int(mask.sum()), reason=why)
        return DetectionResult(DetectionStatus.NOT_FOUND, None, (), (blob,), dark_sigma)
    for k in range(1, n):
        x, y, bw, bh, area = (int(s) for s in stats[k])
        ys, xs = np.nonzero(labels[y : y + bh, x : x + bw] == k)
        wts = diff[y + ys, x + xs].astype(np.float64)
        mu = float((xs * wts).sum() / wts.sum()) + x
        mv = float((ys * wts).sum() / wts.sum()) + y
        reason = None
        peak_snr = float(snr_map[y + ys, x + xs].max())
        if area < cfg.min_area:
            reason = f"area {area} < {cfg.min_area} px"
        elif area > cfg.max_area:
            reason = f"area {area} > {cfg.max_area} px"
        elif peak_snr < cfg.min_peak_sigma:
            reason = f"peak {peak_snr:.1f} sigma < {cfg.min_peak_sigma}"
        elif area / float(bw * bh) < cfg.min_fill:
            reason = f"fill {area / float(bw * bh):.2f} < {cfg.min_fill}"
        else:
            cov = np.cov(np.stack([xs, ys]).astype(float), aweights=np.maximum(wts, 1e-9)) if area > 1 else np.eye(2)
            ev = np.linalg.eigvalsh(np.atleast_2d(cov) + 1e-3 * np.eye(2))
            elong = math.sqrt(ev[1] / ev[0])
            if elong > cfg.max_elongation:
                reason = f"elongation {elong:.1f} > {cfg.max_elongation}"
        if reason is not None:
            rejected.append(RejectedBlob(u=mu, v=mv, area=area, reason=reason))
            continue
        # Spot width from flux and peak (a Gaussian has flux = 2 pi sigma^2 peak), measured in a
        # generous window; the centroid window then spans +- window_sigmas spot widths.
        peak = float(diff[y + ys, x + xs].max())
        _, _, wide_flux, _, _ = _centroid(diff, mu, mv, int(math.ceil(math.sqrt(area / math.pi))) + 3)
        spot_sigma = math.sqrt(max(wide_flux, peak) / (2.0 * math.pi * peak))
        half = max(int(math.ceil(cfg.window_sigmas * spot_sigma)), 2)
        u, v = mu, mv
        for _ in range(3):
            u, v, total, jj, ii = _centroid(diff, u, v, half)
        if len(jj) < 2 * half + 1 or len(ii) < 2 * half + 1:
            rejected.append(RejectedBlob(u=u, v=v, area=area, reason="spot cut by the image border"))
            continue
        cu, cv = int(round(u)), int(round(v))
        win_sigma = sigma_map[max(cv - half, 0) : cv + half + 1, max(cu - half, 0) : cu + half + 1]
        s = float(np.mean(win_sigma))
        npix = win_sigma.size
        flux_sigma = s * math.sqrt(npix)
        snr = total / flux_sigma if flux_sigma > 0 else float("inf")
        var_u = s * s * float(((jj - u) ** 2).sum()) * len(ii) / max(total, 1e-12) ** 2
        var_v = s * s * float(((ii - v) ** 2).sum()) * len(jj) / max(total, 1e-12) ** 2
        sigma_px = math.sqrt(0.5 * (var_u + var_v))
        # Confidence: 1 for a strong, precise blob, falling as the flux approaches the noise.
        confidence = float(1.0 - math.exp(-((snr / (4.0 * cfg.threshold_sigma)) ** 2)))
        candidates.append(
            LedDetection(u=u, v=v, sigma_px=sigma_px, area=area, peak=peak,
                         flux=total, snr=snr, confidence=confidence)
        )
    if len(candidates) == 1:
        return DetectionResult(DetectionStatus.FOUND, candidates[0], tuple(candidates), tuple(rejected), dark_sigma)
    status = DetectionStatus.NOT_FOUND if not candidates else DetectionStatus.AMBIGUOUS
    return DetectionResult(status, None, tuple(candidates), tuple(rejected), dark_sigma)
