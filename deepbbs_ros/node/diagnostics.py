"""Counters, per-stage latency windows and rate-limited error reporting for the node (no ROS import)."""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np


class StageTimes:
    """Rolling windows (last ``window`` samples) of per-stage durations in milliseconds."""

    def __init__(self, window: int = 200) -> None:
        self.window = window
        self._lock = threading.Lock()
        self._samples: dict[str, deque[float]] = {}

    def add(self, timings_ms: dict[str, float]) -> None:
        with self._lock:
            for stage, ms in timings_ms.items():
                self._samples.setdefault(stage, deque(maxlen=self.window)).append(float(ms))

    def summary(self) -> dict[str, dict[str, float]]:
        """``{stage: {"median": ms, "p99": ms, "max": ms, "n": count}}`` over the window."""
        with self._lock:
            items = {k: np.asarray(v, dtype=np.float64) for k, v in self._samples.items() if v}
        return {
            k: {
                "median": float(np.median(v)),
                "p99": float(np.percentile(v, 99)),
                "max": float(v.max()),
                "n": float(v.size),
            }
            for k, v in items.items()
        }


class RateLimitedErrors:
    """Log one message per error kind at most every ``period`` seconds (wall clock), count them all.

    ``log(kind, message)`` calls ``sink(text)`` for the first occurrence of ``kind`` and again after
    ``period`` seconds, appending how many were suppressed in between. ``counts`` keeps the totals.
    """

    def __init__(self, sink: Callable[[str], None], period: float = 5.0) -> None:
        self._sink = sink
        self.period = period
        self._lock = threading.Lock()
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def log(self, kind: str, message: str) -> bool:
        """Count one error of ``kind``; returns True when it was actually logged."""
        now = time.monotonic()
        with self._lock:
            self.counts[kind] = self.counts.get(kind, 0) + 1
            last = self._last.get(kind)
            if last is not None and now - last < self.period:
                self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
                return False
            self._last[kind] = now
            suppressed = self._suppressed.pop(kind, 0)
        more = f" ({suppressed} more of this kind suppressed)" if suppressed else ""
        self._sink(f"[{kind}] {message}{more}")
        return True
