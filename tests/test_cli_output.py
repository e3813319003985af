"""What the CLI shows besides results: -v/-q log levels on stderr, progress bars and their callbacks."""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path

import pytest

from fgloc.cli import main
from tests.test_rig_config import EXAMPLE


def rig_file(path: Path, n_nodes: int = 8) -> Path:
    """A small in-process simulated rig whose node n003 never answers (one LED warning)."""
    data = json.loads(EXAMPLE.read_text())
    data["node_ids"] = [f"n{j:03d}" for j in range(n_nodes)]
    data["simulation"] = {"seed": 1, "heights": [0.1, 0.12], "occlusion": 0.0, "dead_nodes": ["n003"]}
    data["retry"] = {"backoff_s": 0.0}
    path.write_text(json.dumps(data))
    return path


class TerminalStderr(io.StringIO):
    """A stderr that says it is a terminal, so tqdm draws its bar."""

    def isatty(self) -> bool:
        return True


def _log_everything(args) -> int:
    for level in (logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR):
        logging.getLogger("fgloc.survey.runner").log(level, f"{logging.getLevelName(level).lower()} line")
    return 0


@pytest.mark.parametrize(
    "flags,shown",
    [
        ([], ["warning", "error"]),
        (["-v"], ["info", "warning", "error"]),
        (["-vv"], ["debug", "info", "warning", "error"]),
        (["-q"], ["error"]),
    ],
)
def test_verbosity_sets_what_reaches_stderr(flags, shown, monkeypatch, capsys) -> None:
    import fgloc.cli.score

    monkeypatch.setattr(fgloc.cli.score, "run", _log_everything)
    logger = logging.getLogger("fgloc")
    handlers, level = list(logger.handlers), logger.level
    assert main([*flags, "score", "x.json", "y.json"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[1] for line in err] == shown
    assert all(line.startswith("fgloc: ") and line.endswith(" line") for line in err)
    if "-vv" in flags:
        assert err[0] == "fgloc: debug: fgloc.survey.runner: debug line"
    else:
        assert f"fgloc: {shown[0]}: {shown[0]} line" == err[0]
    # main() leaves the logger as it found it (no stacked handlers across calls)
    assert logger.handlers == handlers and logger.level == level


def test_errors_stay_one_line_with_any_verbosity(tmp_path, capsys) -> None:
    rig = rig_file(tmp_path / "rig.json")
    for flags in ([], ["-vv"], ["-q"]):
        assert main([*flags, "survey", "--rig", str(rig), "-o", str(tmp_path / "o"), "--live-every", "0"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("fgloc: error: --live-every must be >= 1") and err.count("\n") == 1


def test_survey_on_a_non_terminal_writes_no_bar_but_its_warnings(tmp_path, capsys) -> None:
    rig = rig_file(tmp_path / "rig.json")
    assert main(["survey", "--rig", str(rig), "-o", str(tmp_path / "out"), "--simulate", "--no-live"]) == 0
    captured = capsys.readouterr()
    err = captured.err.splitlines()
    assert len(err) == 1 and err[0].startswith("fgloc: warning: n003: LED failed: no acknowledgement after")
    assert "\r" not in captured.err and "node/s" not in captured.err and "it/s" not in captured.err
    assert "wrote " in captured.out


def test_survey_bar_on_a_terminal_shows_nodes_observations_failures(tmp_path, monkeypatch, capsys) -> None:
    rig = rig_file(tmp_path / "rig.json")
    fake = TerminalStderr()
    monkeypatch.setattr("sys.stderr", fake)
    assert main(["survey", "--rig", str(rig), "-o", str(tmp_path / "out"), "--simulate", "--no-live"]) == 0
    drawn = fake.getvalue()
    assert "survey" in drawn and "8/8" in drawn and "14 obs, 1 failed" in drawn  # n003's LED never lit
    fake2 = TerminalStderr()
    monkeypatch.setattr("sys.stderr", fake2)
    assert main(["-q", "survey", "--rig", str(rig), "-o", str(tmp_path / "q"), "--simulate", "--no-live"]) == 0
    assert fake2.getvalue() == ""  # -q: no bar, no warnings, even on a terminal


def test_report_callback_sees_every_run() -> None:
    from fgloc.evaluate.report import ReportConfig, run_experiment

    config = ReportConfig.quick()
    calls: list[tuple[int, int]] = []
    data = run_experiment(config, progress=lambda done, total: calls.append((done, total)))
    total = len(config.heights) * len(config.seeds) * len(config.subset_sizes)
    assert total == len(data.runs) == 2
    assert calls == [(k, total) for k in range(1, total + 1)]


def test_sweep_callback_sees_every_trial_and_a_bar_stays_off_a_non_terminal(capsys) -> None:
    from fgloc.evaluate.sweep import run_sweep
    from fgloc.sim.bench_scenes import BenchScene

    scenes = [BenchScene(30, 2, seed=s) for s in range(3)]
    calls: list[tuple[int, int]] = []
    outcomes = run_sweep(scenes, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)] and [o.scene for o in outcomes] == scenes
    again = run_sweep(scenes, progress=True)
    assert [o.rms_error for o in again] == [o.rms_error for o in outcomes]
    assert capsys.readouterr().err == ""


def test_bench_callback_counts_every_case_method_and_isam2_step(monkeypatch) -> None:
    import numpy as np

    import fgloc.evaluate.bench as bench

    ran: list[tuple[int, int, str]] = []

    def fake_case(n, c, method, repeats, seed=0):
        ran.append((n, c, method))
        res = bench.CaseResult(n, c, method, 2 * n, repeats, True, "", total_median_s=0.01)
        return res, np.zeros((n, 3))

    monkeypatch.setattr(bench, "run_case", fake_case)
    monkeypatch.setattr(bench, "run_incremental", lambda *a, **k: {"n_nodes": a[0], "n_cameras": a[1],
                        "active_nodes": k["active_nodes"], "batch_nodes": 1, **dict.fromkeys(
                            ("update_median_s", "update_mean_s", "update_p95_s", "update_max_s", "estimate_s",
                             "estimate_with_covariances_s", "bootstrap_s"), 0.001)})
    calls: list[tuple[int, int]] = []
    report = bench.run_benchmark([(40, 2), (200, 4)], ["fgloc", "scipy", "subset_newton"], True, 80, [(200, 4)],
                                 progress=lambda done, total: calls.append((done, total)))
    # 2 cases x 3 methods (scipy at 200 and subset_newton at 4 cameras skipped, still counted) + 2 iSAM2 windows
    assert calls == [(k, 8) for k in range(1, 9)]
    assert ran == [(40, 2, "fgloc"), (40, 2, "scipy"), (40, 2, "subset_newton"), (200, 4, "fgloc")]
    assert len(report["incremental"]) == 2


def test_cli_bench_on_a_non_terminal_writes_no_bar(monkeypatch, capsys) -> None:
    import fgloc.evaluate.bench as bench

    seen = []

    def fake_benchmark(cases, methods, quick, scipy_max, inc_cases, progress=None):
        for k in range(3):
            progress(k + 1, 3)
            seen.append(k)
        return {"markdown": "| scene (nodes x cams) |"}

    monkeypatch.setattr(bench, "run_benchmark", fake_benchmark)
    assert main(["bench", "--quick"]) == 0
    captured = capsys.readouterr()
    assert seen == [0, 1, 2] and "| scene (nodes x cams) |" in captured.out and captured.err == ""
