"""The command line of ``scripts/field_time.py``: its options (:func:`build_parser`), their
checks, and the :class:`~field_time_variants.Variant` they ask for (:func:`variant_from_args`).

A bad flag exits through ``ArgumentParser.error``: one line naming the flag and the value,
exit status 2, no traceback. Units as in ``field_time_variants``: px at the wide zoom,
samples, shares in [0, 1].
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from field_time_variants import OLD, SEPARATION_PX, Rate, Variant  # noqa: E402

from fgloc.survey.clock import HEAD_MODELS  # noqa: E402
from fgloc.survey.field_plans import pair_rate_table  # noqa: E402

#: command-line flags (flag, argparse dest, Variant field) of one rate or rate table
RATE_FLAGS = (("--pair-decode", "pair_decode", "pair_rate"),
              ("--group-decode", "group_decode", "group_rate"),
              ("--partner-decode", "partner_decode", "partner_rate"),
              ("--partner-group-decode", "partner_group_decode", "partner_group_rate"),
              ("--near-decode", "near_decode", "near_rate"))


def _add_rig_arguments(ap: argparse.ArgumentParser) -> None:
    """The head model, the isolated miss rate and the camera's frame rate (frames/s)."""
    ap.add_argument("--head", default="EVI-D100", choices=sorted(HEAD_MODELS))
    ap.add_argument("--miss-rate", type=float, default=0.0)
    ap.add_argument("--fps", type=float, default=30000.0 / 1001.0)


def _add_plan_arguments(ap: argparse.ArgumentParser) -> None:
    """How the coded survey starts, records, retries and refines, and how it separates crowds."""
    ap.add_argument("--frames", action="store_true", help="decode frames, not fields (interlaced heads)")
    ap.add_argument("--unicast", action="store_true", help="one unicast start per mote, not a broadcast")
    ap.add_argument("--sync", action="store_true", help="the synchronized book (epoch broadcast, resync every 10 s)")
    ap.add_argument("--extend", type=int, default=0, help="code lengths recorded beyond K in every view")
    ap.add_argument("--burst-retry", action="store_true", help="a retry records a new burst of K frames")
    ap.add_argument("--no-refine-retry", action="store_true", help="refinement views are never retried")
    ap.add_argument("--zoom-out", action="store_true", help="zoom back out after the last refinement pass")
    ap.add_argument("--separate-tiles", action="store_true", help="each zoom level tiles only its own targets")
    ap.add_argument("--fixed-ladder", action="store_true", help="refine on --levels only, not the cheapest of LADDERS")
    ap.add_argument("--separate", default="zoom", choices=("zoom", "radio", "best"),
                    help="crowded motes: zoom refinement, radio separation (pause colour classes, re-record wide "
                    "views), or per camera the cheaper on the clock")


def _add_decoder_arguments(ap: argparse.ArgumentParser) -> None:
    """The pair and group decoders' measured rates in the wide view."""
    ap.add_argument("--pair-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="crowded groups of exactly two motes are resolved by the pair decoder in the wide view with "
                    "this measured success rate (scripts/blink_montecarlo.py --pairs), or per bound on the distance "
                    "to the nearest third mote (px); default off")
    ap.add_argument("--group-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="crowded groups of exactly three motes are resolved by the group decoder in the wide view "
                    "with this measured rate (scripts/blink_montecarlo.py --groups), or per bound on the distance to "
                    "the nearest fourth mote (px); default off")


def _add_round_arguments(ap: argparse.ArgumentParser) -> None:
    """Radio rounds: short rounds, cover rounds (known-partner decoding) and the round order."""
    ap.add_argument("--round-frames", default="", metavar="K'",
                    help="short rounds: each radio-round view records K' samples, labelled against the class's "
                    "candidates (fgloc.camera.blink_candidates): a count or a L + b in code lengths L (e.g. L+2, 2L+2); "
                    "default off")
    ap.add_argument("--round-miss-rate", type=float, default=None, metavar="Q",
                    help="with --round-frames: isolated miss rate of a short-round view (scripts/"
                    "blink_candidates_montecarlo.py --candidates); default: --miss-rate")
    ap.add_argument("--partner-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="cover rounds (with --separate radio|best): a crowded group of exactly two needs only one "
                    "member read in a radio round, the other decoded from the wide view by the known-partner decoder "
                    "with this success rate (scripts/blink_montecarlo.py --partner), or per bound on the distance to "
                    "the nearest third mote (px); failures are read in extra rounds; default off")
    ap.add_argument("--partner-group-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="cover rounds: the same for crowded groups of exactly three (two read in rounds, the third "
                    "decoded; scripts/blink_montecarlo.py --groups --partner), per bound on the nearest fourth mote")
    ap.add_argument("--partner-any", action="store_true",
                    help="with --partner-decode 1: every crowded group leaves one member unread (upper bound)")
    ap.add_argument("--round-order", default="class", choices=("class", "view", "best"),
                    help="with --separate radio|best: class-major rounds (each class in turn, every camera visiting "
                    "its views), view-major (each camera's round views shared across the classes; it stays on a "
                    "view while the classes it needs there take turns, one pause update per class change), or the "
                    "cheaper of the two on the clock; default class")


def _add_separation_arguments(ap: argparse.ArgumentParser) -> None:
    """The decoder's measured separation (px) and the read shares of motes and crowds within it."""
    ap.add_argument("--separation", type=float, default=SEPARATION_PX, metavar="PX",
                    help="a mote is isolated (read as such in the wide view) when no other lies within PX px at the "
                    "wide zoom; default 4 (the crowd criterion of every earlier table); the blind decoder's measured "
                    "separation is ~8 px (scripts/blink_near_montecarlo.py)")
    ap.add_argument("--near-decode", default="", metavar="RATE|PX:RATE,...,inf:RATE",
                    help="with --separation above 4: the share of motes whose nearest neighbour lies 4 px to "
                    "--separation away that the blind decoder still reads (blink_near_montecarlo.py), or per bound "
                    "on that distance; default 0")
    ap.add_argument("--crowd-decode", action="append", default=[], metavar="K=RATE|K=PX:RATE,...,inf:RATE",
                    help="with --separation above 4, repeatable: the share of the motes of crowds of K (3 to 5) alone "
                    "at --separation that the decoder reads in the wide view (blink_near_montecarlo.py --group K "
                    "--pairs), or per bound on each mote's nearest-neighbour distance; replaces the pair and group "
                    "decoders' draws inside those crowds; default none")


def _add_scope_arguments(ap: argparse.ArgumentParser) -> None:
    """Which motes are refined, the old plan, samples per view, the zoom ladder and the scenes."""
    ap.add_argument("--need", type=int, default=0,
                    help="refine a mote only where fewer than this many other cameras resolve it (0: always)")
    ap.add_argument("--old", action="store_true", help="the previous plan: rotation-free book, burst retries of "
                    "wide views only, zoom out at the end (other flags but --frames/--unicast ignored)")
    ap.add_argument("--periods", type=int, default=3, help="code periods recorded per view (K = periods x L + 2)")
    ap.add_argument("--levels", default="0.111,0.333,1", help="refinement zoom ladder (fractions, ascending)")
    ap.add_argument("--sizes", default="100x2,100x4,1000x2,1000x4", help="scenes, motes x cameras")
    ap.add_argument("--seeds", type=int, default=1, help="seeded scenes per size (0..N-1); summary of the speed-ups")


def build_parser(description: str) -> argparse.ArgumentParser:
    """The command line (options in the order ``--help`` lists them)."""
    ap = argparse.ArgumentParser(description=description)
    for add in (_add_rig_arguments, _add_plan_arguments, _add_decoder_arguments, _add_round_arguments,
                _add_separation_arguments, _add_scope_arguments):
        add(ap)
    return ap


def check_scene_flags(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--seeds`` at least 1, ``--separation`` in [4, 64] px, and ``--near-decode`` and
    ``--crowd-decode`` only above 4 px; otherwise exits through ``ap.error`` (status 2)."""
    if args.seeds < 1:
        ap.error(f"--seeds: at least 1 ({args.seeds})")
    if not SEPARATION_PX <= args.separation <= 64.0:
        ap.error(f"--separation: px in [{SEPARATION_PX:g}, 64] ({args.separation})")
    if args.near_decode and args.separation <= SEPARATION_PX:
        ap.error(f"--near-decode: needs --separation above {SEPARATION_PX:g} px ({args.near_decode})")
    if args.crowd_decode and args.separation <= SEPARATION_PX:
        ap.error(f"--crowd-decode: needs --separation above {SEPARATION_PX:g} px ({args.crowd_decode[0]})")


def round_frames_of(text: str) -> tuple[int, int]:
    """``"18"`` -> (0, 18); ``"L+2"`` -> (1, 2); ``"2L+2"`` -> (2, 2): samples a L + b of a
    short-round view. ValueError unless at least one code length (a >= 1) or 8 samples."""
    t = text.replace(" ", "").upper()
    if "L" in t:
        a_txt, _, b_txt = t.partition("L")
        a = int(a_txt) if a_txt else 1
        b = int(b_txt) if b_txt else 0
        if a < 1 or b < 0:
            raise ValueError("a L + b needs a >= 1, b >= 0")
        return a, b
    k = int(t)
    if k < 8:
        raise ValueError("at least one code length (8 samples or more)")
    return 0, k


def _rate_of(text: str) -> Rate:
    """``pair_rate_table(text)`` as a Variant rate: the bare rate when the table has one row
    (``"RATE"``), else the table. ValueError when malformed or a rate is outside [0, 1]."""
    table = pair_rate_table(text)
    return table[0][1] if len(table) == 1 else table


def _base_variant(args: argparse.Namespace) -> Variant:
    """The Variant of the plain flags (booleans, counts, choices), every rate off."""
    return Variant(fields=not args.frames, broadcast=not args.unicast, sync=args.sync,
                   extend=args.extend, continuous_retry=not args.burst_retry,
                   retry_refinement=not args.no_refine_retry, zoom_out=args.zoom_out, need=args.need,
                   share_tiles=not args.separate_tiles, pick_ladder=not args.fixed_ladder,
                   separate=args.separate, round_miss_rate=args.round_miss_rate, round_order=args.round_order,
                   separation_px=args.separation)


def _with_short_rounds(variant: Variant, ap: argparse.ArgumentParser, args: argparse.Namespace) -> Variant:
    """``--round-frames K'`` (a count or a L + b) and its ``--round-miss-rate Q`` (in [0, 1))
    applied; a malformed or lone value exits through ``ap.error``."""
    if args.round_frames:
        try:
            variant = replace(variant, round_frames=round_frames_of(args.round_frames))
        except ValueError as exc:
            ap.error(f"--round-frames: {exc} ({args.round_frames})")
    if args.round_miss_rate is not None and not (args.round_frames and 0.0 <= args.round_miss_rate < 1.0):
        ap.error(f"--round-miss-rate: needs --round-frames and a rate in [0, 1) ({args.round_miss_rate})")
    return variant


def _with_rates(variant: Variant, ap: argparse.ArgumentParser, args: argparse.Namespace) -> Variant:
    """The crowd-decoding rates of :data:`RATE_FLAGS` applied (one rate, or per bound on the
    distance to the nearest other mote, px); a malformed one exits through ``ap.error``."""
    rates: dict[str, Any] = {}
    for flag, dest, name in RATE_FLAGS:
        value = getattr(args, dest)
        if not value:
            continue
        try:
            rates[name] = _rate_of(value)
        except ValueError as exc:
            ap.error(f"{flag}: {exc} ({value})")
    return replace(variant, **rates)


def _crowd_rates(ap: argparse.ArgumentParser, values: list[str]) -> tuple[tuple[int, Rate], ...]:
    """``--crowd-decode K=RATE|K=PX:RATE,...`` values as ``Variant.crowd_rates`` (ascending K,
    each of 3, 4, 5 at most once); a malformed one exits through ``ap.error``."""
    crowd_rates: dict[int, Rate] = {}
    for value in values:
        size, _, text = value.partition("=")
        try:
            k, rate = int(size), _rate_of(text)
            if not 3 <= k <= 5 or k in crowd_rates:
                raise ValueError(f"crowd size {k}: one of 3, 4, 5, each once")
        except ValueError as exc:
            ap.error(f"--crowd-decode: {exc} ({value})")
        crowd_rates[k] = rate
    return tuple(sorted(crowd_rates.items()))


def _with_partner_any(variant: Variant, ap: argparse.ArgumentParser, args: argparse.Namespace) -> Variant:
    """``--partner-any`` applied (with ``--partner-decode``), allowed only with
    ``--partner-decode 1`` (an upper bound); otherwise exits through ``ap.error``."""
    if args.partner_decode:
        variant = replace(variant, partner_any=args.partner_any)
    if args.partner_any and args.partner_decode.strip() not in ("1", "1.0"):
        ap.error(f"--partner-any: only with --partner-decode 1 (an upper bound) ({args.partner_decode or 'off'})")
    return variant


def variant_from_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> Variant:
    """The Variant of ``scripts/field_time.py``'s parsed command line; a bad flag exits
    through ``ap.error`` (one line, exit status 2). ``--old``: :data:`OLD` with only
    ``--frames`` and ``--unicast`` applied (the other flags are still checked)."""
    variant = _with_short_rounds(_base_variant(args), ap, args)
    variant = _with_rates(variant, ap, args)
    variant = replace(variant, crowd_rates=_crowd_rates(ap, args.crowd_decode))
    variant = _with_partner_any(variant, ap, args)
    if args.old:
        variant = replace(OLD, fields=not args.frames, broadcast=not args.unicast)
    return variant
