"""The public API is enough to extend the graph: the example script runs and its factors act.

Truth used: a prior on a node can only shrink that node's marginal covariance, and
an exact range measurement shrinks the two ranged nodes' covariance too.
"""

import runpy
from pathlib import Path

import fgloc

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "custom_factors_example.py"


def test_custom_factors_example_tightens_the_anchored_nodes(capsys) -> None:
    changes = runpy.run_path(str(SCRIPT))["main"]()
    before, after = changes["n000"]
    assert after < 0.5 * before  # the 1 mm anchor dominates
    for n in ("n001", "n002"):
        assert changes[n][1] < changes[n][0]
    assert "range n001-n002" in capsys.readouterr().out


def test_public_names_exist() -> None:
    for name in fgloc.__all__:
        assert hasattr(fgloc, name), name
