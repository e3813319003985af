"""The one retry policy (fgloc.core.retry): tries, which errors, waits, hooks, the last error re-raised."""

from __future__ import annotations

import pytest

from fgloc.core.retry import RetryPolicy, linear


def test_retries_until_success_and_reports_each_retry() -> None:
    seen: list[int] = []
    hooks: list[tuple[int, str]] = []

    def op(attempt: int) -> str:
        seen.append(attempt)
        if attempt < 2:
            raise TimeoutError(f"try {attempt}")
        return "ok"

    assert RetryPolicy(5, TimeoutError).call(op, lambda n, exc: hooks.append((n, str(exc)))) == "ok"
    assert seen == [0, 1, 2]
    assert hooks == [(1, "try 0"), (2, "try 1")]


def test_last_error_is_reraised_unchanged_after_all_attempts() -> None:
    calls: list[int] = []

    def op(attempt: int) -> None:
        calls.append(attempt)
        raise TimeoutError(f"try {attempt}")

    with pytest.raises(TimeoutError, match="try 2"):
        RetryPolicy(3, TimeoutError).call(op)
    assert calls == [0, 1, 2]


def test_other_errors_propagate_at_once() -> None:
    calls: list[int] = []

    def op(attempt: int) -> None:
        calls.append(attempt)
        raise ValueError("not retried")

    with pytest.raises(ValueError):
        RetryPolicy(5, (TimeoutError, ConnectionError)).call(op)
    with pytest.raises(ValueError):
        RetryPolicy(5, lambda exc: isinstance(exc, KeyError)).call(op)
    assert calls == [0, 0]


def test_waits_fixed_linear_and_by_error(monkeypatch: pytest.MonkeyPatch) -> None:
    slept: list[float] = []
    monkeypatch.setattr("time.sleep", slept.append)

    def failing(attempt: int) -> None:
        raise TimeoutError

    for wait, expected in ((0.25, [0.25, 0.25, 0.25]), (linear(0.1), [0.1, 0.2, 0.30000000000000004]),
                           (lambda n, exc: 1.0 if isinstance(exc, TimeoutError) else 0.0, [1.0, 1.0, 1.0])):
        slept.clear()
        with pytest.raises(TimeoutError):
            RetryPolicy(4, TimeoutError, wait).call(failing)
        assert slept == pytest.approx(expected)
