"""The Markdown table ``scripts/field_time.py`` prints: its header, one scene's rows
(:func:`report`) and the speed-up summary over seeds.

A scene's result is the dict of ``field_time.run``: times in seconds, counts of views and
motes, retry fractions (shares of views retried), the decode rate in Hz. A row that is not
a scene's first starts with an empty cell and ends with the table's remaining separators.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from field_time_variants import Variant  # noqa: E402

#: the table's columns (one scene's first row, :func:`report`)
HEADER = ("| motes | cameras | sequential (s) | coded (s) | speed-up | L | samples/view | decode rate (Hz) | "
          "views/camera | refinement views | retried views (wide / refinement) | unresolved | "
          "radio cameras | colour classes | radio round views (retry) |")
RULE = "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
FILL = "|||||||||||"  #: closes a row whose text spans the columns after the first


def print_header(args: argparse.Namespace, levels: tuple[float, ...], variant: Variant) -> None:
    """The run's settings line (head, frame rate in frames/s, miss rate, refinement zooms as
    fractions of the optical range, the variant), then the table's header and rule."""
    print(f"head {args.head}, {args.fps:.2f} frames/s, miss rate {args.miss_rate}, refinement zooms {levels}, {variant}")
    print(HEADER)
    print(RULE)


def _scene_row(r: dict[str, Any]) -> str:
    """The scene's row of the table: the times (s), the speed-up (sequential / coded) and the counts."""
    n, c = r["motes"], r["cameras"]
    return (f"| {n} | {c} | {r['seq']:.1f} | {r['coded']:.1f} | {r['seq'] / r['coded']:.1f}x | {r['L']} | "
            f"{r['K']} | {r['rate']:.2f} | {r['views']:.1f} | {r['refine']} | {r['retry']:.2f} / "
            f"{r['refine_retry']:.2f} | {r['unresolved']} | {r['radio_cams']} | {r['classes']} | "
            f"{r['round_views']} ({r['radio_retry']:.2f}) |")


def _phase_rows(r: dict[str, Any]) -> list[str]:
    """The sequential and the coded survey's time by phase (s)."""
    return [f"|   | sequential phases: {r['seq_desc']} (not found {r['missing']}) {FILL}",
            f"|   | coded phases: {r['coded_desc']} {FILL}"]


def _decoder_rows(r: dict[str, Any], variant: Variant, miss_rate: float) -> list[str]:
    """One row per lever the variant turns on: short rounds (samples per round view, candidate
    miss rate), pair, group and crowd decoding (counts over the cameras; distances in px)."""
    rows: list[str] = []
    if r["round_K"]:
        rows.append(f"|   | short rounds: {r['round_K']} samples per round view, candidate miss rate "
                    f"{variant.round_miss_rate if variant.round_miss_rate is not None else miss_rate} {FILL}")
    if variant.pair_rate:
        rows.append(f"|   | pair decoding: {r['pairs']} crowded pairs of exactly two over the cameras "
                    f"({r['pairs_third8']} with a third mote within 8 px), {r['pairs_resolved']} resolved; "
                    f"{r['crowded']} crowded mote-views {FILL}")
    if variant.group_rate:
        rows.append(f"|   | group decoding: {r['groups']} crowded groups of exactly three over the cameras "
                    f"({r['groups_fourth8']} with a fourth mote within 8 px), {r['groups_resolved']} resolved {FILL}")
    if variant.crowd_rates:
        rows.append(f"|   | crowd decoding: {r['crowd_motes']} mote-views in crowds of "
                    f"{', '.join(str(k) for k, _ in variant.crowd_rates)} alone at {variant.separation_px:g} px, "
                    f"{r['crowd_read']} read in the wide view {FILL}")
    return rows


def report(r: dict[str, Any], variant: Variant, args: argparse.Namespace) -> float:
    """Print one scene's rows; returns its speed-up (sequential over coded time)."""
    for row in [_scene_row(r), *_phase_rows(r), *_decoder_rows(r, variant, args.miss_rate)]:
        print(row)
    return r["seq"] / r["coded"]


def print_seed_summary(n_motes: int, n_cams: int, seeds: int, speedups: list[float]) -> None:
    """With more than one seed, the median and range of the speed-ups of the scenes of one size."""
    if seeds > 1:
        print(f"|   | {n_motes} x {n_cams} over seeds 0..{seeds - 1}: speed-up median {np.median(speedups):.1f}x "
              f"(range {min(speedups):.1f}-{max(speedups):.1f}x) {FILL}")
