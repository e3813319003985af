"""How ``scripts/field_time.py`` runs the coded survey: :class:`Variant` and its constants
(the command line that builds one: ``scripts/field_time_cli.py``).

Units: pixels (px) at the wide zoom for separations and rate-table bounds, seconds for
times, samples (video frames or fields) for recording lengths; zooms are fractions of the
optical range (1x..10x). Rates are shares in [0, 1]: one number, or a table
``((max_px, rate), ..., (inf, rate))`` by a distance in px (:func:`pair_rate_table`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

SEPARATION_PX = 4.0  #: crowds (pairs, groups of three) are motes closer than this at the wide zoom
#: candidate refinement zoom ladders (fractions of the optical range, 1x..10x): the old one first
LADDERS = ((1 / 9, 3 / 9, 1.0), (1 / 9, 2 / 9, 4 / 9, 1.0), (0.2, 0.5, 1.0), (1 / 18, 1 / 9, 2 / 9, 1 / 3, 5 / 9, 1.0))
RESYNC_S = 10.0  #: the synchronized book's start is repeated every this many seconds

#: a share of motes read: one rate, or a table ((max_px, rate), ..., (inf, rate)) by a distance in px
Rate: TypeAlias = float | tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class Variant:
    """How the coded survey is run (see ``scripts/field_time.py``'s module docstring)."""

    fields: bool = True  #: decode fields on interlaced heads
    broadcast: bool = True  #: one broadcast start, not one unicast per mote
    sync: bool = False  #: synchronized book (epoch broadcast, resync every RESYNC_S)
    extend: int = 0  #: more code lengths recorded in every view (sliding windows)
    continuous_retry: bool = True  #: a retry goes on recording one code length, not a new burst
    retry_refinement: bool = True  #: refinement views are retried like wide views
    zoom_out: bool = False  #: zoom back out after the last refinement pass
    need: int = 0  #: refine a mote only where fewer than this many other cameras resolve it (0: always)
    share_tiles: bool = True  #: a higher-zoom refinement tile also serves lower-zoom targets it covers
    pick_ladder: bool = True  #: per camera, the zoom ladder of LADDERS whose refinement is cheapest on the clock
    #: crowded motes: "zoom" refinement only; "radio": every camera pauses colour classes and
    #: re-records its wide views; "best": the cheapest subset of cameras doing so, on the clock
    separate: str = "zoom"
    #: pair decoding: share of crowded groups of exactly two that the pair decoder resolves in
    #: the wide view (measured, scripts/blink_montecarlo.py --pairs); 0: off
    pair_rate: Rate = 0.0
    #: group decoding: the same for crowded groups of exactly three (blink_montecarlo.py --groups); 0: off
    group_rate: Rate = 0.0
    #: short rounds: radio-round views record this many samples, labelled against the class's
    #: candidates (blink_candidates); 0: off (a round view records K like a wide view)
    round_frames: tuple[int, int] = (0, 0)  #: (a, b): a L + b samples; (0, 0): off
    #: isolated miss rate of a short-round view (blink_candidates_montecarlo.py --candidates); None: the wide rate
    round_miss_rate: float | None = None
    #: cover rounds: share of crowded groups of exactly two whose unread member the known-partner
    #: decoder reads from the wide view once the other was read in a round (blink_montecarlo.py
    #: --partner), or a table by the distance to the nearest third mote; 0: off (colour rounds)
    partner_rate: Rate = 0.0
    partner_any: bool = False  #: every crowded group may leave one member unread (upper bound only)
    #: the same for crowded groups of exactly three (two read in rounds, the third decoded); 0: off
    partner_group_rate: Rate = 0.0
    #: radio rounds: "class" (class-major), "view" (each camera's round views shared across classes,
    #: it stays on a view while its classes take turns: field_plan_radio.view_major_round_time) or
    #: "best" (the cheaper of the two on the clock)
    round_order: str = "class"
    #: the blind decoder reads a mote as isolated when no other lies this close (px) at the wide
    #: zoom; 4 (the default, every earlier table) is the crowd criterion; a larger value with
    #: ``near_rate`` prices the measured read rate of motes whose neighbour lies between 4 px and it
    separation_px: float = SEPARATION_PX
    #: share of those motes the blind decoder reads (blink_near_montecarlo.py), or a table by
    #: the nearest neighbour's distance; 0: none is read (all refined or separated)
    near_rate: Rate = 0.0
    #: crowds of k motes alone at ``separation_px`` (k, rate or table by each mote's nearest
    #: neighbour, blink_near_montecarlo.py --group k --pairs): the share of their motes the
    #: decoder reads in the wide view (field_plans.crowd_decoding); their draws replace the
    #: pair and group decoders' draws of the crowds within 4 px inside them; (): none is read
    crowd_rates: tuple[tuple[int, Rate], ...] = ()


#: the previous plan: burst retries of wide views only, separate tiles on the fixed ladder, zoom-out
OLD = Variant(continuous_retry=False, retry_refinement=False, zoom_out=True, share_tiles=False,
              pick_ladder=False)
