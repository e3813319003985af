"""Read an .rrd back for assertions (rerun.chunk.RrdReader + pyarrow; see
shared/reference/rerun-checks.md). Colours come back packed as 0xRRGGBBAA."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rerun.chunk import RrdReader


@dataclass
class EntityRows:
    """Every row logged to one entity: static rows and (time, row) per timeline."""

    static: dict[str, list] = field(default_factory=dict)  # component column -> list of rows
    timed: dict[str, dict[str, list[tuple[int, object]]]] = field(default_factory=dict)  # timeline -> column -> rows


def load_rrd(path: str | Path) -> dict[str, EntityRows]:
    """Entity path (without the leading '/') -> its rows, from the recording store."""
    out: dict[str, EntityRows] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        name = chunk.entity_path.lstrip("/")
        rows = out.setdefault(name, EntityRows())
        rb = chunk.to_record_batch()
        comps = [c for c in rb.schema.names if ":" in c and not c.startswith("rerun.")]
        if chunk.is_static:
            for c in comps:
                rows.static.setdefault(c, []).extend(rb.column(c).to_pylist())
            continue
        for tl in chunk.timeline_names:
            if tl == "log_time":
                continue
            times = rb.column(tl).to_pylist()
            for c in comps:
                rows.timed.setdefault(tl, {}).setdefault(c, []).extend(zip(times, rb.column(c).to_pylist()))
    for rows in out.values():
        for cols in rows.timed.values():
            for c in cols:
                cols[c].sort(key=lambda tv: tv[0])
    return out


def last_static(entities: dict[str, EntityRows], entity: str, component: str) -> np.ndarray:
    """The last static value of a component as an array."""
    return np.asarray(entities[entity].static[component][-1])


def unpack_rgba(packed: object) -> np.ndarray:
    """Packed 0xRRGGBBAA uint32 colours -> (N, 4) uint8."""
    p = np.asarray(packed, dtype=np.uint64).reshape(-1)
    return np.stack([(p >> 24) & 255, (p >> 16) & 255, (p >> 8) & 255, p & 255], axis=1).astype(np.uint8)
