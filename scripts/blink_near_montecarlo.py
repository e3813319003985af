"""Monte Carlo of the blind decoder on near motes: the share read by the distance to the nearest neighbour.

The field plan (``scripts/field_time.py``) counts a mote as isolated, read in the wide view
at the isolated miss rate, when no other mote lies within 4 px; closer ones are crowds
(pair and group decoding, rounds, zoom). This measures what the blind decoder
(:func:`fgloc.camera.blink_decoder.decode_view`; pair decoding off, or on with ``--pairs``) reads between: each
seeded view (the rendered views of ``scripts/blink_views.py``: 640 x 480 at 65 deg, or
fields, 5 % drops, 1 % repeats, flickering lamps, ``--glints`` glints, drifting mote
clocks) holds ``--motes`` / 2 pairs of motes ``U(--min-px, --max-px)`` px apart in a
random direction (field pixels with ``--fields``, the plan's tangent-plane criterion), no
other mote within 2 x ``--max-px`` of either. A mote is *read* when a reading names its
code within 2 px of it; a reading elsewhere is *mislabelled*. Printed per distance bin:
the read share, which ``field_time.py --separation PX --near-decode TABLE`` takes.

``--group K`` (3 to 5): crowds of K motes instead of pairs, grown one mote at a time, each
``U(--min-px, --max-px)`` px from a random earlier member and at least ``--min-px`` from
every member (:func:`crowd_pixels`), binned by each mote's nearest neighbour in its crowd;
with ``--pairs`` group decoding of three LEDs is on too. ``field_time.py --crowd-decode
K=TABLE`` takes the read shares.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_near_montecarlo.py --trials 150 [--fields] [--pairs]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_near_montecarlo.py --trials 150 --group 3 --pairs \
        --min-px 1 --max-px 8 --motes 39 [--fields]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from blink_views import add_view_arguments, render_motes, video_label, view_camera  # noqa: E402

from fgloc.camera.blink_codes import code_book  # noqa: E402
from fgloc.camera.blink_decoder import decode_view  # noqa: E402
from fgloc.camera.blink_pairs import PairConfig  # noqa: E402
from fgloc.camera.pixel_angles import pixel_to_pan_tilt  # noqa: E402
from fgloc.core.geometry import pan_tilt_bearing  # noqa: E402
from fgloc.survey.field_plans import frames_for  # noqa: E402

BINS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 16.0)  #: distance bins (px) of the report


def near_pixels(rng: np.random.Generator, n_pairs: int, width: int, height: int, low: float,
                high: float) -> np.ndarray:
    """(2 n_pairs, 2) pixels: pairs ``U(low, high)`` px apart, every other mote at least 2 x ``high`` away."""
    out: list[np.ndarray] = []
    while len(out) < 2 * n_pairs:
        c = np.array([rng.uniform(20, width - 20), rng.uniform(20, height - 20)])
        a, s = rng.uniform(0, math.pi), rng.uniform(low, high)
        pair = [c - 0.5 * s * np.array([math.cos(a), math.sin(a)]), c + 0.5 * s * np.array([math.cos(a), math.sin(a)])]
        if out and min(float(np.min(np.hypot(*(np.array(out) - p).T))) for p in pair) < 2.0 * high:
            continue
        out += pair
    return np.array(out)


def crowd_pixels(rng: np.random.Generator, n_crowds: int, size: int, width: int, height: int, low: float,
                 high: float) -> np.ndarray:
    """(size n_crowds, 2) pixels: crowds of ``size`` motes grown one at a time, each new mote
    ``U(low, high)`` px from a random earlier member in a random direction and at least
    ``low`` from every member (so each mote's nearest neighbour lies in [low, high), and the
    crowd is connected at ``high``: what the field plan calls a crowd of ``size`` alone at
    ``high``), every mote of another crowd at least 2 x ``high`` away."""
    out: list[np.ndarray] = []
    while len(out) < size * n_crowds:
        crowd = [np.array([rng.uniform(24, width - 24), rng.uniform(24, height - 24)])]
        while len(crowd) < size:
            a, s = rng.uniform(0, 2 * math.pi), rng.uniform(low, high)
            p = crowd[int(rng.integers(len(crowd)))] + s * np.array([math.cos(a), math.sin(a)])
            if min(float(np.hypot(*(q - p))) for q in crowd) >= low:
                crowd.append(p)
        inside = all(8 <= p[0] <= width - 8 and 8 <= p[1] <= height - 8 for p in crowd)
        if not inside or (out and min(float(np.min(np.hypot(*(np.array(out) - p).T))) for p in crowd) < 2.0 * high):
            continue
        out += crowd
    return np.array(out)


def nearest_within(uv: np.ndarray, size: int) -> np.ndarray:
    """(N,) px from each mote to its nearest neighbour in its own crowd (consecutive ``size`` rows)."""
    out = np.empty(len(uv))
    for k in range(0, len(uv), size):
        c = uv[k:k + size]
        d = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        out[k:k + size] = d.min(axis=1)
    return out


def trial(seed: int, n_motes: int, book_size: int, glints: int, fields: bool, low: float,
          high: float, pairs: bool = False, group: int = 2, three: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """One view: per mote its distance to its nearest neighbour (px) and whether it was read;
    mislabels. ``pairs``: decoded with pair decoding on (:mod:`fgloc.camera.blink_pairs`, the
    survey's default). ``group`` 3 to 5: crowds of that many (:func:`crowd_pixels`) instead of
    pairs, decoded with group decoding of three LEDs on too (``PairConfig(max_group=3)``)
    unless ``three`` is False (pair decoding alone, the coded survey's ``pairs: on``)."""
    rng = np.random.default_rng(seed)
    book = code_book(book_size)
    intr, head_pan, head_tilt = view_camera(rng, fields)
    if group == 2:
        uv = near_pixels(rng, n_motes // 2, intr.width, intr.height, low, high)
    else:
        uv = crowd_pixels(rng, n_motes // group, group, intr.width, intr.height, low, high)
    pans, tilts = pixel_to_pan_tilt(intr, uv, head_pan, head_tilt)
    pts = pan_tilt_bearing(pans, tilts) * rng.uniform(3.0, 30.0, len(uv))[:, None]
    ids = rng.choice(book_size, size=len(uv), replace=False)
    frames, cfg, _, _ = render_motes(rng, intr, head_pan, head_tilt, pts, ids, book, glints, fields, False, 10.0,
                                     frames_for(book.length))
    res = decode_view(frames, 1.0 / cfg.frame_rate_hz, book, intr, head_pan, head_tilt,
                      pairs=(PairConfig(max_group=3) if group > 2 and three else PairConfig()) if pairs else None)
    where = {int(i): uv[k] for k, i in enumerate(ids)}
    read = set()
    mislabelled = 0
    for r in res.readings:
        t = where.get(r.index)
        if t is not None and math.hypot(r.u - t[0], r.v - t[1]) <= 2.0:
            read.add(r.index)
        else:
            mislabelled += 1
    sep = np.repeat(np.hypot(*(uv[0::2] - uv[1::2]).T), 2) if group == 2 else nearest_within(uv, group)
    return sep, np.array([int(i) in read for i in ids]), mislabelled


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_view_arguments(ap)
    ap.add_argument("--min-px", type=float, default=4.0, help="smallest pair separation (px)")
    ap.add_argument("--max-px", type=float, default=16.0, help="largest pair separation (px)")
    ap.add_argument("--pairs", action="store_true", help="decode with pair decoding on (the survey's default lever)")
    ap.add_argument("--group", type=int, choices=(2, 3, 4, 5), default=2,
                    help="crowd size: 2 (pairs), or 3 to 5 (crowds linked at --max-px; group decoding of three "
                    "LEDs on too with --pairs)")
    ap.add_argument("--no-three", action="store_true",
                    help="with --group 3..5 --pairs: pair decoding alone, no group decoding of three LEDs (the "
                    "coded survey's pairs: on)")
    args = ap.parse_args()
    if not 0.0 < args.min_px < args.max_px <= 64.0:
        ap.error(f"--min-px, --max-px: need 0 < min < max <= 64 ({args.min_px}, {args.max_px})")
    if args.frames is not None:
        ap.error(f"--frames: this Monte Carlo records 3L + 2 ({args.frames})")
    t0 = time.perf_counter()
    seps, reads, mislabelled = [], [], 0
    for k in range(args.trials):
        sep, read, mis = trial(args.seed + k, args.motes, args.book, args.glints, args.fields, args.min_px,
                               args.max_px, args.pairs, args.group, not args.no_three)
        seps.append(sep)
        reads.append(read)
        mislabelled += mis
    sep, read = np.concatenate(seps), np.concatenate(reads)
    crowd = "pairs" if args.group == 2 else f"crowds of {args.group} (links)"
    decoding = ("pair decoding on, " if args.group == 2 or args.no_three else "pair and group decoding on, "
                ) if args.pairs else ""
    print(f"{video_label(args.fields)}: {args.trials} views x {args.motes} motes in {crowd} {args.min_px:g}-"
          f"{args.max_px:g} px apart (book {args.book}), {args.glints} glints/view, "
          f"{decoding}{time.perf_counter() - t0:.0f} s")
    print(f"decodes {len(sep)}: read {read.mean():.2%}, mislabelled {mislabelled}")
    for lo, hi in zip(BINS, BINS[1:]):
        m = (sep >= lo) & (sep < hi)
        if m.any():
            print(f"  {lo:g}-{hi:g} px: read {read[m].mean():.1%} of {int(m.sum())}")


if __name__ == "__main__":
    main()
