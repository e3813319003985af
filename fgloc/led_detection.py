"""Find one blinking LED in a pair of frames (LED on, LED off) with a sub-pixel centroid.

Method:

1. ``diff = on - off`` (float, grayscale). Static scene content, ambient light
   and static bright spots cancel; only what changed remains.
2. Noise: the median difference (a global ambient change) is removed. The
   difference's noise grows with brightness (shot noise), so a robust sigma
   (1.4826 x MAD) is measured per band of the LED-off frame's intensity and the
   sensor model ``sigma^2 = a + b * off`` is fitted to it; it extrapolates to
   bright static lights too few to measure alone. A pixel is a candidate when
   ``diff > threshold_sigma * sigma(off)``. Saturated LED-off pixels are ignored.
3. 8-connected components of candidate pixels. Blobs are rejected when they
   are too small (noise), too large (a light switched, a person walked by),
   too elongated (motion, edges) or too weak at their peak.
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

from fgloc.model import FglocError


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
    window_margin: int = 1  #: centroid window half-size = blob radius + this (>= 3 in all)
    noise_floor: float = 0.4  #: lower bound for the noise sigma (uint8 quantisation ~0.29 DN)
    noise_bands: int = 8  #: intensity bands for the noise model
    saturation: float = 254.5  #: LED-off pixels at or above this (DN) are ignored


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
    Sigma follows the sensor model ``sigma^2 = a + b * off`` (read noise plus shot noise),
    fitted with non-negative a, b to 1.4826 x MAD per band of ``off``, so it extrapolates to
    bright static spots that are too few to be measured on their own.
    """
    step = max(1, int(math.sqrt(diff.size / 20_000)))  # ~20k samples suffice for medians
    d = diff[::step, ::step].ravel()
    o = off[::step, ::step].ravel()
    offset = float(np.median(d))
    d = d - offset
    edges = np.unique(np.quantile(o, np.linspace(0.0, 1.0, config.noise_bands + 1)))
    centres, variances, weights = [], [], []
    band = np.clip(np.searchsorted(edges, o, side="right") - 1, 0, max(edges.size - 2, 0))
    for b in range(max(edges.size - 1, 1)):
        sel = band == b
        if np.count_nonzero(sel) < 50:
            continue
        s = 1.4826 * float(np.median(np.abs(d[sel])))
        centres.append(float(np.median(o[sel])))
        variances.append(s * s)
        weights.append(float(np.count_nonzero(sel)))
    floor2 = config.noise_floor**2
    if len(centres) >= 2 and np.ptp(centres) > 1.0:
        A = np.stack([np.ones(len(centres)), np.array(centres)], axis=1) * np.sqrt(weights)[:, None]
        coef, *_ = np.linalg.lstsq(A, np.array(variances) * np.sqrt(weights), rcond=None)
        a, b = float(coef[0]), max(float(coef[1]), 0.0)
        if a < floor2:  # refit the slope with the intercept pinned at the floor
            a = floor2
            x = np.array(centres)
            b = max(float(np.sum(np.array(weights) * x * (np.array(variances) - a)) / np.sum(np.array(weights) * x * x)), 0.0)
    else:
        a, b = max(float(np.mean(variances)) if variances else floor2, floor2), 0.0
    sigma = np.sqrt(np.maximum(a + b * off, floor2)).astype(np.float32)
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
        half = max(int(math.ceil(math.sqrt(area / math.pi))) + cfg.window_margin, 3)
        u, v = mu, mv
        for _ in range(3):
            u, v, total, jj, ii = _centroid(diff, u, v, half)
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
            LedDetection(u=u, v=v, sigma_px=sigma_px, area=area, peak=float(diff[y + ys, x + xs].max()),
                         flux=total, snr=snr, confidence=confidence)
        )
    dark_sigma = float(sigma_map.min())
    if len(candidates) == 1:
        return DetectionResult(DetectionStatus.FOUND, candidates[0], tuple(candidates), tuple(rejected), dark_sigma)
    status = DetectionStatus.NOT_FOUND if not candidates else DetectionStatus.AMBIGUOUS
    return DetectionResult(status, None, tuple(candidates), tuple(rejected), dark_sigma)
