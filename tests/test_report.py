"""``fgloc report --quick``: the reproduction report regenerates end to end."""

from __future__ import annotations

import sys

import pytest

from fgloc.cli import main


@pytest.mark.slow  # end to end: 8 solves, 3 CRLBs, matplotlib import and 4 PNGs (~5 s)
def test_report_quick_writes_table_and_figures(tmp_path) -> None:
    """The quick report writes report.md with Table 1 rows for every k (paper column
    honest: 'not available'), the CDF, the per-k subset scatter and the joint ellipse PNGs."""
    pytest.importorskip("matplotlib")
    out = tmp_path / "rep"
    assert main(["report", "-o", str(out), "--quick"]) == 0
    text = (out / "report.md").read_text()
    assert "## Table 1, side by side" in text
    for k in (5, 10):
        assert f"\n| {k} | " in text
        assert (out / f"fig4_subset_scatter_k{k}.png").stat().st_size > 10_000
    assert "not available" in text and "Farrell" in text
    for name in ("fig6_error_cdf.png", "fig7_joint_ellipses.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "(every height and k): **True**" in text


def test_report_without_matplotlib_is_one_clear_error(tmp_path, monkeypatch, capsys) -> None:
    """Without the report extra the command stops before computing, naming the fix."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["report", "-o", str(tmp_path / "rep"), "--quick"]) == 2
    assert "pip install fgloc[report]" in capsys.readouterr().err
    assert not (tmp_path / "rep").exists()
