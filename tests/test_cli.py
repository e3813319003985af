"""The command line end to end: simulate -> solve -> score, and the demo (the README's main job)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from fgloc.cli import main


def test_simulate_solve_score(tmp_path: Path, capsys) -> None:
    s, r = tmp_path / "survey.json", tmp_path / "result.json"
    assert main(["simulate", "-o", str(s), "--nodes", "30", "--seed", "7", "--heights", "0.2", "0.1"]) == 0
    assert main(["solve", str(s), "-o", str(r)]) == 0
    out = capsys.readouterr().out
    assert "converged" in out and "iterations" in out and "marginals" in out
    assert main(["score", str(s), str(r), "--json"]) == 0
    score = json.loads(capsys.readouterr().out)
    assert score["n_nodes"] == 30 and score["median_m"] < 1.0


def test_simulate_rejects_bad_options(tmp_path: Path, capsys) -> None:
    assert main(["simulate", "-o", str(tmp_path / "s.json"), "--heights", "0", "0.1"]) == 2
    assert "heights" in capsys.readouterr().err





@pytest.mark.parametrize(
    "option, expected",
    [
        (["--nodes", "-5"], "--nodes: expected an integer >= 1, got -5"),
        (["--nodes", "0"], "--nodes: expected an integer >= 1, got 0"),
        (["--sigma-deg", "nan"], "--sigma-deg: expected a finite number > 0 and <= 90, got nan"),
        (["--sigma-deg", "0"], "--sigma-deg: expected a finite number > 0 and <= 90, got 0.0"),
        (["--heights", "inf", "0.1"], "--heights: expected a finite number > 0, got inf"),
        (["--roll-pitch-deg", "nan"], "--roll-pitch-deg: expected a finite number >= 0 and <= 90, got nan"),
        (["--roll-pitch-deg", "-1"], "--roll-pitch-deg: expected a finite number >= 0 and <= 90, got -1.0"),
        (["--seed", "-1"], "--seed: expected an integer >= 0, got -1"),
        (["--repeats", "0"], "--repeats: expected an integer >= 1, got 0"),
    ],
)
def test_simulate_bad_numbers_are_one_line_errors(tmp_path: Path, capsys, option, expected) -> None:
    out = tmp_path / "s.json"
    assert main(["simulate", "-o", str(out), *option]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err
    assert not out.exists()


def test_survey_live_every_must_be_positive(tmp_path: Path, capsys) -> None:
    rig = Path(__file__).resolve().parent.parent / "examples" / "rig-simulated.json"
    assert main(["survey", "--rig", str(rig), "-o", str(tmp_path / "o"), "--simulate", "--live-every", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--live-every must be >= 1, got 0" in err
    assert not (tmp_path / "o").exists()


def test_score_needs_truth(tmp_path: Path, capsys) -> None:
    s, r = tmp_path / "survey.json", tmp_path / "result.json"
    main(["simulate", "-o", str(s), "--nodes", "10"])
    main(["solve", str(s), "-o", str(r)])
    doc = json.loads(s.read_text())
    del doc["truth"]
    s.write_text(json.dumps(doc))
    assert main(["score", str(s), str(r)]) == 2
    assert "truth: missing" in capsys.readouterr().err


def test_demo_as_a_user_runs_it(tmp_path: Path) -> None:
    """The README's main job, as a subprocess: exit 0, a score table, the files written."""
    proc = subprocess.run([sys.executable, "-m", "fgloc", "demo", "-o", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    assert "| median |" in proc.stdout and "ANEES" in proc.stdout
    assert "paper's subset Newton" in proc.stdout and "Cramér–Rao bound" in proc.stdout
    for name in ("survey.json", "result.json", "result-subset-newton.json", "fgloc.rrd"):
        assert (tmp_path / "out" / name).is_file()
