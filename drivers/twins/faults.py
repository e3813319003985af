"""Fault injection shared by every twin: seeded rates plus an optional forced script.

A twin asks the injector, per request and per reply, whether to misbehave:

* ``drop``      the reply is never sent (a lost byte stream / UDP datagram);
* ``garble``    one byte of the reply is replaced by a random different byte;
* ``byte_error_rate``  independently of the above, every outgoing byte is replaced by a
  random different byte with this probability (line noise: "1 % garbled bytes");
* ``error``     the request is answered with an error reply instead of executing;
* ``slow``      a completion (VISCA) or an ACK (TinyOS) is delayed by ``slow_seconds``;
* ``disconnect`` after ``disconnect_after`` requests the link goes away (pty closed,
  socket closed, UDP silence), coming back after ``reconnect_after`` seconds
  (never, when None).

Randomness comes from ``random.Random(seed)``, so a run is reproducible. ``script``
forces outcomes in order, one entry per reply decision (``"drop"``, ``"garble"``,
``"slow"``, ``"ok"``) before the rates apply; ``error_script`` does the same for
per-request error decisions (``"error"`` or ``"ok"``).
"""

from __future__ import annotations

import random
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class FaultConfig:
    """Fault rates (probabilities per reply or per request) and the disconnect schedule."""

    drop_rate: float = 0.0
    garble_rate: float = 0.0
    error_rate: float = 0.0
    slow_rate: float = 0.0
    slow_seconds: float = 0.5
    byte_error_rate: float = 0.0
    error_codes: tuple[int, ...] = (0x41,)
    disconnect_after: int | None = None
    reconnect_after: float | None = None
    seed: int = 0
    script: list[str] = field(default_factory=list)
    error_script: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ("drop_rate", "garble_rate", "error_rate", "slow_rate", "byte_error_rate"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {v}")


class FaultInjector:
    """Thread-safe decisions from a :class:`FaultConfig`; ``counts`` records what was injected."""

    def __init__(self, config: FaultConfig | None = None) -> None:
        self.config = config or FaultConfig()
        self._rng = random.Random(self.config.seed)
        self._script = list(self.config.script)
        self._error_script = list(self.config.error_script)
        self._lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.requests = 0
        self._disconnected_once = False

    def force(self, *fates: str) -> None:
        """Force the next reply decisions (``"ok"``, ``"drop"``, ``"garble"``, ``"slow"``)."""
        with self._lock:
            self._script.extend(fates)

    def force_error(self, count: int = 1) -> None:
        """Answer the next ``count`` requests with an error reply."""
        with self._lock:
            self._error_script.extend(["error"] * count)

    def _roll(self, rate: float) -> bool:
        return rate > 0.0 and self._rng.random() < rate

    def reply_fate(self, can_be_slow: bool = False) -> str:
        """``"ok"``, ``"drop"``, ``"garble"`` or ``"slow"`` for the next reply."""
        with self._lock:
            if self._script:
                fate = self._script.pop(0)
            else:
                c = self.config
                if self._roll(c.drop_rate):
                    fate = "drop"
                elif self._roll(c.garble_rate):
                    fate = "garble"
                elif can_be_slow and self._roll(c.slow_rate):
                    fate = "slow"
                else:
                    fate = "ok"
            if fate == "slow" and not can_be_slow:
                fate = "ok"
            if fate != "ok":
                self.counts[fate] += 1
            return fate

    def garble(self, data: bytes) -> bytes:
        """``data`` with one byte replaced by a different random byte."""
        with self._lock:
            if not data:
                return data
            i = self._rng.randrange(len(data))
            new = self._rng.randrange(255)
            if new >= data[i]:
                new += 1
            return data[:i] + bytes([new]) + data[i + 1:]

    def line_noise(self, data: bytes) -> bytes:
        """``data`` with each byte replaced (by a different random byte) with ``byte_error_rate``."""
        rate = self.config.byte_error_rate
        if rate <= 0.0 or not data:
            return data
        with self._lock:
            out = bytearray(data)
            hit = 0
            for i, b in enumerate(out):
                if self._rng.random() < rate:
                    new = self._rng.randrange(255)
                    out[i] = new + 1 if new >= b else new
                    hit += 1
            if hit:
                self.counts["byte_error"] += hit
            return bytes(out)

    def faulted_reply(self, data: bytes, can_be_slow: bool = False,
                      garble: Callable[[bytes], bytes] | None = None) -> tuple[float, bytes] | None:
        """One outgoing reply after its fate: None if dropped, else (extra delay s, bytes to send).

        A garbled reply goes through ``garble`` (default :meth:`garble`; a twin passes its own
        to keep framing bytes intact), a slow one is ``slow_seconds`` late, and every sent
        reply gets :meth:`line_noise`."""
        fate = self.reply_fate(can_be_slow=can_be_slow)
        if fate == "drop":
            return None
        if fate == "garble":
            data = (garble or self.garble)(data)
        delay = self.config.slow_seconds if fate == "slow" else 0.0
        return delay, self.line_noise(data)

    def request_error(self) -> int | None:
        """An error code to answer this request with, or None to execute it."""
        with self._lock:
            if self._error_script:
                fate = self._error_script.pop(0)
            else:
                fate = "error" if self._roll(self.config.error_rate) else "ok"
            if fate != "error":
                return None
            self.counts["error"] += 1
            return self._rng.choice(self.config.error_codes)

    def count_request(self) -> bool:
        """Count one request; True exactly once, when the link should disconnect now."""
        with self._lock:
            self.requests += 1
            after = self.config.disconnect_after
            if after is not None and not self._disconnected_once and self.requests > after:
                self._disconnected_once = True
                self.counts["disconnect"] += 1
                return True
            return False
