"""The bridge of ``node.target_mode: localization`` (no ROS import).

A search slower than the scan period does not lose what it finds: the node hands every scan to
:meth:`~SearchBridge.arrived` (:class:`~deepbbs_ros.node.bridge.ScanBridge`, ``localization.bridge_scans``), and once
a search places a scan, :meth:`~SearchBridge.bridge` tracks the scans that arrived meanwhile in stamp order, so that
the worker's next scan is tracked from a fresh prediction instead of a pose seconds old. A scan the bridge already
answered is skipped by ``NodeLocalization.step``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

from deepbbs_ros.node.bridge import BRIDGE_MAX, ScanBridge, gains
from deepbbs_ros.node.inputs import BadInput, Cloud

__all__ = ["BRIDGE_DROP", "SearchBridge"]

#: why the scans kept during a search and not followed by the bridge were dropped (node/drops.py's counter key first)
BRIDGE_DROP = (f"after a search: passed over by the bridge (it follows at most {BRIDGE_MAX} of the scans that arrived "
               "meanwhile, then round after round while it gains on the stream, and a scan older than one answered)")


class SearchBridge:
    """Part of :class:`~deepbbs_ros.node.localization.NodeLocalization`: the scans kept during a search, followed
    once it places its scan."""

    # what it reads of the NodeLocalization it is part of
    tracker: Any
    searching: bool
    step: Callable[[Cloud], Any]  # NodeLocalization.step: a LocalizedScan, or None

    def _init_bridge(self, bridge_scans: int) -> None:
        """The bridge's state (``localization.bridge_scans``: how many arrivals it keeps)."""
        self._bridge = ScanBridge(bridge_scans)
        self.bridged = 0  # scans answered by the bridge after a search (their poses published)
        self._found_t: float | None = None  # perf_counter() when the last search placed its scan (bridge.take)
        #: (why, the last one's stamp, how many): the scans the bridge kept and never answered, said where the node
        #: says every drop (node/drops.py; set by the node)
        self.drop_sink: Callable[[str, int, int], None] | None = None
        self._drops_said = 0  # of self._bridge.dropped
        self.last_arrival: int | None = None  # the stamp of the last scan handed to arrived() (the worker's slot)
        self.last_bridge = ""  # the last bridge's log line (bridge())
        self._bridging = False  # bridge() runs (the scans arriving meanwhile are kept too)
        # a search placed its scan and bridge() has not started yet: the scans arriving in between (while the found
        # pose is published) are kept too, else the worker's slot keeps only the newest of them
        self._bridge_pending = False
        self._followed = 0  # scans the running bridge has followed
        self._behind = ""  # why the last bridge ended before it caught up ("" when it did)

    @property
    def keeps_arrivals(self) -> bool:
        """Whether the scans arriving now are kept for :meth:`bridge` (a search or a bridge runs,
        ``localization.bridge_scans``): their fate is counted there (followed, or :attr:`dropped`)."""
        return self._bridge.size > 0 and (self.searching or self._bridging or self._bridge_pending)

    @property
    def opens_input(self) -> bool:
        """Whether the input decodes and prepares every scan now, not only while the worker has room: the bridge
        keeps them (a search or a bridge runs)."""
        return self.keeps_arrivals

    @property
    def dropped(self) -> int:
        """Scans kept during a search or a bridge and never answered (thinned, passed over, the buffer full)."""
        return self._bridge.dropped

    def arrived(self, cloud: Cloud) -> None:
        """A scan on its way to the worker (input thread): kept for :meth:`bridge` while :attr:`keeps_arrivals`."""
        self.last_arrival = cloud.stamp_ns
        if self.keeps_arrivals:
            self._bridge.add(cloud)

    def answered(self, stamp_ns: int | None) -> bool:
        """Whether the scan stamped ``stamp_ns`` has a pose already (the bridge tracked it: the worker skips it)."""
        tracker = self.tracker
        last = tracker.last_stamp_ns if tracker is not None and tracker.state == "tracking" else None
        return stamp_ns is not None and last is not None and stamp_ns <= last

    def bridge(self, found: Any, stamp_ns: int) -> Iterator[tuple[Cloud, Any]]:
        """After a search placed the scan stamped ``stamp_ns`` (``found``: its :meth:`step`): track the scans that
        arrived meanwhile (:meth:`ScanBridge.take`), in stamp order, yielding each with its :meth:`step` (published
        like any tracked scan); ends when none is left or the tracker lost the pose. One log line, on the last."""
        self.last_bridge = ""
        if found.result.event not in ("found", "relocalized") or self.tracker is None:
            self._bridge_pending = False
            return
        t0 = time.perf_counter()
        self._bridging, self._bridge_pending = True, False
        try:
            yield from self._follow(stamp_ns)
        finally:
            self._bridging = False
        self._say_drops(self.tracker.last_stamp_ns or stamp_ns)
        if self._followed:
            self.last_bridge = (f"localization: followed the pose through {self._followed} scan(s) that arrived during "
                                f"the search in {(time.perf_counter() - t0):.2f} s; "
                                + (f"it fell behind the stream ({self._behind}): tracking from the newest scan"
                                   if self._behind else "tracking from the newest"))

    def _follow(self, stamp_ns: int) -> Iterator[tuple[Cloud, Any]]:
        done = self._followed = 0
        self._behind = ""
        # scans keep arriving meanwhile: round after round until none is left (a cap on the rounds would leave the
        # last arrivals to the worker's one-scan slot, where all but the newest are lost) while the bridge gains on the
        # stream (node/bridge.py gains(): fewer scans arrived while it followed its last `window` than that; else it
        # ends there)
        marks: list[int] = []  # the arrivals counted when each followed scan began
        window = 0
        while self.tracker.state == "tracking":
            # the newest too: the worker's slot keeps only one scan, so a scan left there for it is lost when another
            # arrives before the worker is back (after the bridge, the slot's scan is one answered already: skipped)
            scans = self._bridge.take(self.tracker.last_stamp_ns or stamp_ns, leave_newest=False,
                                      keep_since=self._found_t)  # those since the pose was found: every one
            if not scans:
                break
            window = window or max(len(scans), BRIDGE_MAX)
            for i, cloud in enumerate(scans):
                marks.append(self._bridge.arrived)
                try:
                    loc = self.step(cloud)
                except BadInput:
                    loc = None
                if loc is None:
                    marks.pop()
                    continue
                done += 1
                self._followed = done
                self.bridged += bool(loc.result.valid)
                yield cloud, loc
                arrived = self._bridge.arrived - marks[max(len(marks) - window, 0)]
                if not loc.result.valid or not gains(window, arrived):
                    if loc.result.valid:
                        self._behind = (f"{arrived} scan(s) arrived while it followed the last "
                                        f"{min(len(marks), window)}")
                    self._bridge.restore(scans[i + 1:])  # dropped (counted) once the worker answers a later scan
                    return  # the worker's next scan goes on from the last good pose

    def _say_drops(self, stamp_ns: int) -> None:
        """Hand the scans the bridge dropped since the last call to :attr:`drop_sink` (counted and said once)."""
        n = self._bridge.dropped - self._drops_said
        if n > 0 and self.drop_sink is not None:
            self._drops_said += n
            self.drop_sink(BRIDGE_DROP, stamp_ns, n)
