"""One writer per survey directory: an exclusive ``flock`` on ``DIR/survey.lock``.

The lock belongs to the open file, so the operating system releases it when the
process ends in any way (exit, exception, SIGKILL, power cut): a lock is never
stale and a killed survey resumes at once. The file itself stays (removing it would
let two processes lock two different files of the same name); it holds the holder's
``{"pid", "host", "started"}`` so that a refused second survey can name the running
one. ``flock`` is per open file, so two locks in one process conflict too.

Locks are advisory and local: on a network file system where ``flock`` does not
reach other hosts, two hosts can still both write (docs/survey.md).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from pathlib import Path

from fgloc.core.errors import FglocError

LOCK_NAME = "survey.lock"


class SurveyLocked(FglocError):
    """Another process is running a survey in this directory."""


def _holder(fd: int) -> str:
    """``pid 123 on host, since 2024-05-01 10:00:00`` from the lock file, or ``pid unknown``."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8"))
        pid, host = int(info["pid"]), str(info["host"])
        since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(info["started"])))
        if host == socket.gethostname():
            os.kill(pid, 0)  # the previous holder's record, not yet overwritten by a starting one?
    except PermissionError:  # alive, another user's
        pass
    except (ValueError, KeyError, TypeError, OSError, OverflowError):
        return "pid unknown: it is just starting"
    return f"pid {pid} on {host}, since {since}"


class SurveyLock:
    """Holds ``DIR/survey.lock`` exclusively until :meth:`release` (context manager).

    Raises :class:`SurveyLocked` (one line naming the running survey's pid and host)
    when another process holds it; never waits.
    """

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.path = Path(directory) / LOCK_NAME
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise SurveyLocked(f"{self.path.parent}: a survey is already running in this directory ({holder}); "
                               "wait for it or stop it, then --resume") from None
        except BaseException:
            os.close(fd)
            raise
        info = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "started": round(time.time(), 3)})
        os.ftruncate(fd, 0)
        os.pwrite(fd, (info + "\n").encode("utf-8"), 0)
        self._fd: int | None = fd

    def release(self) -> None:
        """Unlock (the file stays; its content is only read while someone holds the lock)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> SurveyLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
