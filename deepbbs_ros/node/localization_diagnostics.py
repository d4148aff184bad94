"""The /diagnostics of ``node.target_mode: localization`` (no ROS import): the tracker's state, the WARN message while
no pose is published, and the values shown under ``localization.*``."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["LocalizationDiagnostics"]


class LocalizationDiagnostics:
    """Part of :class:`~deepbbs_ros.node.localization.NodeLocalization`: what /diagnostics shows of it (read from the
    executor thread)."""

    # what it reads of the NodeLocalization it is part of (its counters: NodeLocalization.__init__)
    tracker: Any
    localizer: Any
    map: Any  # MapData | None
    map_build_s: float
    placed: int
    rejected: int
    last_event: str
    last_reason: str
    last_score: float
    last_path: str
    first_pose_s: float
    time_to_first_pose_s: float
    prefetched: int
    prepared: int
    bridged: int
    dropped: int

    @property
    def state(self) -> str:
        """``"no map"``, or the tracker's state: ``searching`` | ``tracking`` | ``lost``."""
        tracker = self.tracker
        return "no map" if tracker is None else str(tracker.state)

    def warning(self) -> str:
        """The /diagnostics status message while there is no pose to publish (WARN), else ""."""
        state = self.state
        if state == "no map":
            return "localization: no map yet"
        if state == "lost":
            return f"localization lost: {self.last_reason}"
        if state == "searching" and self.rejected:
            return f"localization searching: {self.last_reason}"
        return ""

    def diagnostics(self) -> dict[str, Any]:
        """The values /diagnostics shows under ``localization.*``."""
        tracker = self.tracker
        out: dict[str, Any] = {
            "state": self.state,
            "placed": self.placed,
            "rejected": self.rejected,
            "recoveries": getattr(tracker, "recoveries", 0),
            "last event": self.last_event or "-",
            "last reason": self.last_reason or "-",
            "last score": f"{self.last_score:.3f}",
            "last path": self.last_path or "-",
            "time to first pose (s)": _seconds(self.first_pose_s),
            "last search took (s)": _seconds(self.time_to_first_pose_s),
            "map crops prepared ahead": self.prefetched,
            "scans prepared on arrival": self.prepared,
            "scans followed after a search": self.bridged,
            "scans kept during a search, dropped": self.dropped,
        }
        if self.map is not None:
            out["map"] = f"{self.map.source}: {len(self.map.points)} points in {self.map.frame_id!r}"
            out["map places"] = len(self.localizer.places) if self.localizer is not None else 0
            out["map build (s)"] = _seconds(self.map_build_s)
        return out


def _seconds(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value:.2f}"
