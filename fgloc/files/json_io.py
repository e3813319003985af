"""Reading a JSON file field by field, every problem one line ``file: field: problem (got value)``.

:func:`load_json` reads and parses a file; :class:`JsonFields` checks the fields of
the parsed document (types, finiteness, sizes, unique ids). Both raise the error
class the caller names, so each file format keeps its own exception type
(:class:`fgloc.core.errors.FileFormatError` and its subclasses). :func:`write_json_atomic`
writes a JSON document so that a reader sees either the old or the complete new file.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def show_value(value: Any) -> str:
    """``value`` as the JSON a user wrote (NaN and Infinity as the JSON literals), cut to 60 characters."""
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def load_json(path: str | os.PathLike[str], error: type[Exception]) -> Any:
    """The parsed JSON document at ``path``; a missing, unreadable or invalid file raises ``error``."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read: {exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None


class JsonFields:
    """Typed field access to one JSON document that raises ``error`` as ``file: field: problem``."""

    def __init__(self, path: str, error: type[Exception]) -> None:
        self.path = path
        self.error = error

    @classmethod
    def load(cls, path: str | os.PathLike[str], error: type[Exception]) -> tuple[JsonFields, dict]:
        """The reader for the file at ``path`` and its top-level object (see :func:`load_json`)."""
        reader = cls(str(path), error)
        return reader, reader.obj(load_json(path, error), "(top level)")

    def fail(self, field_name: str, problem: str) -> Exception:
        """The error to raise for ``field_name`` (``where.key``, ``key[i]``) with ``problem``."""
        return self.error(f"{self.path}: {field_name}: {problem}")

    def get(self, obj: dict, key: str, where: str, required: bool = True) -> Any:
        """``obj[key]`` (None when absent and not ``required``); ``where`` names ``obj``."""
        name = f"{where}.{key}" if where else key
        if key not in obj:
            if required:
                raise self.fail(name, "missing required field")
            return None
        return obj[key]

    def obj(self, value: Any, name: str) -> dict:
        if not isinstance(value, dict):
            raise self.fail(name, f"expected an object, got {show_value(value)}")
        return value

    def array(self, value: Any, name: str) -> list:
        if not isinstance(value, list):
            raise self.fail(name, f"expected an array, got {show_value(value)}")
        return value

    def ident(self, value: Any, name: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.fail(name, f"expected a non-empty string id, got {show_value(value)}")
        return value

    def number(self, value: Any, name: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(name, f"expected a number, got {show_value(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(name, f"expected a finite number, got {show_value(value)}")
        if positive and x <= 0.0:
            raise self.fail(name, f"must be > 0, got {show_value(value)}")
        return x

    def vector(self, value: Any, name: str, length: int) -> np.ndarray:
        items = self.array(value, name)
        if len(items) != length:
            raise self.fail(name, f"expected {length} numbers, got {show_value(value)}")
        return np.array([self.number(v, f"{name}[{i}]") for i, v in enumerate(items)])

    def matrix(self, value: Any, name: str, size: int) -> np.ndarray:
        rows = self.array(value, name)
        if len(rows) != size:
            raise self.fail(name, f"expected a {size}x{size} matrix, got {show_value(value)}")
        return np.array([self.vector(r, f"{name}[{i}]", size) for i, r in enumerate(rows)])

    def unique_ids(self, values: list[str], name: str) -> None:
        seen: set[str] = set()
        for i, v in enumerate(values):
            if v in seen:
                raise self.fail(f"{name}[{i}]", f"duplicate id {show_value(v)}")
            seen.add(v)


def write_json_atomic(data: dict, path: str | os.PathLike[str]) -> None:
    """Write JSON so that ``path`` holds either the old or the complete new content."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual permissions
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(data, f, indent=1, allow_nan=False)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(target.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
