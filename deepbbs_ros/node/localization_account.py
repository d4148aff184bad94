"""What one scan through the live localization changes of its counters, and the state change it logs (no ROS
import): the first pose ("found"), found again ("relocalized") with the time the search took, the pose lost, and a
long search said at most every ``node.error_log_period`` s.

:class:`LocalizationAccount` is a part of :class:`~deepbbs_ros.node.localization.NodeLocalization` (a mixin); its
counters are made in ``NodeLocalization.__init__`` and read by /diagnostics
(:mod:`~deepbbs_ros.node.localization_diagnostics`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.node.inputs import Cloud


class LocalizationAccount:
    """The counters and state-change lines of :class:`~deepbbs_ros.node.localization.NodeLocalization`."""

    def _account(self, res: Any, T: np.ndarray, valid: bool, cloud: Cloud, tracker: Any) -> str | None:
        """Count the tracker's answer ``res`` on ``cloud`` (``T``: T_map_scan; ``valid``: published) -> the state
        change to log, or None."""
        self.events[res.event] = self.events.get(res.event, 0) + 1
        self.last_event, self.last_score, self.last_path = res.event, float(res.score), res.path
        line = None
        if valid:
            self.placed += 1
            self.last_reason = ""
            if self._search_t0 is not None:  # a search ended: found / relocalized
                took = time.perf_counter() - self._search_t0
                self.time_to_first_pose_s = took
                if np.isnan(self.first_pose_s):
                    self.first_pose_s = took
                near = " near the initial pose" if getattr(res, "mode", "") == "hint" else ""
                line = (f"localization {'relocalized' if res.event == 'relocalized' else 'found'}{near}: "
                        f"{_pose_text(T)} in {self.map.frame_id!r} after {self._search_scans + 1} scan(s), "
                        f"{took:.2f} s (score {res.score:.2f}, {res.candidates} candidate place(s))")
                self._search_t0 = None
                self._bridge_pending = not self._bridging
                self._found_t = time.perf_counter()  # the scans received from now on are all bridged
        else:
            self.rejected += 1
            self.last_reason = res.reason or "rejected"
            if res.event == "lost":
                self._search_t0, self._search_scans = time.perf_counter(), 0
                line = (f"localization lost at scan {cloud.stamp_ns} ns: {self.last_reason}; searching the whole "
                        "map from the next scan (no pose is published meanwhile)")
            elif tracker.state != "tracking":
                self._search_scans += 1
                now = time.monotonic()
                if now - self._last_search_log >= max(self.config.node.error_log_period, 1e-9):
                    self._last_search_log = now
                    line = (f"localization searching: no pose for {self._search_scans} scan(s), last: "
                            f"{self.last_reason}")
        return line


def _pose_text(T: np.ndarray) -> str:
    """``x 12.30 y -4.10 z 1.90 m, yaw 35.0 deg``."""
    yaw = np.degrees(np.arctan2(T[1, 0], T[0, 0]))
    x, y, z = T[:3, 3]
    return f"x {x:.2f} y {y:.2f} z {z:.2f} m, yaw {yaw:.1f} deg"
