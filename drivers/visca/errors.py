"""VISCA failures: one exception tree under :class:`ViscaError`, and the error-reply classes.

Error replies are ``z0 6y ee FF`` (``shared/reference/protocols.md`` 1.4): ``y`` the socket,
``ee`` the code; :func:`error_for` maps a code to its exception class.
"""

from __future__ import annotations

from fgloc.core.errors import FglocError


class ViscaError(FglocError):
    """Base of every VISCA failure (one-line message, safe to show a user)."""


class ViscaTimeout(ViscaError):
    """No (valid) reply within the timeout after all retries."""


class ViscaDisconnected(ViscaError):
    """The port or connection went away (device unplugged, pty closed, socket error)."""


class ViscaProtocolError(ViscaError):
    """A reply that cannot be what we asked for (wrong length, bad nibbles)."""


class ViscaGarbledReply(ViscaProtocolError):
    """An inquiry reply that arrived corrupted (wrong data length, bad nibbles); asking again may succeed."""


class ViscaErrorReply(ViscaError):
    """The camera answered with an error packet ``z0 6y ee FF``."""

    code: int = -1
    meaning: str = "unknown error"

    def __init__(self, socket: int, code: int | None = None, command: str = "") -> None:
        self.socket = socket
        if code is not None:
            self.code = code
        what = f" to {command}" if command else ""
        super().__init__(f"camera replied '{self.meaning}' (error 0x{self.code:02X}, socket {socket}){what}")


class MessageLengthError(ViscaErrorReply):
    code, meaning = 0x01, "message length error"


class ViscaSyntaxError(ViscaErrorReply):
    code, meaning = 0x02, "syntax error"


class CommandBufferFull(ViscaErrorReply):
    code, meaning = 0x03, "command buffer full"


class CommandCanceled(ViscaErrorReply):
    code, meaning = 0x04, "command canceled"


class NoSocket(ViscaErrorReply):
    code, meaning = 0x05, "no socket"


class CommandNotExecutable(ViscaErrorReply):
    code, meaning = 0x41, "command not executable"


ERROR_CLASSES: dict[int, type[ViscaErrorReply]] = {
    cls.code: cls
    for cls in (MessageLengthError, ViscaSyntaxError, CommandBufferFull, CommandCanceled, NoSocket,
                CommandNotExecutable)
}


def error_for(code: int, socket: int, command: str = "") -> ViscaErrorReply:
    """The exception instance for an error code (unknown codes keep their number)."""
    cls = ERROR_CLASSES.get(code)
    if cls is None:
        exc = ViscaErrorReply(socket, code, command)
        return exc
    return cls(socket, None, command)
