"""The docs name real code: every module path and dotted name in README.md and docs/ resolves.

Paths are repository paths (``fgloc/solve/joint.py``, ``drivers/twins/faults.py``);
dotted names are import paths, optionally followed by attributes
(``fgloc.solve.joint.solve_survey``). A rename that leaves a doc behind fails here.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
PATH = re.compile(r"(?<![\w/.-])((?:fgloc|drivers|factors|scripts|tests)/[\w/]*\.py)\b")
DOTTED = re.compile(r"(?<![\w/.-])(fgloc(?:\.[A-Za-z_]\w*)+)(?![\w/-])")


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_code_reference_in_the_docs_exists(doc: Path) -> None:
    text = doc.read_text()
    missing = [p for p in PATH.findall(text) if not (REPO / p).exists()]
    names = {d for d in DOTTED.findall(text) if not d.endswith((".rrd", ".json", ".md", ".png", ".py"))}
    missing += sorted(d for d in names if not _resolves(d))
    assert missing == [], f"{doc.name} names code that does not exist: {missing}"
