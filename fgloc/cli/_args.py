"""Checks of command-line flag values: a bad value is one line naming the flag (exit 2).

argparse converts the text (``type=float`` also accepts ``nan`` and ``inf``); these
checks say what the value must be, so that every command refuses alike:
``--baseline-m: expected a finite number > 0, got nan``.
"""

from __future__ import annotations

import math

from fgloc.core.errors import FglocError


class FlagError(FglocError):
    """A command-line flag whose value cannot mean what the flag says."""


def finite(flag: str, value: float, *, above: float | None = None, at_least: float | None = None,
           at_most: float | None = None) -> float:
    """``value`` when finite and within the given bounds; else :class:`FlagError` naming ``flag``."""
    bounds = [f"> {above:g}" if above is not None else "", f">= {at_least:g}" if at_least is not None else "",
              f"<= {at_most:g}" if at_most is not None else ""]
    expected = ("a finite number " + " and ".join(b for b in bounds if b)).strip()
    ok = (math.isfinite(value) and (above is None or value > above) and (at_least is None or value >= at_least)
          and (at_most is None or value <= at_most))
    if not ok:
        raise FlagError(f"{flag}: expected {expected}, got {value!r}")
    return value


def integer(flag: str, value: int, *, at_least: int) -> int:
    """``value`` when ``>= at_least``; else :class:`FlagError` naming ``flag``."""
    if value < at_least:
        raise FlagError(f"{flag}: expected an integer >= {at_least}, got {value}")
    return value
