"""The scans that arrive while a global search runs, kept to carry its pose forward (no ROS import).

A search of the whole map takes seconds; at 10 Hz tens of scans arrive meanwhile and the registration worker keeps
only the newest. The pose the search finds is that of an old scan, and the tracker's prediction from it would be
stale by the time the next scan is registered (a car at 10 m/s is 20 m further after 2 s). :class:`ScanBridge` keeps
the newest ``localization.bridge_scans`` scans that arrived (decoded and prepared on their input thread); when the
search places scan k, :meth:`ScanBridge.take` hands back the scans stamped after k, the newest among them (the node
takes it too: the worker's slot, which holds it as well, may lose it to the next arrival before the bridge ends),
those of the search's time thinned to at most :data:`BRIDGE_MAX`: the first two (the tracker's velocity) and then
evenly spread; those received after the pose was found are all kept. The node
tracks them in stamp order (GICP from the constant-velocity prediction on the map crop, the tracker's usual step),
round after round while more arrive, so the pose reaches the newest scan with a fresh prediction, for as long as it
gains on the stream (:func:`gains`). Scans stamped at or before the last answered one are forgotten
(:meth:`ScanBridge.forget_until`).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

#: at most this many of the scans that arrived during a search are registered to carry its pose to the newest one, in
#: rounds (the scans that arrive while it bridges are the next round's) until none is left, while it gains (gains());
#: also the fewest followed scans over which it judges that
BRIDGE_MAX = 12


def gains(window: int, arrived: int) -> bool:
    """Whether the bridge still gains on the stream when ``arrived`` scans arrived while it followed its last
    ``window`` scans (all of them while it has followed fewer): fewer than ``window``, so tracking a scan costs less
    than the period between arrivals and the backlog shrinks. The node's window is the first round's size, at least
    ``BRIDGE_MAX`` (the rate judged over a dozen scans, not over the phase of one or two arrivals). Once as many
    arrived, the backlog cannot shrink (the machine is too slow for the stream): the bridge ends there and the newest
    scan is tracked from the last pose followed. The bridge never runs away: cut within ``window`` scan periods while it
    falls behind, and gaining, its backlog shrinks by a scan or more every ``window`` scans it follows."""
    return arrived < window


class ArrivalGate:
    """The localization input's gate (``LatestSlotWorker``'s ``gate``): open while the registration worker has room,
    as every input's, and also while ``keeps()`` (a search or a bridge runs: every scan is decoded, prepared, kept)."""

    def __init__(self, room: threading.Event, keeps: Callable[[], bool]) -> None:
        self._room, self._keeps = room, keeps

    def wait(self, timeout: float | None = None) -> bool:
        return self._keeps() or self._room.wait(timeout)


class ScanBridge:
    """A bounded, thread-safe buffer of scans (anything with a ``stamp_ns``) in arrival order (module docstring).

    Args:
        size: scans kept (the newest); 0 keeps none (:meth:`take` returns nothing).
    """

    def __init__(self, size: int) -> None:
        self.size = max(int(size), 0)
        self._lock = threading.Lock()
        self._scans: deque[Any] = deque(maxlen=max(self.size, 1))
        self.dropped = 0  # scans kept and then forgotten or passed over unanswered (full, thinned, older)
        self.arrived = 0  # scans added so far (the stream's pace, measured while the bridge follows: gains())

    def __len__(self) -> int:
        with self._lock:
            return len(self._scans) if self.size else 0

    def add(self, scan: Any) -> None:
        """Keep ``scan`` (the oldest kept one goes when full). Called on the input thread."""
        if self.size:
            with self._lock:
                self.arrived += 1
                self._keep(scan)

    def restore(self, scans: list[Any]) -> None:
        """Keep again scans :meth:`take` handed out and the bridge did not follow (it ended before them): counted as
        dropped once a later scan is answered (:meth:`forget_until`), not lost uncounted."""
        if self.size:
            with self._lock:
                for scan in scans:
                    self._keep(scan)

    def _keep(self, scan: Any) -> None:
        """Append ``scan`` (lock held); the oldest kept one goes when full, counted as dropped."""
        self.dropped += len(self._scans) == self._scans.maxlen
        self._scans.append(scan)

    def clear(self) -> None:
        with self._lock:
            self._scans.clear()

    def forget_until(self, stamp_ns: int) -> None:
        """Forget the scans stamped at or before ``stamp_ns`` (that one answered; the older ones dropped)."""
        with self._lock:
            kept = [s for s in self._scans if s.stamp_ns > stamp_ns]
            self.dropped += sum(s.stamp_ns < stamp_ns for s in self._scans)
            self._scans.clear()
            self._scans.extend(kept)

    def take(self, after_ns: int, most: int = BRIDGE_MAX, leave_newest: bool = True,
             keep_since: float | None = None) -> list[Any]:
        """The scans to register to carry a pose at ``after_ns`` forward: those stamped after it in stamp order, less
        the newest (the worker's next job, tracked as usual) unless ``leave_newest`` is false, at most ``most`` of them
        (the first two, then evenly spread, the last always); every scan up to the last one taken is forgotten.
        ``keep_since``: scans received (``t_recv``, ``time.perf_counter()``) at or after it, those that arrived once
        the pose was found, are all taken; only the ones before them are thinned."""
        with self._lock:
            later = sorted((s for s in self._scans if s.stamp_ns > after_ns), key=lambda s: s.stamp_ns)
            later = later[:-1] if leave_newest else later
            if not later:
                return []
            if len(later) > most:
                new = 0 if keep_since is None else sum(getattr(s, "t_recv", -np.inf) >= keep_since for s in later)
                old = len(later) - new  # the scans of the search's time, thinned (at least two: the velocity)
                room = max(most - new, 2)
                pick = {0, *np.linspace(1, max(old - 1, 0), max(room - 1, 1)).round().astype(int).tolist()}
                pick = {i for i in pick if i < old} | set(range(old, len(later)))
                later = [later[i] for i in sorted(pick)]  # 0, 1, ..., the last: at most `most` besides the new ones
            last = later[-1].stamp_ns
            kept = [s for s in self._scans if s.stamp_ns > last]
            self.dropped += len(self._scans) - len(kept) - len(later) - sum(s.stamp_ns == after_ns for s in self._scans)
            self._scans.clear()
            self._scans.extend(kept)
            return later
