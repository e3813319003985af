"""Decode the blink codes of every mote in one view: IDs, sub-pixel centroids, (pan, tilt).

Input: the frames one camera recorded with its head still at a read-back (pan, tilt),
each with a timestamp (seconds), at a nominal frame period equal to the motes' bit
period, and the :class:`~fgloc.camera.blink_codes.CodeBook`. Steps:

1. **Samples.** Each frame's timestamp gives its sample index ``round((t - t_first) /
   period)``; a missing index (dropped frame) is an erasure, a second frame on one index
   is ignored, and a frame identical to the previous delivered one (a grabber repeating a
   stale buffer) is an erasure.
2. **Blobs.** The per-pixel maximum and minimum over the stack are compared with
   :func:`fgloc.camera.led_detection.detect_led` (on = max, off = min): static scene and
   static lights cancel; everything that changed is a candidate blob.
3. **Levels.** Per frame, each blob's flux is the sum over a small aperture minus the
   aperture's share of the median of a surrounding annulus (a global ambient change
   cancels). The fluxes are split into an off and an on level (two-means); the on-off
   amplitude must exceed ``min_snr`` flux sigmas, the off level must be that of the
   background (a flickering lamp never goes dark; an LED does), and each sample within
   ``level_band`` x amplitude of its level is a bit, anything between is an erasure.
4. **Word.** With L the book's length, samples ``i`` and ``i + L`` carry the same bit:
   every bit position needs at least one sample, and all samples of a position must
   agree. The folded word must equal a rotation of a book word **exactly**; with a
   book distance of 3, up to two bit errors are detected, never corrected. With
   ``DecoderConfig.word_fit`` (off by default; rotation-free books) a blob rejected in
   steps 3-4 gets a second look, the light-curve fit (:func:`fit_blob`,
   :mod:`fgloc.camera.blink_word_fit`), and keeps its refusal unless that names one word.
5. **Refusals.** A blob whose on-frame fluxes or centroids vary more than one LED's
   can (two LEDs closer than the detector separates) is reported *ambiguous*. An ID
   decoded from two blobs is reported *duplicate* for both. Unknown words, conflicts
   and incomplete words are *rejected* with the reason. Nothing is ever guessed. With
   ``pairs`` (off by default) refused blobs are tried as two LEDs and labelled by both
   code words when that is unique (:mod:`fgloc.camera.blink_pairs`); with
   ``PairConfig(max_group=3)`` a refused pair is tried as three LEDs (:mod:`fgloc.camera.blink_groups`).
6. **Angles.** The decoded centroid (mean over on frames) becomes (pan, tilt) by the
   exact composition :func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt`.

**Synchronized books** (``sync``, :class:`SyncTiming`): every mote started its word at a
broadcast epoch, so sample ``i`` (mid-exposure time ``t_i``) is folded at bit position
``floor((t_i - epoch) / bit_period) mod L`` instead of ``i mod L``, and the folded word
must match a book word exactly at the expected alignment or at the one neighbouring
shift towards the nearer bit edge (:meth:`CodeBook.identify_synchronized`): a mote whose
clock is off by less than half a bit is read at one of the two.

**Sliding windows** (:func:`decode_windows`): a continuous recording is decoded in
windows of ``window`` samples every ``step`` samples; a mote missed in one window (a
burst of drops, a glint crossing it) is usually read in the next. Readings of one code
from different windows must agree in position (else the code is refused as a
duplicate), one blob may carry only one code (else both are refused), and a code
refused as duplicate in any window is refused.

Pixels: OpenCV convention (centre of the top-left pixel is (0, 0)); angles radians.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from fgloc.camera.blink_codes import CodeBook, word_of
from fgloc.camera.blink_pairs import PairConfig
from fgloc.camera.blink_word_fit import WordFit, WordFitConfig, fit_word
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.led_detection import DetectorConfig, LedDetection, detect_led, to_gray
from fgloc.camera.pixel_angles import pixel_to_pan_tilt
from fgloc.core.geometry import pan_tilt_bearing


@dataclass(frozen=True)
class DecoderConfig:
    """Decoder thresholds (pixels, flux sigmas, fractions of the on-off amplitude)."""

    min_snr: float = 12.0  #: on-off amplitude in flux-noise sigmas
    level_band: float = 0.3  #: a sample within this x amplitude of a level is that bit
    max_off_level: float = 0.2  #: off level over amplitude above which the blob is no LED
    max_on_spread: float = 0.2  #: robust spread of on fluxes over amplitude (one LED)
    max_centroid_spread_px: float = 0.35  #: robust spread of on-frame centroids (one LED)
    min_on_samples: int = 3
    detector: DetectorConfig = DetectorConfig(max_blobs=5000, max_elongation=2.0)
    #: step 8, the light-curve fit of a blob the levels refused (rotation-free books), e.g.
    #: ``WordFitConfig()``; None (default): off
    word_fit: WordFitConfig | None = None


_APERTURE = 3  #: half-width (px) of the square flux aperture


@dataclass(frozen=True)
class SyncTiming:
    """Timing of a synchronized start: the broadcast ``epoch_s`` (camera host clock, s) at
    which every mote started bit 0, the commanded ``bit_period_s`` and the frame exposure
    (samples are taken at mid-exposure)."""

    epoch_s: float
    bit_period_s: float
    exposure_s: float = 0.002


@dataclass(frozen=True)
class DecodedReading:
    """One identified mote: book ``index``, centroid (u, v) px with sigma, and (pan, tilt) rad."""

    index: int
    u: float
    v: float
    sigma_px: float
    pan: float
    tilt: float
    on_samples: int
    partner: int | None = None  #: book index of the other LED of a pair-decoded blob (None: a single LED)
    group: tuple[int, ...] = ()  #: book indices of the other LEDs of a group-decoded blob (three LEDs)


@dataclass(frozen=True)
class RefusedBlob:
    """A blob that yields no reading: ``kind`` is ambiguous, duplicate or rejected."""

    u: float
    v: float
    kind: str
    reason: str
    code: int | None = None  #: the code a duplicate claimed (None otherwise)


@dataclass(frozen=True)
class ViewDecode:
    """Everything one view gave: readings, refusals, and the sample count (with erasures)."""

    readings: tuple[DecodedReading, ...]
    refused: tuple[RefusedBlob, ...]
    samples: int
    erased: int
    #: bit positions (sample index modulo L) no delivered sample fell on: a word needs them all.
    #: L / 2 when every second frame is lost (a camera fallen to half rate; L is even).
    unsampled: int = 0

    def ambiguous(self) -> list[RefusedBlob]:
        return [r for r in self.refused if r.kind == "ambiguous"]


def unsampled_positions(sample_index: np.ndarray, length: int) -> int:
    """How many of the ``length`` bit positions no sample of ``sample_index`` (frame-period
    indices of the delivered samples) falls on, positions taken modulo ``length``."""
    idx = np.asarray(sample_index, dtype=np.int64)
    return length - len(np.unique(idx[idx >= 0] % length)) if length > 0 else 0


def sample_stack(frames: Sequence[tuple[float, np.ndarray]], period: float) -> tuple[np.ndarray, np.ndarray]:
    """(stack (N, H, W) float32 with NaN-free zeros for erased samples, valid (N,) bool)."""
    if not frames:
        return np.zeros((0, 0, 0), np.float32), np.zeros(0, bool)
    t0 = frames[0][0]
    idx = [int(round((t - t0) / period)) for t, _ in frames]
    n = max(idx) + 1
    first = to_gray(frames[0][1])
    stack = np.zeros((n, *first.shape), np.float32)
    valid = np.zeros(n, bool)
    previous: np.ndarray | None = None
    for k, (_, img) in zip(idx, frames):
        same = previous is not None and previous.shape == img.shape and np.array_equal(previous, img)
        previous = img
        if k < 0 or valid[k] or same:
            continue
        stack[k] = to_gray(img)
        valid[k] = True
    return stack, valid


def _fold_positions(frames: Sequence[tuple[float, np.ndarray]], period: float, n: int, length: int,
                    sync: SyncTiming | None) -> tuple[np.ndarray, tuple[int, ...]]:
    """Bit position (0..L-1) of each of the ``n`` samples, and the alignment shifts to try.
    Rotation-free: ``i mod L``, shift 0. Synchronized: one bit per sample, anchored at the
    bit in which the middle sample's mid-exposure time falls (time since the epoch over
    the bit period), and shifts (0, -1) when that sample lies in the first half of its
    bit (a late mote may still show the previous bit), else (0, +1). One bit per sample,
    not each sample's own bit: frames and bits slip by ~2e-4 bit per frame, and a mote
    whose bits slip past the samples is rejected as a conflict whichever way it is folded."""
    if sync is None:
        return np.arange(n) % length, (0,)
    t0 = frames[0][0]
    stamps = np.array([t for t, _ in frames])
    idx = np.rint((stamps - t0) / period)
    t_ref = float(np.median(stamps - idx * period))  # robust to timestamp jitter
    mid = n // 2
    x = (t_ref + period * mid + 0.5 * sync.exposure_s - sync.epoch_s) / sync.bit_period_s
    b = math.floor(x)
    return (b + np.arange(n) - mid) % length, ((0, -1) if x - b < 0.5 else (0, 1))


def _two_means(x: np.ndarray) -> tuple[float, float]:
    lo, hi = float(x.min()), float(x.max())
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        a, b = x[x <= mid], x[x > mid]
        if a.size == 0 or b.size == 0:
            break
        nlo, nhi = float(np.median(a)), float(np.median(b))
        if nlo == lo and nhi == hi:
            break
        lo, hi = nlo, nhi
    return lo, hi


@dataclass(frozen=True)
class BlobSamples:
    """One blob read as one LED (:func:`read_blob`): its per-sample bits and on-frame centroids."""

    u: float  #: detected blob centre (px)
    v: float
    bits: np.ndarray  #: (N,) int8 per sample: 1 on, 0 off, -1 erased (dropped, repeated or between levels)
    us: np.ndarray  #: centroid u (px) of each clean on sample
    vs: np.ndarray  #: centroid v (px) of each clean on sample
    sigma_px: float  #: the detector's centroid sigma of the blob (px)

    def reading(self, index: int, intr: CameraIntrinsics, head_pan: float, head_tilt: float) -> DecodedReading:
        """The blob labelled as book word ``index``: centroid = mean over the clean on samples,
        its sigma (scatter or detector sigma over sqrt(on samples), the larger), and
        (pan, tilt) by :func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt`."""
        us, vs = self.us, self.vs
        u, v = float(np.mean(us)), float(np.mean(vs))
        sig = float(np.hypot(np.std(us), np.std(vs)) / math.sqrt(max(us.size, 1)))
        sig = max(sig, self.sigma_px / math.sqrt(max(us.size, 1)))
        p_, t_ = pixel_to_pan_tilt(intr, np.array([u, v]), head_pan, head_tilt)
        return DecodedReading(index, u, v, sig, float(p_), float(t_), int(us.size))


def blob_flux(stack: np.ndarray, cand: LedDetection, noise_sigma: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Step 3's flux of one blob per sample: the sum over a 7 x 7 aperture minus the
    aperture's share of the median of a surrounding annulus. Returns (flux (N,), the
    15 x 15 window stack, its annulus medians (N,), the flux sigma from pixel noise), or
    None for a blob too close to the image border."""
    h, w = stack.shape[1:]
    cu, cv = int(round(cand.u)), int(round(cand.v))
    r = _APERTURE
    if not (r + 4 <= cu < w - r - 4 and r + 4 <= cv < h - r - 4):
        return None
    big = stack[:, cv - r - 4: cv + r + 5, cu - r - 4: cu + r + 5]
    yy, xx = np.mgrid[-r - 4: r + 5, -r - 4: r + 5]
    ring = (np.maximum(abs(yy), abs(xx)) > r + 1)
    core = (np.maximum(abs(yy), abs(xx)) <= r)
    bgk = np.median(big[:, ring], axis=1)
    flux = (big[:, core] - bgk[:, None]).sum(axis=1)
    return flux, big, bgk, noise_sigma * math.sqrt(core.sum() * 2.0)


def lit_centroids(big: np.ndarray, bgk: np.ndarray, lit: np.ndarray, cand: LedDetection
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (u, v) px of the aperture in each ``lit`` sample (background-subtracted,
    negative pixels clipped); ``big``/``bgk`` as :func:`blob_flux`."""
    r = _APERTURE
    ys, xs = np.mgrid[-r:r + 1, -r:r + 1]
    wts = np.clip(big[lit][:, 4:-4, 4:-4] - bgk[lit][:, None, None], 0.0, None)
    tot = np.maximum(wts.sum(axis=(1, 2)), 1e-9)
    return (wts * xs).sum(axis=(1, 2)) / tot + int(round(cand.u)), (wts * ys).sum(axis=(1, 2)) / tot + int(round(cand.v))


def centroid_spread(us: np.ndarray, vs: np.ndarray) -> tuple[float, np.ndarray]:
    """Robust spread (px) of per-sample centroids and each one's distance from their median."""
    spread = float(np.hypot(1.4826 * np.median(np.abs(us - np.median(us))),
                            1.4826 * np.median(np.abs(vs - np.median(vs)))))
    return spread, np.hypot(us - np.median(us), vs - np.median(vs))


def read_blob(stack: np.ndarray, valid: np.ndarray, cand: LedDetection, noise_sigma: float,
              cfg: DecoderConfig) -> BlobSamples | RefusedBlob:
    """Steps 3 and 5 of the module docstring for one detected blob: its flux per sample, the
    off/on split and the LED tests (amplitude, dark off level, enough on samples, lit frames
    alike), and each sample's bit; a :class:`RefusedBlob` when it is no single LED.
    ``stack``/``valid`` as :func:`sample_stack`; ``noise_sigma`` the detector's pixel noise."""
    n = int(valid.size)
    got = blob_flux(stack, cand, noise_sigma)
    if got is None:
        return RefusedBlob(cand.u, cand.v, "rejected", "too close to the image border")
    flux, big, bgk, noise = got
    f = flux[valid]
    off, on = _two_means(f)
    amp = on - off
    why = None
    if amp < cfg.min_snr * noise:
        why = f"on-off amplitude {amp:.0f} < {cfg.min_snr} x {noise:.1f}"
    elif abs(off) > cfg.max_off_level * amp + 4.0 * noise:
        why = f"never dark (off level {off:.0f} of amplitude {amp:.0f}): a flickering light"
    if why is not None:
        return RefusedBlob(cand.u, cand.v, "rejected", why)
    bits = np.full(n, -1, dtype=np.int8)
    is_on = valid & (np.abs(flux - on) <= cfg.level_band * amp)
    is_off = valid & (np.abs(flux - off) <= cfg.level_band * amp)
    bits[is_on] = 1
    bits[is_off] = 0
    on_f = flux[is_on]
    lit = valid & (flux > off + cfg.level_band * amp)  # any frame with light, partial ones too
    if on_f.size < cfg.min_on_samples:
        return RefusedBlob(cand.u, cand.v, "rejected", f"only {on_f.size} on samples")
    us_all, vs_all = lit_centroids(big, bgk, lit, cand)
    cspread, dev = centroid_spread(us_all, vs_all)
    bright = flux[lit] >= off + 0.6 * amp  # centroids of bright frames are precise: one outlier counts
    cmax = float(np.max(dev[bright])) if bright.any() else 0.0
    spread = 1.4826 * float(np.median(np.abs(on_f - np.median(on_f)))) / amp
    if spread > cfg.max_on_spread or cspread > cfg.max_centroid_spread_px or cmax > 3 * cfg.max_centroid_spread_px:
        return RefusedBlob(cand.u, cand.v, "ambiguous",
                           f"lit frames vary (flux spread {spread:.2f}, centroid spread {cspread:.2f} px,"
                           f" max {cmax:.2f} px): LEDs closer than the detector separates")
    return BlobSamples(cand.u, cand.v, bits, us_all[is_on[lit]], vs_all[is_on[lit]], float(cand.sigma_px))


def fit_blob(stack: np.ndarray, valid: np.ndarray, cand: LedDetection, noise_sigma: float, book: CodeBook,
             cfg: DecoderConfig, refusal: RefusedBlob,
             elsewhere: Callable[[int], bool] | None = None) -> tuple[BlobSamples, int] | RefusedBlob:
    """Step 4's second look: a blob the level decoder refused (``refusal``: its levels or its bits) read
    by the light-curve fit (:func:`fgloc.camera.blink_word_fit.fit_word`), with the single-LED
    centroid tests of step 5 on its lit samples: (samples, book index), or ``refusal``
    (same kind, so the survey treats the blob as before) with the fit's reason appended."""
    got = blob_flux(stack, cand, noise_sigma)
    if got is None or cfg.word_fit is None:
        return refusal
    flux, big, bgk, noise = got
    fit = fit_word(flux, valid, book, noise, cfg.min_snr, cfg.word_fit, elsewhere)
    why = fit if isinstance(fit, str) else None
    if isinstance(fit, WordFit):
        us, vs = lit_centroids(big, bgk, fit.lit, cand)
        if us.size < cfg.min_on_samples:
            why = f"only {us.size} lit samples"
        else:
            cspread, dev = centroid_spread(us, vs)
            if cspread > cfg.max_centroid_spread_px or float(np.max(dev)) > 3 * cfg.max_centroid_spread_px:
                why = f"lit frames vary (centroid spread {cspread:.2f} px, max {float(np.max(dev)):.2f} px)"
    if why is not None or not isinstance(fit, WordFit):
        return replace(refusal, reason=f"{refusal.reason}; light-curve fit: {why}")
    bits = np.where(fit.lit, 1, -1).astype(np.int8)
    return BlobSamples(cand.u, cand.v, bits, us, vs, float(cand.sigma_px)), fit.index


def _word_of_samples(bits: np.ndarray, positions: np.ndarray, book: CodeBook, shifts: tuple[int, ...]
                     ) -> tuple[str | None, tuple[int, int] | None]:
    """Step 4: fold a blob's per-sample bits at ``positions`` into one word and identify it:
    (None, (book index, rotation or shift)), or (the reason, None)."""
    length = book.length
    word_bits = np.full(length, -1, dtype=np.int8)
    for i in np.flatnonzero(bits >= 0).tolist():
        p = int(positions[i])
        if word_bits[p] == -1:
            word_bits[p] = bits[i]
        elif word_bits[p] != bits[i]:
            return "samples one period apart disagree", None
    if (word_bits < 0).any():
        return f"{int((word_bits < 0).sum())} of {length} bits never read cleanly", None
    hit = (book.identify_synchronized(word_of(word_bits), shifts) if book.synchronized
           else book.identify(word_of(word_bits)))
    return (None, hit) if hit is not None else ("word is no rotation of a book code", None)


#: a mote read this many pixels (at the view's zoom) or more from a blob is no part of it (rule 4 of the fit)
ELSEWHERE_PX = 5.0


def _read_away(elsewhere: Mapping[int, np.ndarray] | None, intr: CameraIntrinsics, head_pan: float,
               head_tilt: float, u: float, v: float) -> Callable[[int], bool] | None:
    """Whether a code was read :data:`ELSEWHERE_PX` or more away from the blob at (u, v) px."""
    if not elsewhere:
        return None
    pan, tilt = pixel_to_pan_tilt(intr, np.array([[u, v]]), head_pan, head_tilt)
    here = pan_tilt_bearing(float(pan[0]), float(tilt[0]))
    cos_far = math.cos(ELSEWHERE_PX / intr.fx)
    return lambda code: code in elsewhere and float(np.dot(elsewhere[code], here)) < cos_far


def decode_view(
    frames: Sequence[tuple[float, np.ndarray]], period: float, book: CodeBook, intr: CameraIntrinsics,
    head_pan: float, head_tilt: float, config: DecoderConfig | None = None, sync: SyncTiming | None = None,
    pairs: PairConfig | None = None, elsewhere: Mapping[int, np.ndarray] | None = None,
) -> ViewDecode:
    """Decode every mote in ``frames`` (see the module docstring). ``sync`` is required
    with a synchronized book and refused with a rotation-free one. ``pairs`` (rotation-free
    books only; default off): refused blobs are tried as two LEDs
    (:func:`fgloc.camera.blink_pairs.decode_pair`, see
    :func:`fgloc.camera.blink_crowd_decoding.crowd_readings`). ``elsewhere``: book code -> unit
    bearing (head frame, :func:`fgloc.core.geometry.pan_tilt_bearing`) where this camera read
    that mote before; the light-curve fit's rule 4 takes a mote read more than
    :data:`ELSEWHERE_PX` from a blob to be no part of it."""
    cfg = config or DecoderConfig()
    if book.synchronized != (sync is not None):
        raise ValueError("a synchronized book needs sync timing, a rotation-free book none")
    stack, valid = sample_stack(frames, period)
    n = int(valid.size)
    unsampled = unsampled_positions(np.flatnonzero(valid), book.length)
    if valid.sum() < book.length:
        return ViewDecode((), (), n, int(n - valid.sum()), unsampled)
    positions, shifts = _fold_positions(frames, period, n, book.length, sync)
    good = stack[valid]
    det = detect_led(good.max(axis=0), good.min(axis=0), cfg.detector)
    refused: list[RefusedBlob] = [RefusedBlob(b.u, b.v, "ambiguous", f"unresolved blob: {b.reason}")
                                  for b in det.rejected if "elongation" in b.reason]
    decoded: list[tuple[DecodedReading, int]] = []
    fit_refused = cfg.word_fit is not None and sync is None
    for cand in det.candidates:
        got = read_blob(stack, valid, cand, float(det.noise_sigma), cfg)
        hit: tuple[int, int] | None = None
        if isinstance(got, BlobSamples):
            why, hit = _word_of_samples(got.bits, positions, book, shifts)
            if why is not None:
                got = RefusedBlob(cand.u, cand.v, "rejected", why)
        if isinstance(got, RefusedBlob) and fit_refused and got.kind == "rejected" and "border" not in got.reason:
            fitted = fit_blob(stack, valid, cand, float(det.noise_sigma), book, cfg, got,
                              _read_away(elsewhere, intr, head_pan, head_tilt, cand.u, cand.v))
            if isinstance(fitted, tuple):
                got, hit = fitted[0], (fitted[1], 0)
            else:
                got = fitted
        if isinstance(got, RefusedBlob) or hit is None:
            refused.append(got if isinstance(got, RefusedBlob) else
                           RefusedBlob(cand.u, cand.v, "rejected", "word is no rotation of a book code"))
            continue
        decoded.append((got.reading(hit[0], intr, head_pan, head_tilt), hit[0]))
    if pairs is not None and sync is None:
        from fgloc.camera.blink_crowd_decoding import crowd_readings  # it builds on this module's types

        refused, merged = crowd_readings(stack, valid, positions, book, float(det.noise_sigma), refused,
                                         [rd for rd, _ in decoded], intr, head_pan, head_tilt, pairs)
        decoded = [(rd, rd.index) for rd in merged]
    counts = Counter(code for _, code in decoded)
    readings = []
    for rd, code in decoded:
        if counts[code] > 1:
            refused.append(RefusedBlob(rd.u, rd.v, "duplicate", f"code {code} decoded from {counts[code]} blobs", code))
        else:
            readings.append(rd)
    return ViewDecode(tuple(readings), tuple(refused), n, int(n - valid.sum()), unsampled)


def decode_windows(
    frames: Sequence[tuple[float, np.ndarray]], period: float, book: CodeBook, intr: CameraIntrinsics,
    head_pan: float, head_tilt: float, window: int, step: int | None = None, config: DecoderConfig | None = None,
    sync: SyncTiming | None = None, merge_px: float = 1.0, blob_px: float = 2.0, pairs: PairConfig | None = None,
    elsewhere: Mapping[int, np.ndarray] | None = None,
) -> ViewDecode:
    """Decode a continuous recording in sliding windows of ``window`` samples every ``step``
    (default one code length) samples, each by :func:`decode_view`, and merge (see the
    module docstring): a code read in several windows must be read within ``merge_px``
    of its first reading, codes whose readings lie within ``blob_px`` of each other
    are refused as one ambiguous blob, and a code refused as duplicate anywhere is
    refused. The reading kept for a code is the one with the most on samples. ``pairs``,
    ``elsewhere``: see :func:`decode_view`; the two readings of one pair-decoded blob do not clash."""
    if not frames:
        return ViewDecode((), (), 0, 0)
    step = step or book.length
    t0 = frames[0][0]
    idx = np.array([int(round((t - t0) / period)) for t, _ in frames])
    n = int(idx.max()) + 1
    starts = list(range(0, max(n - window, 0) + 1, step))
    per_code: dict[int, list[DecodedReading]] = {}
    refused: list[RefusedBlob] = []
    duplicates: set[int] = set()
    for s0 in starts:
        part = [f for f, k in zip(frames, idx) if s0 <= k < s0 + window]
        if not part:
            continue
        res = decode_view(part, period, book, intr, head_pan, head_tilt, config, sync, pairs, elsewhere)
        for rd in res.readings:
            per_code.setdefault(rd.index, []).append(rd)
        for rf in res.refused:
            if rf.kind == "duplicate" and rf.code is not None:
                duplicates.add(rf.code)
            refused.append(rf)
    kept: dict[int, DecodedReading] = {}
    for code, rds in per_code.items():
        far = max(math.hypot(r.u - rds[0].u, r.v - rds[0].v) for r in rds)
        if code in duplicates or far > merge_px:
            why = "refused as duplicate in a window" if code in duplicates else f"read {far:.1f} px apart in two windows"
            refused += [RefusedBlob(r.u, r.v, "duplicate", f"code {code} {why}", code) for r in rds]
            continue
        kept[code] = max(rds, key=lambda r: r.on_samples)
    clash = {a for a in kept for b in kept
             if a != b and kept[a].partner != b and b not in kept[a].group and math.hypot(kept[a].u - kept[b].u, kept[a].v - kept[b].v) <= blob_px}
    for code in sorted(clash):
        rd = kept.pop(code)
        refused.append(RefusedBlob(rd.u, rd.v, "ambiguous", f"code {code}: one blob read as two codes", code))
    readings = tuple(sorted(kept.values(), key=lambda r: r.index))
    left: list[RefusedBlob] = []  # one refusal per blob (windows repeat them), none where a code was read
    for rf in refused:
        read = any(math.hypot(rf.u - r.u, rf.v - r.v) <= blob_px for r in readings)
        seen = any(math.hypot(rf.u - o.u, rf.v - o.v) <= blob_px and (rf.kind, rf.code) == (o.kind, o.code)
                   for o in left)
        if not read and not seen:
            left.append(rf)
    return ViewDecode(readings, tuple(left), n, n - len(set(idx.tolist())), unsampled_positions(idx, book.length))


def supplement_decode(whole: ViewDecode, first: ViewDecode, blob_px: float = 2.0) -> ViewDecode:
    """``whole`` (the decode of a whole recording) with the readings of ``first`` (the decode of
    its first samples) it lacks: a code ``whole`` neither read nor refused as duplicate, read
    more than ``blob_px`` from every reading of ``whole``. ``whole``'s refusals within
    ``blob_px`` of an added reading are dropped (that blob is read). Nothing ``whole`` read is
    changed or lost; a code ``first`` read twice is not in its readings (it refused both)."""
    read = {r.index for r in whole.readings}
    dup = {f.code for f in whole.refused if f.kind == "duplicate" and f.code is not None}
    added = [r for r in first.readings if r.index not in read and r.index not in dup
             and all(math.hypot(r.u - w.u, r.v - w.v) > blob_px for w in whole.readings)]
    if not added:
        return whole
    refused = tuple(f for f in whole.refused if all(math.hypot(f.u - r.u, f.v - r.v) > blob_px for r in added))
    readings = tuple(sorted((*whole.readings, *added), key=lambda r: r.index))
    return ViewDecode(readings, refused, whole.samples, whole.erased, whole.unsampled)
