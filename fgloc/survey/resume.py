"""May a journal be continued with this rig.json? (docs/survey.md, "Resuming after a rig.json edit")

A journal written by ``fgloc survey`` keeps, in its header, the rig.json fields that fix
what its readings mean (:func:`fgloc.files.rig_config.rig_meaning`: cameras, their
models, mountings, zoom and intrinsics, nodes and mote addresses, gauge, sigma,
repeats, the measurement method, a simulated scene) and the operational rest
(:func:`fgloc.files.rig_config.rig_operational`: ports, credentials, video sources,
timeouts, retries, back-off, the search pattern, twin faults; URL user info redacted).

:func:`resume_change` compares a rig with the journal: the same rig (same full hash)
continues as before; a rig whose meaning differs is refused with one line naming the
first field that differs; a rig that differs only in operational fields is accepted, and
the session journals a ``rig_changed`` record naming the changed fields (a password
change shows as ``(credentials, or fields fgloc ignores)``: its value is never written).
Journals from before the split (no ``rig_meaning`` in the header) accept only the
identical rig.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fgloc.core.errors import FglocError
from fgloc.core.redact import redact_urls
from fgloc.files.journal import JournalState
from fgloc.files.json_io import show_value
from fgloc.files.rig_config import RigConfig, rig_meaning, rig_operational

UNSEEN_CHANGE = "(credentials, or fields fgloc ignores)"
_MISSING = object()


class ResumeRefused(FglocError):
    """The rig.json differs from the journal's in a field that changes what the readings mean."""

    def __init__(self, message: str) -> None:
        super().__init__(redact_urls(message))


def _plain(doc: dict[str, Any]) -> dict[str, Any]:
    """``doc`` as it reads back from the journal (tuples become lists, floats keep every bit)."""
    out: dict[str, Any] = json.loads(json.dumps(doc, allow_nan=False))
    return out


def _show(value: object) -> str:
    return "absent" if value is _MISSING else show_value(value)


def resume_change(rig: RigConfig, state: JournalState, journal: str | Path, simulated: bool
                  ) -> tuple[list[str], dict[str, Any]] | None:
    """None when ``rig`` is the rig the journal runs with; (changed fields, new operational
    fields) when it differs only operationally; raises :class:`ResumeRefused` otherwise."""
    header = state.header
    was_simulated = bool(header.meta.get("simulated")) if isinstance(header.meta, dict) else False
    if "simulated" in header.meta and was_simulated != simulated:
        raise ResumeRefused(f"--simulate: {journal} was recorded {'with' if was_simulated else 'without'} "
                            f"--simulate; resume it the same way")
    if state.rig_hash == rig.hash:
        return None
    if header.rig_meaning is None:
        raise ResumeRefused(f"{journal}: header.rig_hash: journal was recorded with a different {rig.path}")
    now, was = _plain(rig_meaning(rig, simulated)), header.rig_meaning
    for key in [*now, *(k for k in was if k not in now)]:
        a, b = was.get(key, _MISSING), now.get(key, _MISSING)
        if a != b:
            raise ResumeRefused(f"{rig.path}: {key}: changes what the readings recorded in {journal} mean "
                                f"(was {_show(a)}, now {_show(b)}); undo the change, or survey into a new directory")
    op_now, op_was = _plain(rig_operational(rig)), state.rig_operational or {}
    changed = [k for k in [*op_now, *(k for k in op_was if k not in op_now)]
               if op_now.get(k, _MISSING) != op_was.get(k, _MISSING)]
    return changed or [UNSEEN_CHANGE], op_now
