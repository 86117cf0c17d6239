"""Small measurement helpers: a bounded sample window with percentiles, a rate-limited log."""

from __future__ import annotations

import logging
import os
import time
from collections import deque

import numpy as np

__all__ = ["RateLimitedLog", "Window", "median_us", "percentiles", "rss_mb"]

_PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20 if hasattr(os, "sysconf") else 0.0


def rss_mb() -> float:
    """Resident memory of this process in MiB (Linux /proc; 0.0 elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE_MB
    except (OSError, ValueError, IndexError):
        return 0.0


def median_us(fn, repeats: int = 200, warmup: bool = True) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls, in microseconds (benchmarks);
    ``warmup``: one call first, not timed (caches, lazy imports)."""
    if warmup:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        fn()
        times.append(time.perf_counter_ns() - t0)
    return float(np.median(times)) / 1e3


def percentiles(values, qs=(50, 99)) -> list[float]:
    """Percentiles of ``values`` (NaN for each when empty)."""
    if len(values) == 0:
        return [float("nan")] * len(qs)
    return [float(v) for v in np.percentile(np.asarray(values, dtype=np.float64), qs)]


class Window:
    """The last ``size`` samples of a quantity (bounded memory whatever the run length)."""

    def __init__(self, size: int = 2048) -> None:
        self._values: deque[float] = deque(maxlen=size)

    def add(self, value: float) -> None:
        self._values.append(value)

    def __len__(self) -> int:
        return len(self._values)

    def percentiles(self, qs=(50, 99)) -> list[float]:
        return percentiles(self._values, qs)


class RateLimitedLog:
    """Log a message at most once per ``interval_s`` per key, saying how many were suppressed.

    Hot paths (a flood of malformed payloads) must not flood the log.
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 5.0) -> None:
        self._logger = logger
        self._interval_ns = int(interval_s * 1e9)
        self._last: dict[str, int] = {}
        self._suppressed: dict[str, int] = {}

    def log(self, level: int, key: str, msg: str, *args, exc_info=None) -> bool:
        now = time.monotonic_ns()
        last = self._last.get(key)
        if last is not None and now - last < self._interval_ns:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        self._last[key] = now
        n = self._suppressed.pop(key, 0)
        if n:
            msg = f"{msg} (+{n} similar suppressed)"
        self._logger.log(level, msg, *args, exc_info=exc_info)
        return True
