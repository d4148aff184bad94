"""The scan record every reader yields, every writer takes and the simulator produces."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

APOLLO_LIDAR_TOPIC = "/apollo/sensor/velodyne64/compensator/PointCloud2"
APOLLO_LIDAR_FRAME = "velodyne64"
GT_POSE_TOPIC = "/ground_truth/pose"
WORLD_FRAME = "world"


@dataclass
class Scan:
    """One LiDAR sweep.

    Attributes:
        index: frame number within its recording (0-based for bags; Apollo folders keep their
            1-based file number).
        stamp_ns: header stamp in nanoseconds (start of the sweep for simulated scans).
        points: (N, 3) float32 xyz in the sensor frame, metres, only valid returns.
        fields: extra per-point arrays with the same N (e.g. ``intensity`` float32, ``time``
            float32 seconds relative to ``stamp_ns``, ``ring`` uint16).
        frame_id: the sensor frame.
        T_world_lidar: (4, 4) float64 ground-truth pose of the sensor at ``stamp_ns``, or None.
    """

    index: int
    stamp_ns: int
    points: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    frame_id: str = APOLLO_LIDAR_FRAME
    T_world_lidar: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float32).reshape(-1, 3)
        if self.T_world_lidar is not None:
            self.T_world_lidar = np.asarray(self.T_world_lidar, dtype=np.float64).reshape(4, 4)

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

    def __len__(self) -> int:
        return int(self.points.shape[0])
