"""What the command line shows besides results: log records and progress bars.

Library code only logs (``logging.getLogger(__name__)`` under the ``fgloc``
logger) and reports progress through callbacks; the CLI decides what reaches
the terminal. :func:`logging_to_stderr` sends the ``fgloc`` records to stderr
at the level ``-v``/``-q`` chose, and :func:`progress_bar` /
:class:`StepBar` draw tqdm bars on stderr, only when it is a terminal and
``-q`` was not given. Log lines are written through ``tqdm.write`` so that
they never tear a bar apart.

tqdm is imported inside the functions: building the parser imports nothing
but argparse and the standard library.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from fgloc.core.redact import redact_urls

if TYPE_CHECKING:
    from tqdm import tqdm

PACKAGE_LOGGER = "fgloc"


def level_for(verbose: int, quiet: bool) -> int:
    """The log level of ``-v`` (counted) and ``-q``: WARNING by default, INFO, DEBUG, or ERROR."""
    if quiet:
        return logging.ERROR
    if verbose >= 2:
        return logging.DEBUG
    return logging.INFO if verbose == 1 else logging.WARNING


class StderrFormatter(logging.Formatter):
    """``fgloc: warning: message`` (DEBUG adds the logger name: ``fgloc: debug: fgloc.x: message``)."""

    def format(self, record: logging.LogRecord) -> str:
        level = record.levelname.lower()
        where = f"{record.name}: " if record.levelno <= logging.DEBUG else ""
        text = f"fgloc: {level}: {where}{record.getMessage()}"
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return redact_urls(text)


class StderrHandler(logging.Handler):
    """Writes each record to the ``sys.stderr`` of the moment, through ``tqdm.write`` (bars stay intact)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never raise into the caller
            self.handleError(record)


@contextmanager
def logging_to_stderr(level: int) -> Iterator[logging.Handler]:
    """Show the ``fgloc`` logger's records at ``level`` and above on stderr, for the duration.

    The logger's previous level and handlers are restored afterwards, so ``main()`` can be
    called repeatedly in one process (tests) without stacking handlers."""
    logger = logging.getLogger(PACKAGE_LOGGER)
    handler = StderrHandler(level)
    handler.setFormatter(StderrFormatter())
    old_level = logger.level
    logger.addHandler(handler)
    logger.setLevel(level)
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)


def progress_bar(enabled: bool, **options: Any) -> tqdm:
    """A tqdm bar on stderr; drawn only when ``enabled`` and stderr is a terminal (``disable=None``)."""
    from tqdm import tqdm

    options.setdefault("dynamic_ncols", True)
    options.setdefault("leave", False)
    return tqdm(file=sys.stderr, disable=None if enabled else True, **options)


class StepBar:
    """A bar driven by a library's ``progress(done, total)`` callback (pass the instance itself).

    Use as a context manager; the bar is created on the first call (when the total is known)."""

    def __init__(self, enabled: bool, desc: str, unit: str = "step") -> None:
        self.enabled = enabled
        self.desc = desc
        self.unit = unit
        self.bar: tqdm | None = None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            self.bar = progress_bar(self.enabled, total=total, desc=self.desc, unit=self.unit)
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.bar.n)

    def __enter__(self) -> StepBar:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()
