"""Survey planning by the Cramér–Rao bound: where to put the cameras, what to re-measure.

Layer: above :mod:`fgloc.evaluate` (its sweeps validate every plan by Monte Carlo).
See docs/planning.md.
"""
