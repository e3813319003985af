"""Cover rounds: every crowded group but one member read in a round, the rest by the known-partner decoder."""

from __future__ import annotations

import itertools
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.survey.field_plan_cover import components, cover_colour
from fgloc.survey.field_plan_radio import radio_separation
from fgloc.survey.view_planner import colour_conflicts

ROOT = Path(__file__).resolve().parents[1]


def _mask(n: int, idx: list[int]) -> np.ndarray:
    m = np.zeros(n, bool)
    m[idx] = True
    return m


def _check_cover(n: int, edges: dict[str, np.ndarray], colour: np.ndarray, reads: dict[str, np.ndarray]) -> None:
    """Lit sets independent in every camera's conflicts; each group has <= 1 member unread."""
    for e in edges.values():
        for a, b in e.tolist():
            assert not (colour[a] >= 0 and colour[a] == colour[b])
    for c, e in edges.items():
        for g in components(n, e):
            assert sum(1 for v in g if not reads[c][v]) <= 1
            assert all(colour[v] >= 0 for v in g if reads[c][v])


def test_odd_cycle_needs_two_rounds_not_three() -> None:
    n = 5
    cycle = np.array([[i, (i + 1) % 5] for i in range(5)])
    assert colour_conflicts(n, cycle).max() + 1 == 3
    t = {"a": _mask(n, list(range(5)))}
    colour, reads = cover_colour(n, {"a": cycle}, t, t)
    assert colour.max() + 1 == 2
    assert (~reads["a"]).sum() == 1 and colour[~reads["a"]][0] == -1
    _check_cover(n, {"a": cycle}, colour, reads)


def test_triangle_and_shared_mote_across_cameras() -> None:
    n = 6
    edges = {"a": np.array([[0, 1], [0, 2], [1, 2], [3, 4]]), "b": np.array([[3, 5]])}
    t = {"a": _mask(n, [0, 1, 2, 3, 4]), "b": _mask(n, [3, 5])}
    colour, reads = cover_colour(n, edges, t, t)
    _check_cover(n, edges, colour, reads)
    assert colour.max() + 1 == 2  # the triangle: two members read, adjacent
    assert colour[4] == -1 and colour[5] == -1 and colour[3] >= 0  # 3 read once serves both cameras
    # not eligible: the plain colouring of every conflicting mote
    none = {c: np.zeros(n, bool) for c in t}
    colour0, reads0 = cover_colour(n, edges, t, none)
    assert np.array_equal(colour0, colour_conflicts(n, np.vstack(list(edges.values()))))
    assert all(np.array_equal(reads0[c], t[c]) for c in t)


def test_failed_partner_decode_is_read_in_an_extra_round() -> None:
    n = 4
    edges = {"a": np.array([[0, 1], [2, 3]])}
    t = {"a": _mask(n, [0, 1, 2, 3])}
    colour, reads = cover_colour(n, edges, t, t)
    assert colour.max() == 0
    unread = np.flatnonzero(~reads["a"])
    ok = {"a": t["a"].copy()}
    ok["a"][unread[0]] = False  # that group's known-partner decode fails
    colour_f, reads_f = cover_colour(n, edges, t, t, ok)
    assert colour_f[unread[0]] == 1 and reads_f["a"][unread[0]]  # after the cover round, read by "a"
    assert colour_f[unread[1]] == -1 and not reads_f["a"][unread[1]]
    _check_cover(n, edges, colour_f, reads_f)


def test_random_graphs_cover_never_needs_more_rounds_than_colouring() -> None:
    rng = np.random.default_rng(3)
    for _ in range(30):
        n = 14
        edges = {}
        for c in ("a", "b"):
            e = [(i, j) for i, j in itertools.combinations(range(n), 2) if rng.random() < 0.12]
            edges[c] = np.array(e, int).reshape(-1, 2)
        t = {c: _mask(n, sorted(set(edges[c].ravel().tolist()))) for c in edges}
        colour, reads = cover_colour(n, edges, t, t)
        _check_cover(n, edges, colour, reads)
        full = colour_conflicts(n, np.vstack(list(edges.values())))
        assert colour.max() <= full.max()


def test_radio_separation_with_partner_reads_one_of_a_pair() -> None:
    intr = CameraIntrinsics.from_fov(640, 480, 65.0)
    px = 1.0 / intr.fx
    pt = np.array([[0.0, 0.0], [2 * px, 0.0], [0.2, 0.05], [0.2 + 2 * px, 0.05]])
    views = {"a": [(0.0, 0.0), (0.2, 0.05)]}
    off = radio_separation(intr, {"a": pt}, views, 4.0, ("a",))
    assert off.classes == 2 and sum(len(r.views) for r in off.rounds["a"]) == 2
    on = radio_separation(intr, {"a": pt}, views, 4.0, ("a",), partner={"a": np.ones(4, bool)})
    assert on.classes == 1 and (on.colour >= 0).sum() == 2
    assert sum(len(r.views) for r in on.rounds["a"]) <= 2 and sum(sum(r.view_targets) for r in on.rounds["a"]) == 2


def test_field_time_lever_off_unchanged_and_upper_bound_shorter(field_time: ModuleType) -> None:
    from fgloc.survey.clock import EVI_D100, CameraTiming, RigTiming
    from fgloc.survey.field_plans import pair_rate_table
    ft = field_time
    timing = RigTiming(head=EVI_D100, camera=CameraTiming(frame_rate_hz=30000.0 / 1001.0))
    base = ft.Variant(separate="radio", pair_rate=pair_rate_table("6:0.023,8:0.296,12:0.449,inf:0.473"),
                      round_frames=(1, 2), round_miss_rate=0.2552)
    off = ft.run(100, 2, timing, 0.1257, variant=base)
    zero = ft.run(100, 2, timing, 0.1257, variant=replace(base, partner_rate=0.0))
    assert zero["coded"] == off["coded"] and zero["phases"] == off["phases"]
    bound = ft.run(100, 2, timing, 0.1257, variant=replace(base, partner_rate=1.0, partner_any=True))
    assert bound["coded"] < off["coded"] and bound["round_views"] < off["round_views"]
    for ph in ("slew", "settle", "position"):  # the wide pass is untouched (round slews are in "separate")
        assert bound["phases"][ph] == pytest.approx(off["phases"][ph])


@pytest.mark.parametrize("args", [["--partner-decode", "1.5"], ["--partner-any"],
                                  ["--partner-decode", "0.8", "--partner-any"]])
def test_bad_partner_flags_are_one_line_exit_2(args: list[str]) -> None:
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "field_time.py"), "--sizes", "100x2", *args],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert "--partner-" in res.stderr.strip().splitlines()[-1] and "Traceback" not in res.stderr
