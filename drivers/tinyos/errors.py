"""Mote-network failures: one tree under :class:`MoteError` (one-line messages, safe to show a user)."""

from __future__ import annotations

from fgloc.core.errors import FglocError


class MoteError(FglocError):
    """Base of mote-network failures (one line, safe to show a user)."""


class MoteTimeout(MoteError):
    """The base station did not acknowledge a frame after all retries."""


class MoteDisconnected(MoteError):
    """The serial port or SerialForwarder connection went away."""


class MoteProtocolError(MoteError):
    """The peer spoke something else (bad SF handshake, unknown-protocol reply)."""
