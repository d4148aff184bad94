"""Scans the node drops unanswered, said once in the log and counted (no ROS import).

The first dropped scan is one log line naming why, the scan and the counter; later drops are only counted and
summarised in one line at most every ``node.error_log_period`` s (when one comes after that long), so that a node
that cannot keep up says so without a line per scan. :meth:`DropLog.diagnostics` gives the counters per reason for
/diagnostics.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class DropLog:
    """Count every dropped scan by why, log the first one and a summary at most every ``period`` s.

    Args:
        sink: called with each line to log (the node's logger, info).
        period: seconds between two summary lines (``node.error_log_period``).
    """

    def __init__(self, sink: Callable[[str], None], period: float = 5.0) -> None:
        self._sink = sink
        self.period = float(period)
        self._lock = threading.Lock()
        self.counts: dict[str, int] = {}
        self._since = 0  # drops since the last line
        self._last: float | None = None  # time.monotonic() of the last line

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self.counts.values())

    def dropped(self, why: str, stamp_ns: int, topic: str, n: int = 1) -> None:
        """``n`` scans (the last stamped ``stamp_ns``, on ``topic``) dropped unanswered, ``why`` in words (the
        reason's counter key)."""
        if n <= 0:
            return
        now = time.monotonic()
        with self._lock:
            self.counts[why] = self.counts.get(why, 0) + n
            total = sum(self.counts.values())
            self._since += n
            first = self._last is None
            if not first and now - self._last < self.period:
                return
            since, self._since, self._last = self._since, 0, now
        if first:
            what = f"scan at {stamp_ns} ns" if n == 1 else f"{n} scans up to the one at {stamp_ns} ns"
            line = (f"{topic}: {what} dropped unanswered {why} ({total} dropped so far; later drops are "
                    f"counted on /diagnostics and summarised here at most every {self.period:g} s)")
        else:
            line = f"{topic}: {since} more scan(s) dropped unanswered ({total} in all), the last {why}"
        self._sink(line)

    def diagnostics(self) -> dict[str, int]:
        """``scans dropped unanswered`` (total) and one entry per reason."""
        with self._lock:
            out = {"scans dropped unanswered": sum(self.counts.values())}
            out.update({f"scans dropped {why.split(':')[0]}": n for why, n in sorted(self.counts.items())})
        return out
