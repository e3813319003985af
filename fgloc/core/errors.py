"""The one exception tree of fgloc: everything a user can cause is an :class:`FglocError`.

The command line turns an ``FglocError`` into one line on stderr and exit status 2;
library users catch ``FglocError`` (or a subclass) to tell bad input from bugs.
"""

from __future__ import annotations


class FglocError(Exception):
    """Base of every error fgloc reports to a user as one line."""


class FileFormatError(FglocError):
    """A file (survey, result, camera, rig, journal) that does not follow its documented format.

    The message is one line: ``FILE: FIELD: problem (got VALUE)``.
    """
