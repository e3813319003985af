"""Monte Carlo of the blink decoder: mislabels, misses and angle error on seeded rendered views.

Each trial renders one view (640 x 480, 65 deg HFOV, head at a random tilt) with
``--motes`` motes at random directions inside it, coded from the book for
``--book`` motes, with the disturbances of ``scripts/blink_views.py`` (5 % dropped
frames, 1 % duplicated frames, 50 Hz mains flicker on static lights, ``--glints``
daylight false blobs, ambient gain noise, head and timestamp jitter, mote clocks
offset and drifting). A decode is one true mote in the view. A reading is
*mislabelled* when its centroid is not within 2 px of the true pixel of the mote its
code names. Misses and ambiguous reports are counted, never guessed.

``--sync``: the synchronized book (:func:`fgloc.camera.blink_codes.sync_code_book`);
motes start at a broadcast epoch, each off by up to +-2 ms and drifting at 50 ppm
(sd), and the view is recorded a uniform 0..``--resync`` s after the last (re)start.
``--slide N``: the recording goes on for N more code lengths and is decoded in
sliding windows (:func:`fgloc.camera.blink_decoder.decode_windows`, keys ``sl_*``).
``--adaptive``: the survey's adaptive length with ``first_window "kept"``
(:func:`fgloc.survey.coded_recording.record_adaptive`): the whole 3L + 2 samples' decode
with the readings of the first 2L + 2 samples' decode it lacks
(:func:`fgloc.camera.blink_decoder.supplement_decode`, keys ``ad_*``); counted over every
view, as if each went on.
``--groups N``: each view also holds N crowded groups of three
(:func:`fgloc.drivers.blink_frames.close_groups`: each LED ``4 sqrt(U)`` px from an earlier
one of its group, no other mote within 4 px of any) and is decoded with group decoding on
(``PairConfig(max_group=3)``, :mod:`fgloc.camera.blink_groups`); a group decode is
resolved when all three motes are read within 2 px (keys ``grp_*``).
``--pairs N``: each view also holds N crowded pairs (two motes closer than 4 px in the
view's pixels, field pixels for ``--fields``: the field plan's criterion; separation
``4 sqrt(U)`` px, as for uniformly scattered motes, in a random direction; no other mote
within 4 px of either LED: :func:`blink_crowds.pair_pixels`) and is decoded with pair decoding on
(:mod:`fgloc.camera.blink_pairs`). A *pair decode* is one such pair; it is resolved when
both its motes are read within 2 px; mislabels are counted over all readings as above.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_montecarlo.py --trials 250 [--fields] [--sync] [--slide 1] [--word-fit]
        [--pairs 40 [--time-decode]] [--groups 20] [--partner]

``--readout S``: a rolling shutter whose last row starts its exposure S seconds after the
first (a CMOS camera; the modelled heads are CCDs, 0). ``--rate-fall S``: from S seconds
after the start of each recording every second frame is lost (a camera falling from 60 to
30 Hz). Both are render options of :class:`fgloc.drivers.blink_frames.BlinkRenderConfig`.

``--partner`` (with ``--pairs`` or ``--groups``): each crowd's last mote is also decoded by
the known-partner decoder (:mod:`fgloc.camera.blink_partner`), the others known
(:func:`blink_crowds.partner_stats`; margins 3 and 2 on the same views). The pair, group
and partner accounting is in ``scripts/blink_crowds.py``; candidate-restricted decoding of
radio-round views is ``scripts/blink_candidates_montecarlo.py``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from blink_crowds import (  # noqa: E402
    group_stats,
    pair_pixels,
    pair_stats,
    partner_stats,
    print_groups,
    print_pairs,
    print_partner,
)
from blink_views import add_view_arguments, render_motes, video_label, view_camera  # noqa: E402

from fgloc.camera.blink_codes import CodeBookError, code_book, sync_code_book  # noqa: E402
from fgloc.camera.blink_decoder import DecoderConfig, decode_view, decode_windows, supplement_decode  # noqa: E402
from fgloc.camera.blink_pairs import PairConfig  # noqa: E402
from fgloc.camera.blink_word_fit import WordFitConfig  # noqa: E402
from fgloc.camera.pixel_angles import pixel_to_pan_tilt  # noqa: E402
from fgloc.core.geometry import pan_tilt_bearing  # noqa: E402
from fgloc.drivers.blink_frames import close_groups  # noqa: E402
from fgloc.survey.field_plans import frames_for  # noqa: E402


def trial(seed: int, n_motes: int, book_size: int, glints: int, fields: bool = False,
          frames: int | None = None, extend: int = 0, sync: bool = False, resync_s: float = 10.0,
          slide: int = 0, pairs: int = 0, time_decode: bool = False, groups: int = 0,
          partner: bool = False, readout_s: float = 0.0, rate_fall_s: float | None = None,
          length: int | None = None, word_fit: bool = False, adaptive: bool = False) -> dict[str, float]:
    """One view. ``frames`` recorded (default 3L + 2); with ``extend`` > 0 the recording
    goes on for ``extend`` more frames and the whole stack is decoded again (keys ``ext_*``):
    the retry of a view whose motes were missed, without moving the head. ``slide``:
    ``slide`` more code lengths decoded in sliding windows (keys ``sl_*``). ``sync``: the
    synchronized book and a synchronized start (see the module docstring). ``pairs``: that many
    crowded pairs more, decoded with pair decoding (keys ``pair_*``). ``time_decode``: the
    first window is decoded once more without pair decoding, both timed (keys ``t_off``,
    ``t_on``, seconds). ``partner``: each crowded pair (group) is also decoded by the
    known-partner decoder given one (two) of its motes (keys ``ptn_*``, :func:`blink_crowds.partner_stats`).
    ``readout_s``, ``rate_fall_s``: rolling shutter and rate fall of the video
    (:class:`fgloc.drivers.blink_frames.BlinkRenderConfig`). ``length``: the book's word length
    (default the shortest that holds ``book_size`` words). ``word_fit``: the decoder's light-curve
    fit on (:mod:`fgloc.camera.blink_word_fit`; rotation-free books). ``adaptive``: the first
    2L + 2 samples' readings the whole recording's decode lacks added to it (keys ``ad_*``)."""
    rng = np.random.default_rng(seed)
    dcfg = DecoderConfig(word_fit=WordFitConfig()) if word_fit and not sync else None
    book = sync_code_book(book_size, length) if sync else code_book(book_size, length)
    intr, head_pan, head_tilt = view_camera(rng, fields)
    uv = np.column_stack([rng.uniform(15, intr.width - 15, n_motes), rng.uniform(15, intr.height - 15, n_motes)])
    n_single = n_motes
    if pairs:
        uv = np.vstack([uv, pair_pixels(rng, uv, pairs, intr.width, intr.height)])
        n_motes = len(uv)
    g0 = n_motes
    if groups:
        uv = np.vstack([uv, close_groups(groups, 3, intr.width, intr.height, rng, uv)])
        n_motes = len(uv)
    pans, tilts = pixel_to_pan_tilt(intr, uv, head_pan, head_tilt)
    dist = rng.uniform(3.0, 30.0, n_motes)
    pts = pan_tilt_bearing(pans, tilts) * dist[:, None]
    ids = rng.choice(book_size, size=n_motes, replace=False)
    k0 = frames if frames is not None else frames_for(book.length)
    ext = max(extend, slide * book.length)
    stack, cfg, t_start, timing = render_motes(rng, intr, head_pan, head_tilt, pts, ids, book, glints, fields,
                                               sync, resync_s, k0 + ext, readout_s, rate_fall_s)
    truth = {int(i): uv[k] for k, i in enumerate(ids)}
    dmin = np.sqrt(((uv[:, None, :] - uv[None, :, :]) ** 2).sum(-1)) + np.diag(np.full(n_motes, np.inf))
    isolated = dmin.min(axis=1) >= 4.0  # no other mote within 4 px: the field plan's criterion
    out: dict[str, float] = {"decodes": n_motes, "isolated": int(isolated.sum())}
    def within(periods: int) -> list[tuple[float, np.ndarray]]:  # frames of the first periods (jitter << period)
        return [f for f in stack if f[0] < t_start + (periods - 0.5) / cfg.frame_rate_hz]

    runs = [""] + (["ext_"] if extend else []) + (["sl_"] if slide else []) + (["ad_"] if adaptive else [])
    pc = PairConfig(max_group=3) if groups else PairConfig() if pairs else None
    for prefix in runs:
        if prefix == "ad_":
            res = supplement_decode(
                decode_view(within(k0), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, dcfg, sync=timing,
                            pairs=pc),
                decode_view(within(2 * book.length + 2), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, dcfg,
                            sync=timing, pairs=pc))
        elif prefix == "sl_":
            res = decode_windows(stack, 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, k0, config=dcfg, sync=timing,
                                 pairs=pc)
        else:
            t_on = time.perf_counter()
            res = decode_view(within(k0 + (extend if prefix else 0)), 1.0 / cfg.frame_rate_hz, book, intr,
                              head_pan, head_tilt, dcfg, sync=timing, pairs=pc)
            t_on = time.perf_counter() - t_on
            if time_decode and not prefix:
                t_off = time.perf_counter()
                decode_view(within(k0), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt, sync=timing)
                out.update({"t_off": time.perf_counter() - t_off, "t_on": t_on})
        correct = mislabelled = 0
        ex: list[float] = []
        ey: list[float] = []
        found = set()
        for r in res.readings:
            t = truth.get(r.index)
            if t is not None and math.hypot(r.u - t[0], r.v - t[1]) <= 2.0:
                correct += 1
                found.add(r.index)
                k = int(np.flatnonzero(ids == r.index)[0])
                ex.append(math.remainder(r.pan - pans[k], 2 * math.pi) * math.cos(tilts[k]))
                ey.append(r.tilt - tilts[k])
            else:
                mislabelled += 1
        iso_missed = sum(1 for k, i in enumerate(ids) if isolated[k] and int(i) not in found)
        if groups:
            out.update({prefix + k: v for k, v in group_stats(res.readings, ids, uv, g0, found,
                                                               pans, tilts).items()})
        if pairs:
            out.update({prefix + k: v for k, v in pair_stats(res.readings, ids, uv, n_single, found,
                                                              isolated, pans, tilts).items()})
        if partner and not prefix:
            plain = decode_view(within(k0), 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt)
            first = n_single if pairs else g0
            out.update(partner_stats(rng, within(k0), 1.0 / cfg.frame_rate_hz, book, plain, res.readings, ids, uv,
                                     first, 2 if pairs else 3))
        out.update({prefix + "correct": correct, prefix + "mislabelled": mislabelled,
                    prefix + "isolated_missed": iso_missed, prefix + "views_missing": float(iso_missed > 0), prefix + "ambiguous": len(res.ambiguous()),
                    prefix + "erased": res.erased, prefix + "samples": res.samples,
                    prefix + "sq_err": float(np.sum(np.square(ex)) + np.sum(np.square(ey))),
                    prefix + "n_err": 2 * len(ex), prefix + "sq_x": float(np.sum(np.square(ex))),
                    prefix + "sq_y": float(np.sum(np.square(ey))), prefix + "n_xy": len(ex)})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_view_arguments(ap)
    ap.add_argument("--extend", type=int, default=0, help="also decode after this many more frames")
    ap.add_argument("--sync", action="store_true", help="synchronized book and start (epoch broadcast)")
    ap.add_argument("--resync", type=float, default=10.0, help="seconds between synchronized (re)starts")
    ap.add_argument("--slide", type=int, default=0, help="record this many more code lengths, sliding windows")
    ap.add_argument("--adaptive", action="store_true",
                    help="also add to the whole recording's decode the readings of its first 2L + 2 samples it lacks")
    ap.add_argument("--pairs", type=int, default=0, help="crowded pairs per view, decoded with pair decoding on")
    ap.add_argument("--groups", type=int, default=0,
                    help="crowded groups of three per view, decoded with group decoding on (max_group=3)")
    ap.add_argument("--partner", action="store_true",
                    help="with --pairs/--groups: also decode each crowd's last mote by the known-partner decoder "
                    "(fgloc.camera.blink_partner), the others known")
    ap.add_argument("--time-decode", action="store_true",
                    help="also decode each first window without pair decoding; print both medians (s per view)")
    ap.add_argument("--readout", type=float, default=0.0, metavar="S",
                    help="rolling shutter: the last row starts its exposure S seconds after the first (default 0: CCD)")
    ap.add_argument("--rate-fall", type=float, default=None, metavar="S",
                    help="from S seconds after the start of each recording every second frame is lost (a camera "
                    "falling from 60 to 30 Hz); default never")
    ap.add_argument("--word-fit", action="store_true",
                    help="decode with the light-curve fit on (fgloc.camera.blink_word_fit; rotation-free books)")
    ap.add_argument("--length", type=int, default=None, metavar="L",
                    help="word length of the book (default: the shortest that holds --book words)")
    args = ap.parse_args()
    try:
        (sync_code_book if args.sync else code_book)(args.book, args.length)
    except CodeBookError as exc:
        ap.error(f"--length: {exc}")
    if not 0.0 <= args.readout <= 1.0:
        ap.error(f"--readout: seconds in [0, 1] ({args.readout})")
    if args.rate_fall is not None and args.rate_fall < 0.0:
        ap.error(f"--rate-fall: seconds >= 0 ({args.rate_fall})")
    if args.partner and not (args.pairs or args.groups) or args.partner and (args.sync or args.slide):
        ap.error("--partner: with --pairs or --groups, rotation-free book, no --slide")
    if args.pairs and args.groups:  # their statistics index the motes of one kind of crowd per view
        ap.error("--pairs and --groups are separate experiments: give one of them")
    tot: dict[str, float] = {}
    times: dict[str, list[float]] = {"t_off": [], "t_on": []}
    t0 = time.perf_counter()
    for k in range(args.trials):
        for key, v in trial(args.seed + k, args.motes, args.book, args.glints, args.fields, args.frames,
                             args.extend, args.sync, args.resync, args.slide, args.pairs, args.time_decode,
                             args.groups, args.partner, args.readout, args.rate_fall, args.length,
                             args.word_fit, args.adaptive).items():
            if key in times:
                times[key].append(v)
            else:
                tot[key] = tot.get(key, 0.0) + v
    dt = time.perf_counter() - t0
    d = tot["decodes"]
    book = sync_code_book(args.book, args.length) if args.sync else code_book(args.book, args.length)
    k0 = args.frames if args.frames is not None else frames_for(book.length)
    print(f"{video_label(args.fields)}: "
          f"{args.trials} views x {args.motes} motes ({'synchronized' if args.sync else 'rotation-free'} book "
          f"{args.book}, L = {book.length}), {args.glints} glints/view, "
          + (f"rolling shutter {1e3 * args.readout:.1f} ms, " if args.readout else "")
          + (f"every second frame lost from {args.rate_fall:g} s, " if args.rate_fall is not None else "")
          + f"{dt:.0f} s")
    for prefix, k in [("", k0)] + ([("ext_", k0 + args.extend)] if args.extend else []) + (
            [("sl_", k0 + args.slide * book.length)] if args.slide else []) + (
            [("ad_", k0)] if args.adaptive else []):
        miss = d - tot[prefix + "correct"] - tot[prefix + "mislabelled"]
        print(f"{k} samples/view, {tot[prefix + 'erased'] / tot[prefix + 'samples']:.1%} erased (drops + duplicates): "
              f"decodes {d:.0f}: correct {tot[prefix + 'correct']:.0f} ({tot[prefix + 'correct'] / d:.2%}), "
              f"mislabelled {tot[prefix + 'mislabelled']:.0f}, missed {miss:.0f} ({miss / d:.2%}), "
              f"ambiguous reports {tot[prefix + 'ambiguous']:.0f}")
        print(f"  isolated motes (no other within 4 px) {tot['isolated']:.0f}: missed "
              f"{tot[prefix + 'isolated_missed']:.0f} ({tot[prefix + 'isolated_missed'] / max(tot['isolated'], 1):.2%}); "
              f"views with an isolated miss {tot[prefix + 'views_missing'] / args.trials:.1%}")
        rms = math.sqrt(tot[prefix + "sq_err"] / max(tot[prefix + "n_err"], 1))
        n_xy = max(tot[prefix + "n_xy"], 1)
        print(f"  angle error RMS per axis of correct readings: {math.degrees(rms) * 3600:.1f} arcsec "
              f"({math.degrees(rms):.5f} deg); pan (x cos tilt) {math.degrees(math.sqrt(tot[prefix + 'sq_x'] / n_xy)):.5f}"
              f" deg, tilt {math.degrees(math.sqrt(tot[prefix + 'sq_y'] / n_xy)):.5f} deg")
        if args.pairs:
            print_pairs(tot, prefix)
        if args.groups:
            print_groups(tot, prefix)
        if args.partner and not prefix:
            print_partner(tot)
    if times["t_on"]:
        print(f"decode_view per view, median of {len(times['t_on'])}: without pair decoding "
              f"{1e3 * float(np.median(times['t_off'])):.0f} ms, with {1e3 * float(np.median(times['t_on'])):.0f} ms")


if __name__ == "__main__":
    main()
