"""Cover rounds: radio rounds that leave one member of each crowded group unread.

Radio separation (:mod:`fgloc.survey.field_plan_radio`) colours the conflict graph so
every crowded mote is lit alone in some round. With the known-partner decoder
(:mod:`fgloc.camera.blink_partner`) that is more than needed: once every member but one
of a crowded group has been read in a round (ID, word and pixel known), the last one is
decoded from the wide recording that already exists. So a camera needs only all but one
member of each of its crowded groups read, and the rounds are a *cover*: lit sets,
independent in the conflict graph, that together hold every required member.

:func:`cover_colour` picks the member each eligible group leaves unread (greedy, so the
graph induced on the required motes loses as many edges, and odd cycles, as it can),
colours the required motes (:func:`fgloc.survey.view_planner.colour_conflicts`) and
puts the unread members whose known-partner decode fails (learnt only after their
partners' round, never assumed away) into the first later round they fit.
"""

from __future__ import annotations

import numpy as np

from fgloc.survey.view_planner import colour_conflicts


def components(n: int, edges: np.ndarray) -> list[list[int]]:
    """Connected components (sorted members, ascending by first member) of the graph on
    ``n`` vertices with ``edges`` (E, 2), vertices in no edge left out."""
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in np.asarray(edges, int).reshape(-1, 2).tolist():
        parent[root(a)] = root(b)
    groups: dict[int, list[int]] = {}
    for v in sorted(set(np.asarray(edges, int).ravel().tolist())):
        groups.setdefault(root(v), []).append(v)
    return sorted(groups.values())


def _colours(n: int, required: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Colour the graph induced on ``required`` (isolated required motes: colour 0)."""
    e = edges[required[edges[:, 0]] & required[edges[:, 1]]] if len(edges) else edges
    colour = colour_conflicts(n, e)
    colour[required & (colour < 0)] = 0
    colour[~required] = -1
    return colour


def cover_colour(
    n: int, edges: dict[str, np.ndarray], targets: dict[str, np.ndarray],
    eligible: dict[str, np.ndarray], ok: dict[str, np.ndarray] | None = None, sweeps: int = 2,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Plan cover rounds.

    ``edges[camera]``: (E, 2) conflict pairs of that camera (the motes it must separate);
    ``targets[camera]``: (n,) bool, the conflicting motes it must read;
    ``eligible[camera]``: (n,) bool, motes whose crowded group (connected component of
    that camera's conflict graph) may leave one member to the known-partner decoder;
    ``ok[camera]`` (default ``eligible``): the groups whose known-partner decode succeeds.
    Per camera and eligible group, one target member is left unread: greedily the one
    whose removal takes the most edges out of the graph induced on the motes still
    required by some camera, then ``sweeps`` passes of local search that move a group's
    unread member when that needs fewer colours (ties: fewer required motes).
    Returns the colour (round) per mote (-1: lit in no round) and, per camera, the motes
    it must read (its targets minus the unread ones whose decode succeeds). An unread mote
    whose decode fails is known to fail once the last of its group's other members has
    been read (the decode runs on the wide recording between rounds): it is lit, for the
    cameras that left it, in the first later round in which none of its conflict
    neighbours is lit (a new round after the cover rounds if none)."""
    ok = eligible if ok is None else ok
    all_edges = np.vstack([np.asarray(e, int).reshape(-1, 2) for e in edges.values()] or [np.zeros((0, 2), int)])
    groups: list[tuple[str, list[int]]] = []
    for c, e in edges.items():
        for g in components(n, e):
            members = [v for v in g if targets[c][v]]
            if len(members) == len(g) and all(eligible[c][v] for v in g):
                groups.append((c, members))
    need: dict[int, int] = {}  # how many cameras require each mote
    for c in targets:
        for v in np.flatnonzero(targets[c]).tolist():
            need[v] = need.get(v, 0) + 1
    skip: list[int] = []
    adj: dict[int, set[int]] = {}
    for a, b in all_edges.tolist():
        adj.setdefault(a, set()).add(b)
        adj.setdefault(b, set()).add(a)
    groups.sort(key=lambda cg: -len(cg[1]))  # larger groups choose first
    for _, members in groups:
        def gain(v: int) -> tuple[int, int]:
            if need[v] > 1:
                return (0, -v)
            return (sum(1 for u in adj.get(v, ()) if need.get(u, 0) > 0), -v)
        v = max(members, key=gain)
        need[v] -= 1
        skip.append(v)

    def required_mask() -> np.ndarray:
        m = np.zeros(n, bool)
        for v, k in need.items():
            if k > 0:
                m[v] = True
        return m

    def score() -> tuple[int, int]:
        req = required_mask()
        col = _colours(n, req, all_edges)
        return (int(col.max()) + 1 if req.any() else 0, int(req.sum()))

    best = score()
    for _ in range(sweeps):
        improved = False
        for gi, (_, members) in enumerate(groups):
            for v in members:
                if v == skip[gi]:
                    continue
                old = skip[gi]
                need[old] += 1
                need[v] -= 1
                s = score()
                if s < best:
                    best, skip[gi], improved = s, v, True
                else:
                    need[v] += 1
                    need[old] -= 1
        if not improved:
            break
    colour = _colours(n, required_mask(), all_edges)
    reads = {c: np.asarray(t, bool).copy() for c, t in targets.items()}
    after: dict[int, int] = {}  # failed unread mote -> first round after its group's members were read
    for (c, members), v in zip(groups, skip):
        if ok[c][v]:
            reads[c][v] = False
        elif colour[v] < 0:  # no camera reads it in a cover round: read it once its failure is known
            done = max(int(colour[u]) for u in members if u != v) + 1
            after[v] = max(after.get(v, 0), done)
    for v in sorted(after, key=lambda u: (after[u], u)):
        r = after[v]
        while any(colour[u] == r for u in adj.get(v, ())):
            r += 1
        colour[v] = r
    return colour, reads
