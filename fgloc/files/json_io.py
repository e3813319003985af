"""JSON files checked against the JSON Schemas shipped in ``fgloc/files/schemas/`` (docs/file-format.md).

:func:`load_json` reads and parses a file, keeping any non-finite number token
(``NaN``, ``Infinity``, ``1e999``, an integer too large for a float) as a
:class:`NonFinite` marker, which no schema accepts as a number. :func:`check`
validates a parsed document with ``jsonschema`` (Draft 2020-12) and raises the
first problem as one line ``FILE: FIELD: problem (got VALUE)`` in the error class
the caller names, so each format keeps its own exception type
(:class:`fgloc.core.errors.FileFormatError` and its subclasses, exit status 2).
What a schema cannot say (ids that must exist elsewhere in the file, matrix shapes
that depend on the mode, rotations) the readers check after it.

:func:`write_json_atomic` writes a document so that a reader sees either the old or
the complete new file.
"""

from __future__ import annotations

import functools
import glob
import json
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator, ValidationError  # type: ignore[import-untyped]
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT202012

#: Predicates that pre-accept the items of a big array or object, keyed by the
#: items' container path (``("observations",)``). Each must accept only items the
#: schema accepts; every item it refuses is checked by the schema, which gives the message.
Bulk = Mapping[tuple[str, ...], Callable[[Any], bool]]


class NonFinite:
    """A JSON number token that is not a finite double (``NaN``, ``-Infinity``, ``1e400``, ...)."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text


def _parse_float(text: str) -> float | NonFinite:
    value = float(text)
    return value if math.isfinite(value) else NonFinite(text)


def _parse_int(text: str) -> int | NonFinite:
    if len(text) < 300:
        return int(text)
    try:
        value = int(text)
        float(value)
    except (OverflowError, ValueError):  # beyond a double, or beyond Python's digit limit
        return NonFinite(text)
    return value


def parse_json(text: str | bytes) -> Any:
    """The document in ``text``; non-finite numbers become :class:`NonFinite`.

    Raises ``json.JSONDecodeError``, also for a document nested too deeply for the
    parser (thousands of ``[``), which no fgloc format needs.
    """
    try:
        return json.loads(text, parse_float=_parse_float, parse_int=_parse_int, parse_constant=NonFinite)
    except RecursionError:
        raise json.JSONDecodeError("nested too deeply", text if isinstance(text, str) else "", 0) from None


#: Largest coordinate magnitude a position may have (gauge units, baseline = 1):
#: no bearing survey places anything a billion baselines away, and beyond it
#: squares and float32 viewers overflow. Also ``survey.schema.json#/$defs/coordinate``.
POSITION_LIMIT = 1e9


def is_number(x: object) -> bool:
    """A finite JSON number as parsed here (bool and :class:`NonFinite` are other types)."""
    return type(x) is float or type(x) is int


def is_coordinate(x: object) -> bool:
    """A finite number within +-:data:`POSITION_LIMIT`, as ``survey.schema.json#/$defs/coordinate``."""
    return (type(x) is float or type(x) is int) and -POSITION_LIMIT <= x <= POSITION_LIMIT  # type: ignore[operator]


def is_vector3(v: object) -> bool:
    """Three coordinates: accepts only what ``survey.schema.json#/$defs/vector3`` accepts."""
    return type(v) is list and len(v) == 3 and all(map(is_coordinate, v))


def find_nonfinite(value: Any, path: tuple[str | int, ...] = ()) -> tuple[str | int, ...] | None:
    """The path of the first :class:`NonFinite` inside ``value`` (free-form fields), or None."""
    stack: list[tuple[Any, tuple[str | int, ...]]] = [(value, path)]
    while stack:
        v, where = stack.pop()
        if isinstance(v, NonFinite):
            return where
        if isinstance(v, dict):
            stack.extend((item, (*where, str(k))) for k, item in v.items())
        elif isinstance(v, list):
            stack.extend((item, (*where, i)) for i, item in enumerate(v))
    return None


def show_value(value: Any) -> str:
    """``value`` as the JSON a user wrote (non-finite numbers as written), cut to 60 characters."""
    try:
        text = value.text if isinstance(value, NonFinite) else json.dumps(value, default=repr)
    except (RecursionError, ValueError):
        text = f"<{type(value).__name__} nested too deeply>"
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
        return parse_json(text)
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON: {exc}") from None


@functools.cache
def schema(name: str) -> dict[str, Any]:
    """The shipped schema ``fgloc/files/schemas/NAME.schema.json`` (checked against Draft 2020-12)."""
    text = resources.files("fgloc.files").joinpath("schemas", f"{name}.schema.json").read_text(encoding="utf-8")
    doc: dict[str, Any] = json.loads(text)
    Draft202012Validator.check_schema(doc)
    return doc


SCHEMAS = ("survey", "result", "camera", "rig", "journal", "sites")


@functools.cache
def _registry() -> Registry:
    """Every shipped schema under its ``$id``, so that they can ``$ref`` each other."""
    return Registry().with_resources(
        (schema(n)["$id"], Resource.from_contents(schema(n), default_specification=DRAFT202012)) for n in SCHEMAS
    )


@functools.cache
def _validator(name: str, definition: str | None) -> Draft202012Validator:
    root = schema(name)
    if definition is not None:  # one of the schema's $defs
        root = {"$schema": root["$schema"], "$ref": f"{root['$id']}#/$defs/{definition}"}
    return Draft202012Validator(root, registry=_registry())


def field_name(path: Iterable[str | int], root: str = "") -> str:
    """``cameras.c1.rotation``, ``observations[3].pan``; ``root`` (or ``(top level)``) for the document itself."""
    name = root
    for part in path:
        name += f"[{part}]" if isinstance(part, int) else (f".{part}" if name else str(part))
    return name or "(top level)"


_TYPE_WORDS = {"object": "an object", "array": "an array", "string": "a string", "number": "a number",
               "integer": "an integer", "boolean": "true or false", "null": "null"}


def describe(err: ValidationError, root: str = "", path: Iterable[str | int] | None = None) -> tuple[str, str]:
    """(field, problem) for one schema violation, the way every fgloc file error reads.

    A subschema may carry ``"x-expected"``, the phrase that follows "expected" when its
    type, choices, length, size or range is wrong (``"a non-empty list of node ids"``).
    ``path`` overrides the error's own path to the instance.
    """
    sub = err.schema if isinstance(err.schema, dict) else {}
    kw, value = err.validator, err.instance
    path = list(err.absolute_path if path is None else path)
    got = show_value(value)
    if kw == "required":
        missing = next(k for k in err.validator_value if k not in value)
        return field_name([*path, missing], root), "missing required field"
    name = field_name(path, root)
    expected = sub.get("x-expected")
    if kw == "type" and isinstance(value, NonFinite):
        return name, f"expected a finite number, got {got}"
    if kw == "enum":
        return name, f"expected {expected or 'one of ' + ', '.join(map(str, err.validator_value))}, got {value!r}"
    if expected is not None and kw in ("type", "minLength", "minItems", "maxItems", "const", "pattern",
                                       "minimum", "maximum", "exclusiveMinimum"):
        return name, f"expected {expected}, got {got}"
    if kw == "type":
        types = [err.validator_value] if isinstance(err.validator_value, str) else err.validator_value
        return name, f"expected {' or '.join(_TYPE_WORDS[t] for t in types)}, got {got}"
    if kw in ("minimum", "maximum"):
        return name, f"must lie in [{sub.get('minimum', -math.inf):g}, {sub.get('maximum', math.inf):g}], got {got}"
    if kw == "exclusiveMinimum":
        return name, f"must be > {err.validator_value:g}, got {got}"
    if kw == "minLength":
        return name, f"expected a non-empty string, got {got}"
    if kw in ("minItems", "maxItems"):
        lo, hi = sub.get("minItems", 0), sub.get("maxItems")
        size = f"{lo}" if lo == hi else f"at least {lo}" if hi is None else f"{lo} to {hi}"
        return name, f"expected {size} items, got {got}"
    if kw == "const":
        return name, f"expected {show_value(err.validator_value)}, got {got}"
    return name, err.message.splitlines()[0]


def _skeleton(doc: Any, bulk: Bulk) -> tuple[Any, dict[tuple[str, ...], list[int]]]:
    """``doc`` with each bulk container cut down to the items its predicate refuses.

    Returns the cut document and, for cut arrays, the original index of each kept item.
    """
    indexes: dict[tuple[str, ...], list[int]] = {}
    for where, accept in bulk.items():
        parent = doc
        for key in where[:-1]:
            parent = parent.get(key) if isinstance(parent, dict) else None
        items = parent.get(where[-1]) if isinstance(parent, dict) else None
        if isinstance(items, list):
            kept_index = [i for i, item in enumerate(items) if not accept(item)]
            cut: Any = [items[i] for i in kept_index]
            indexes[where] = kept_index
        elif isinstance(items, dict):
            cut = {k: v for k, v in items.items() if not accept(v)}
        else:
            continue  # not a container: the schema reports it
        doc = _replace(doc, where, cut)
    return doc, indexes


def _replace(doc: dict, where: tuple[str, ...], value: Any) -> dict:
    """A copy of ``doc`` with ``doc[where[0]]...[where[-1]]`` set to ``value`` (only the path is copied)."""
    head, *rest = where
    return {**doc, head: _replace(doc[head], tuple(rest), value) if rest else value}


def check(doc: Any, schema_name: str, where: str, error: type[Exception], *, definition: str | None = None,
          bulk: Bulk | None = None, root: str = "") -> None:
    """Raise ``error("WHERE: FIELD: problem")`` for the first way ``doc`` breaks the schema.

    ``definition`` picks one of the schema's ``$defs`` instead of the whole schema;
    ``root`` prefixes field names (a journal names ``observation.pan``). ``bulk``
    speeds up big containers (see :data:`Bulk`).
    """
    indexes: dict[tuple[str, ...], list[int]] = {}
    if bulk:
        doc, indexes = _skeleton(doc, bulk)
    err = next(iter(_validator(schema_name, definition).iter_errors(doc)), None)
    if err is None:
        return
    path = list(err.absolute_path)
    for cut, original in indexes.items():  # back to the index the item has in the file
        n = len(cut)
        if len(path) > n and tuple(path[:n]) == cut:
            path[n] = original[path[n]]
    field, problem = describe(err, root, path)
    raise error(f"{where}: {field}: {problem}")


def _temp_is_stale(tmp: Path, prefix: str) -> bool:
    """A ``PREFIX PID.XXXX.tmp`` file whose writer (PID, on this host) is gone; an old-style name
    without a pid when it is over an hour old."""
    pid_text = tmp.name[len(prefix):].split(".", 1)[0]
    try:
        if pid_text.isdigit():
            try:
                os.kill(int(pid_text), 0)
            except ProcessLookupError:
                return True
            except (PermissionError, OverflowError):
                return False
            return False
        return time.time() - tmp.stat().st_mtime > 3600
    except OSError:
        return False


def remove_stale_temps(directory: str | os.PathLike[str], name: str = "*") -> list[Path]:
    """Remove the temporary files of interrupted :func:`write_json_atomic` calls in ``directory``
    (of file ``name``, or of any file): those whose writing process is gone. Returns them."""
    removed = []
    for tmp in Path(directory).glob(f".{name if name == '*' else glob.escape(name)}.*.tmp"):
        target = tmp.name[1:].rsplit(".", 3)[0] if name == "*" else name
        if _temp_is_stale(tmp, f".{target}."):
            try:
                tmp.unlink()
                removed.append(tmp)
            except OSError:
                pass
    return removed


def write_json_atomic(data: dict, path: str | os.PathLike[str]) -> None:
    """Write JSON so that ``path`` holds either the old or the complete new content.

    The content goes to ``.NAME.PID.XXXX.tmp`` beside ``path`` first; temporary files left
    by killed writers of ``path`` are removed (:func:`remove_stale_temps`)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(target.parent, target.name)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.{os.getpid()}.", suffix=".tmp", dir=target.parent)
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
