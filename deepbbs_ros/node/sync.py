"""Approximate-time pairing of message streams (message_filters' ``ApproximateTimeSynchronizer``).

``message_filters`` does not ship as a PyPI wheel, so the node carries its own synchroniser with the
same semantics as the rclpy one:

* one queue per input, holding at most ``queue_size`` messages keyed by header stamp (a message with
  a stamp already queued replaces it; when a queue overflows its oldest message is dropped);
* when a message arrives on input ``i``, every other input is searched for the queued message whose
  stamp is closest to it; if all of those lie within ``slop`` seconds of each other (``max - min <=
  slop``), the tuple is emitted (in input order) and its messages leave their queues.

Two additions make the output safe to feed a registration pipeline:

* tuples are emitted in stamp order: once a tuple is emitted, queued messages older than its stamp on
  the same input can never be paired any more and are dropped (counted in ``stats["stale"]``), and
  a late message older than the last emitted stamp of its input is refused (``stats["late"]``);
* a backwards jump of more than ``jump_back_s`` on one input (a bag restarted, simulated time rewound)
  clears every queue and the ordering memory (``stats["resets"]``; cleared messages in ``stats["cleared"]``)
  instead of refusing everything after it. Each input is compared with its own newest stamp: an input that
  lags the other (its older scans still arriving after the other's newer ones) is no time jump.

The class holds no ROS import: stamps are integers in nanoseconds and payloads are opaque. It is
thread-safe (one lock); the callback is invoked outside the lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from deepbbs_ros.errors import ConfigError


class ApproximateTimeSync:
    """Pair ``n_inputs`` streams by approximate header stamp.

    Args:
        n_inputs: number of input streams (>= 2).
        queue_size: messages kept per input (>= 1).
        slop: maximum spread of the stamps of one emitted tuple, seconds (>= 0).
        callback: called as ``callback(items)`` with one ``(stamp_ns, payload)`` per input, in input order.
        jump_back_s: a stamp this many seconds older than the newest one seen on its input resets the
            synchroniser.
    """

    def __init__(
        self,
        n_inputs: int,
        queue_size: int,
        slop: float,
        callback: Callable[[list[tuple[int, Any]]], None] | None = None,
        *,
        jump_back_s: float = 1.0,
    ) -> None:
        if n_inputs < 2:
            raise ConfigError(f"sync: n_inputs must be >= 2, got {n_inputs}")
        if queue_size < 1:
            raise ConfigError(f"sync: queue_size must be >= 1, got {queue_size}")
        if slop < 0:
            raise ConfigError(f"sync: slop must be >= 0, got {slop}")
        self.n_inputs = n_inputs
        self.queue_size = int(queue_size)
        self.slop_ns = int(round(slop * 1e9))
        self.jump_back_ns = int(round(jump_back_s * 1e9))
        self.callback = callback
        self._lock = threading.Lock()
        self._queues: list[dict[int, Any]] = [{} for _ in range(n_inputs)]
        self._last_emitted: list[int | None] = [None] * n_inputs
        self._newest_seen: list[int | None] = [None] * n_inputs  # per input: one lagging the other is no jump
        self.stats = {"received": 0, "emitted": 0, "overflow": 0, "stale": 0, "late": 0, "resets": 0, "cleared": 0}

    # -------------------------------------------------------------------------------------------
    def add(self, index: int, stamp_ns: int, payload: Any) -> list[tuple[int, Any]] | None:
        """Queue ``payload`` stamped ``stamp_ns`` on input ``index``; return the emitted tuple, if any.

        The tuple (one ``(stamp_ns, payload)`` per input) is also passed to ``callback``.
        """
        if not 0 <= index < self.n_inputs:
            raise IndexError(f"sync: input index {index} out of range 0..{self.n_inputs - 1}")
        stamp_ns = int(stamp_ns)
        with self._lock:
            self.stats["received"] += 1
            newest = self._newest_seen[index]
            if newest is not None and stamp_ns < newest - self.jump_back_ns:
                self._reset_locked()
                self.stats["resets"] += 1
                newest = None
            if newest is None or stamp_ns > newest:
                self._newest_seen[index] = stamp_ns
            last = self._last_emitted[index]
            if last is not None and stamp_ns <= last:
                self.stats["late"] += 1
                return None
            queue = self._queues[index]
            queue[stamp_ns] = payload
            while len(queue) > self.queue_size:
                del queue[min(queue)]
                self.stats["overflow"] += 1
            chosen = self._match_locked(index, stamp_ns)
            if chosen is None:
                return None
            items = [(s, self._queues[i].pop(s)) for i, s in enumerate(chosen)]
            for i, s in enumerate(chosen):
                self._last_emitted[i] = s
                q = self._queues[i]
                for old in [t for t in q if t < s]:
                    del q[old]
                    self.stats["stale"] += 1
            self.stats["emitted"] += 1
        if self.callback is not None:
            self.callback(items)
        return items

    def _match_locked(self, index: int, stamp_ns: int) -> list[int] | None:
        # closest stamp on every other input, each within slop of the new message
        chosen: list[int] = []
        for i, queue in enumerate(self._queues):
            if i == index:
                chosen.append(stamp_ns)
                continue
            best = None
            for s in queue:
                d = abs(s - stamp_ns)
                if d > self.slop_ns:
                    continue
                if best is None or d < abs(best - stamp_ns) or (d == abs(best - stamp_ns) and s < best):
                    best = s
            if best is None:
                return None
            chosen.append(best)
        if max(chosen) - min(chosen) > self.slop_ns:
            return None
        return chosen

    def reset(self) -> None:
        """Forget every queued message and the ordering memory (e.g. after a time jump)."""
        with self._lock:
            self._reset_locked()

    def _reset_locked(self) -> None:
        for q in self._queues:
            self.stats["cleared"] += len(q)
            q.clear()
        self._last_emitted = [None] * self.n_inputs
        self._newest_seen = [None] * self.n_inputs

    def queue_lengths(self) -> Sequence[int]:
        """Messages currently queued per input (never more than ``queue_size`` each)."""
        with self._lock:
            return [len(q) for q in self._queues]
