"""Random subset schedules for the paper's subset-averaging procedure.

A schedule is a list of ``T`` subsets, each an array of ``k`` distinct node
indices (sorted). Subsets are cut from successive random permutations of the
nodes, so every node is covered as evenly as possible (``T k / N`` times on
average, differing by at most one between nodes when ``T k`` is a multiple of
``N``). Shared by the simulator (which re-measures each subset) and the
baseline solver (which draws its own subsets for untagged surveys).
"""

from __future__ import annotations

import numpy as np

from fgloc.core.errors import FglocError


def draw_subsets(n_nodes: int, subset_size: int, n_subsets: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``n_subsets`` random subsets of ``subset_size`` distinct nodes out of ``n_nodes``."""
    if not 1 <= subset_size <= n_nodes:
        raise FglocError(f"subset size must be in 1..{n_nodes}, got {subset_size}")
    if n_subsets < 1:
        raise FglocError(f"number of subsets must be >= 1, got {n_subsets}")
    out: list[np.ndarray] = []
    deck: list[int] = []
    while len(out) < n_subsets:
        if len(deck) < subset_size:
            rest = set(deck)
            deck = deck + [int(j) for j in rng.permutation(n_nodes) if int(j) not in rest]
        out.append(np.array(sorted(deck[:subset_size]), dtype=np.int64))
        deck = deck[subset_size:]
    return out


def subsets_for_coverage(n_nodes: int, subset_size: int, coverage: float) -> int:
    """Number of subsets so that each node lies in about ``coverage`` subsets."""
    return max(1, int(round(coverage * n_nodes / subset_size)))
