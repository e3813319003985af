"""Monte Carlo of candidate-restricted blink decoding: radio-round views read against their class.

``--candidates M``: radio-separation round views (:func:`candidate_trial`): ``--motes`` lit
class motes (none within 4 px of another), each decoded by
:func:`fgloc.camera.blink_candidates.decode_candidates` against the class: itself predicted
``--predict-px`` (sd) from its pixel plus 0..M-1 dark class members predicted within its
``--radius`` (1..M candidates in range), and ``--strays`` lit motes that are no candidate
(they missed the pause) near it, which must be refused; ``--candidates book``: the whole
book, no prediction, no strays (the control). Views and disturbances are those of
``scripts/blink_views.py`` (as for ``scripts/blink_montecarlo.py``). A reading is
*mislabelled* when its centroid is not within 2 px of the true pixel of the mote its code
names (a stray labelled as a candidate is one); missed is the isolated miss rate (every
lit mote is isolated).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/blink_candidates_montecarlo.py --candidates 3|book --frames 18
        --motes 20 [--fields]
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

from fgloc.camera.blink_candidates import Candidate, CandidateRule, decode_candidates  # noqa: E402
from fgloc.camera.blink_codes import code_book  # noqa: E402
from fgloc.camera.pixel_angles import pixel_to_pan_tilt  # noqa: E402
from fgloc.core.geometry import pan_tilt_bearing  # noqa: E402
from fgloc.survey.field_plans import frames_for  # noqa: E402


def candidate_trial(seed: int, n_lit: int, book_size: int, glints: int, fields: bool, frames: int,
                    near: int | None, strays: int, predict_px: float, radius_px: float,
                    rule: CandidateRule) -> dict[str, float]:
    """One round view decoded against candidates (:mod:`fgloc.camera.blink_candidates`).
    ``n_lit`` class motes (no two within 4 px: a colour class has no conflict) at random
    pixels, each a candidate predicted ``N(0, predict_px)`` px from its true pixel with radius
    ``radius_px``, plus ``U{0..near-1}`` dark decoys per lit mote (other class members
    predicted uniformly within 0.8 x radius of its prediction: 1..``near`` candidates in
    range of each blob); ``strays`` lit motes that are no candidate (they missed the pause)
    4 px to the radius from a lit mote. ``near`` None: the whole book, no prediction, no
    strays (the control). ``frames`` samples recorded; disturbances of :func:`blink_views.render_motes`."""
    rng = np.random.default_rng(seed)
    book = code_book(book_size)
    intr, head_pan, head_tilt = view_camera(rng, fields)
    strays = strays if near is not None else 0
    uv = np.zeros((0, 2))
    while len(uv) < n_lit:
        p = np.array([rng.uniform(15, intr.width - 15), rng.uniform(15, intr.height - 15)])
        if not len(uv) or np.min(np.hypot(*(uv - p).T)) >= 4.0:
            uv = np.vstack([uv, p])
    while len(uv) < n_lit + strays:
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(4.0, radius_px)
        p = uv[int(rng.integers(n_lit))] + r * np.array([math.cos(a), math.sin(a)])
        if 15 <= p[0] <= intr.width - 15 and 15 <= p[1] <= intr.height - 15 and np.min(np.hypot(*(uv - p).T)) >= 4.0:
            uv = np.vstack([uv, p])
    n = len(uv)
    pans, tilts = pixel_to_pan_tilt(intr, uv, head_pan, head_tilt)
    pts = pan_tilt_bearing(pans, tilts) * rng.uniform(3.0, 30.0, n)[:, None]
    order = rng.permutation(book_size)
    ids = order[:n]
    stack, cfg, _, _ = render_motes(rng, intr, head_pan, head_tilt, pts, ids, book, glints, fields, False, 10.0,
                                    frames)
    if near is None:
        cands = [Candidate(i) for i in range(book_size)]
        in_range = float(book_size * n_lit)
    else:
        cands, spare = [], iter(order[n:].tolist())
        in_range = 0.0
        for k in range(n_lit):
            pu, pv = uv[k] + rng.normal(0.0, predict_px, 2)
            cands.append(Candidate(int(ids[k]), float(pu), float(pv), radius_px))
            for _ in range(int(rng.integers(near))):
                a, r = rng.uniform(0, 2 * math.pi), 0.8 * radius_px * math.sqrt(rng.uniform())
                cands.append(Candidate(next(spare), float(pu + r * math.cos(a)), float(pv + r * math.sin(a)),
                                       radius_px))
        for k in range(n_lit):
            in_range += sum(c.near(*uv[k]) for c in cands)
    res = decode_candidates(stack, 1.0 / cfg.frame_rate_hz, book, cands, intr, head_pan, head_tilt, rule)
    truth = {int(i): uv[k] for k, i in enumerate(ids[:n_lit])}
    # clear: no lit non-candidate within 8 px (outside the decoder's aperture and annulus)
    clear = {int(ids[k]) for k in range(n_lit) if not strays or np.min(np.hypot(*(uv[n_lit:] - uv[k]).T)) > 8.0}
    correct = mislabelled = stray = clear_found = 0
    for rd in res.readings:
        t = truth.get(rd.index)
        if t is not None and math.hypot(rd.u - t[0], rd.v - t[1]) <= 2.0:
            correct += 1
            clear_found += rd.index in clear
        else:
            mislabelled += 1
            stray += any(math.hypot(rd.u - q[0], rd.v - q[1]) <= 2.0 for q in uv[n_lit:])
    return {"decodes": n_lit, "clear": len(clear), "clear_missed": len(clear) - clear_found, "correct": correct, "mislabelled": mislabelled, "stray_labelled": stray,
            "strays": strays, "candidates": len(cands), "in_range": in_range, "erased": res.erased,
            "samples": res.samples, "refused": len(res.refused)}


def _run_candidates(args: argparse.Namespace) -> None:
    """The ``--candidates`` experiment: trials, then one summary line per row."""
    near = None if args.candidates == "book" else int(args.candidates)
    book = code_book(args.book)
    k = args.frames if args.frames is not None else frames_for(book.length)
    rule = CandidateRule(max_unread=args.max_unread, book_margin=args.book_margin)
    tot: dict[str, float] = {}
    t0 = time.perf_counter()
    for s in range(args.trials):
        for key, v in candidate_trial(args.seed + s, args.motes, args.book, args.glints, args.fields, k, near,
                                      args.strays, args.predict_px, args.radius, rule).items():
            tot[key] = tot.get(key, 0.0) + v
    d = tot["decodes"]
    miss = d - tot["correct"] - tot["mislabelled"]
    print(f"{video_label(args.fields)}: candidate decoding,"
          f" {args.trials} views x {args.motes} lit class motes (book {args.book}, L = {book.length}), "
          f"{args.glints} glints/view, {time.perf_counter() - t0:.0f} s")
    what = ("whole book, no prediction" if near is None else
            f"1..{near} candidates within {args.radius:g} px of each blob (prediction sd {args.predict_px:g} px), "
            f"{tot['strays'] / args.trials:g} lit non-candidates/view")
    print(f"  candidates: {what}; {tot['candidates'] / args.trials:.1f} per view, "
          f"{tot['in_range'] / d:.2f} in range of each lit mote; rule {rule.max_errors} errors, margin "
          f"{rule.margin}, {rule.max_unread} unread bits, book margin {rule.book_margin}")
    print(f"{k} samples/view, {tot['erased'] / tot['samples']:.1%} erased: decodes {d:.0f}: correct "
          f"{tot['correct']:.0f} ({tot['correct'] / d:.2%}), mislabelled {tot['mislabelled']:.0f} "
          f"(non-candidates labelled {tot['stray_labelled']:.0f} of {tot['strays']:.0f}), "
          f"missed {miss:.0f} ({miss / d:.2%}; all lit motes are isolated)")
    print(f"  lit motes with no lit non-candidate within 8 px {tot['clear']:.0f}: missed {tot['clear_missed']:.0f} "
          f"({tot['clear_missed'] / max(tot['clear'], 1):.2%})")

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_view_arguments(ap)
    ap.add_argument("--candidates", required=True, metavar="M|book",
                    help="round views decoded against candidates (blink_candidates): 1..M candidates in range of "
                    "each lit mote plus the rest of the class, or 'book' (the whole book, the control)")
    ap.add_argument("--strays", type=int, default=2, help="lit non-candidate motes per view")
    ap.add_argument("--predict-px", type=float, default=1.5, help="prediction error sd (px)")
    ap.add_argument("--radius", type=float, default=8.0, help="candidate radius (px)")
    ap.add_argument("--max-unread", type=int, default=CandidateRule().max_unread,
                    help="bit positions allowed without a clean sample")
    ap.add_argument("--book-margin", type=int, default=CandidateRule().book_margin,
                    help="every other book word at least this many mismatches more (0: off)")
    args = ap.parse_args()
    if args.candidates != "book" and not (args.candidates.isdigit() and int(args.candidates) >= 1):
        ap.error(f"--candidates: a count >= 1 or 'book' ({args.candidates})")
    try:
        CandidateRule(max_unread=args.max_unread, book_margin=args.book_margin)
    except ValueError as exc:
        ap.error(f"--max-unread/--book-margin: {exc}")
    _run_candidates(args)


if __name__ == "__main__":
    main()
