"""A simulated drive as frames (no ROS): frame k is stamped ``STAMP0_NS + k period``; its ground-truth pose is read
without ray casting. The simulators (sim/simulator.py, sim/rig.py) give the poses and the scans."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from deepbbs_ros.datasets.base import Scan

STAMP0_NS = 1_600_000_000 * 10**9  # stamp of frame 0 (2020-09-13T12:26:40Z), keeps stamps non-zero


class Frames:
    """A drive as frames: ``frames`` scans ``period`` s apart, frame k stamped ``STAMP0_NS + k period``; the
    subclass gives ``T_world_lidar(t)`` and ``scan_at(k)``."""

    frames: int
    period: float

    def __len__(self) -> int:
        return self.frames

    def __iter__(self) -> Iterator[Scan]:
        for k in range(self.frames):
            yield self.scan_at(k)

    def pose_at(self, frame: int) -> np.ndarray:
        """(4, 4) float64 ground-truth ``T_world_lidar`` at the stamp of ``frame`` (no ray casting)."""
        return self.T_world_lidar(frame * self.period)

    def stamp_ns(self, frame: int) -> int:
        return STAMP0_NS + int(round(frame * self.period * 1e9))

    def frames_apart(self, spacing: float, count: int, start: int = 0) -> list[int]:
        """Up to ``count`` frames from ``start`` on, each at least ``spacing`` m (ground truth) from the one
        picked before it."""
        picks: list[int] = []
        last = None
        for k in range(start, self.frames):
            p = self.pose_at(k)[:3, 3]
            if last is None or np.linalg.norm(p - last) >= spacing:
                picks.append(k)
                last = p
                if len(picks) == count:
                    break
        return picks
