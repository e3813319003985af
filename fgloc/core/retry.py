"""One retry policy for every flaky operation: how many tries, which errors, how long to wait.

Drivers (VISCA retransmits and reconnects, HTTP retries, TinyOS ACK and LED
attempts, VISCA-over-IP RESET) and the survey runner (head retries, reconnects,
LED attempts) all retry through :class:`RetryPolicy`, built on ``tenacity``.

An operation signals "try again" by raising one of the policy's retryable
errors; anything else propagates at once. After the last try the last error is
raised unchanged (its message is what a user sees). Waits are in seconds.

Example::

    policy = RetryPolicy(attempts=4, retry_on=TimeoutError, wait=linear(0.05))
    data = policy.call(lambda attempt: link.ask(resend=attempt > 0))
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import tenacity

T = TypeVar("T")

#: ``(failures so far, the last error) -> seconds`` to wait before the next try.
WaitFn = Callable[[int, BaseException], float]
RetryOn = type[BaseException] | tuple[type[BaseException], ...] | Callable[[BaseException], bool]


def linear(step_s: float) -> WaitFn:
    """Back-off growing by ``step_s`` per failure: ``step_s``, ``2 step_s``, ... seconds."""
    return lambda failures, _error: step_s * failures


@dataclass(frozen=True)
class RetryPolicy:
    """Try an operation up to ``attempts`` times (>= 1) while it raises an error matching ``retry_on``.

    ``retry_on`` is an exception type, a tuple of types, or a predicate on the error.
    ``wait`` is a fixed number of seconds, or a :data:`WaitFn`, slept before each retry.
    """

    attempts: int
    retry_on: RetryOn = Exception
    wait: float | WaitFn = 0.0

    def retries(self, error: BaseException) -> bool:
        """True when ``error`` is one this policy retries."""
        r = self.retry_on
        if isinstance(r, (type, tuple)):
            return isinstance(error, r)
        return bool(r(error))

    def call(self, op: Callable[[int], T],
             before_retry: Callable[[int, BaseException], None] | None = None) -> T:
        """``op(attempt)`` with attempt = 0, 1, ... until it returns; re-raises the last error.

        ``before_retry(failures, error)`` runs after each failed try that will be
        retried (before the wait): count it, log it, reopen a link.
        """
        counter = itertools.count()

        def wait(state: tenacity.RetryCallState) -> float:
            if not callable(self.wait):
                return self.wait
            return self.wait(state.attempt_number, _error(state))

        def before_sleep(state: tenacity.RetryCallState) -> None:
            if before_retry is not None:
                before_retry(state.attempt_number, _error(state))

        retrying = tenacity.Retrying(
            stop=tenacity.stop_after_attempt(max(1, self.attempts)),
            retry=tenacity.retry_if_exception(self.retries),
            wait=wait,
            before_sleep=before_sleep,
            reraise=True,
        )
        return retrying(lambda: op(next(counter)))


def _error(state: tenacity.RetryCallState) -> BaseException:
    assert state.outcome is not None
    exc = state.outcome.exception()
    assert exc is not None
    return exc
