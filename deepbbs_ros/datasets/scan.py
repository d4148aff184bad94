"""The scan record every reader yields, every writer takes and the simulator produces: :class:`Scan`, with the
per-point time fields of real drivers (:func:`time_field`, :func:`time_offsets`) and the topic and frame names
of the Apollo layout."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

APOLLO_LIDAR_TOPIC = "/apollo/sensor/velodyne64/compensator/PointCloud2"
APOLLO_RAW_LIDAR_TOPIC = "/apollo/sensor/velodyne64/PointCloud2"  # raw sweeps, per-point time
APOLLO_LIDAR_FRAME = "velodyne64"
GT_POSE_TOPIC = "/ground_truth/pose"
WORLD_FRAME = "world"
#: per-point time fields of real drivers and their unit in seconds: Velodyne ``time`` (s since the
#: stamp), Ouster ``t`` (ns since the stamp); the first one a cloud has is used
TIME_FIELDS = (("time", 1.0), ("t", 1e-9))
#: absolute per-point time field of Livox (float64 ns) and Hesai / RoboSense (float64 s), read after TIME_FIELDS
ABSOLUTE_TIME_FIELD = "timestamp"


def time_field(names: Iterable[str]) -> str | None:
    """The per-point time field a cloud with fields ``names`` is timed by: the first of :data:`TIME_FIELDS`, else
    :data:`ABSOLUTE_TIME_FIELD`, else None."""
    names = set(names)
    absolute = ABSOLUTE_TIME_FIELD if ABSOLUTE_TIME_FIELD in names else None
    return next((n for n, _ in TIME_FIELDS if n in names), absolute)


def time_offsets(name: str, values: np.ndarray, stamp_ns: int) -> np.ndarray:
    """(N,) float64 seconds since ``stamp_ns`` from the per-point time field ``name`` (:func:`time_field`) holding
    ``values``: relative fields scaled by their unit; the absolute ``timestamp`` read as nanoseconds when its values
    exceed 1e12 (Livox), else as seconds (Hesai, RoboSense), and made relative to the stamp."""
    ts = np.asarray(values, dtype=np.float64)
    unit = dict(TIME_FIELDS).get(name)
    if unit is not None:
        return ts * unit
    if len(ts) and float(np.max(ts)) > 1e12:
        return (ts - float(stamp_ns)) * 1e-9
    return ts - stamp_ns * 1e-9


@dataclass
class Scan:
    """One LiDAR sweep.

    Attributes:
        index: frame number within its recording (0-based for bags; Apollo folders keep their
            1-based file number).
        stamp_ns: header stamp in nanoseconds (start of the sweep for simulated scans).
        points: (N, 3) float32 xyz in the sensor frame, metres, only valid returns.
        fields: extra per-point arrays with the same N (e.g. ``intensity`` float32, ``time``
            float32 seconds relative to ``stamp_ns``, ``ring`` uint16; drivers' own time fields:
            Ouster ``t`` uint32 ns since the stamp, Livox ``timestamp`` float64 absolute ns, Hesai and
            RoboSense ``timestamp`` float64 absolute s).
        frame_id: the sensor frame.
        T_world_lidar: (4, 4) float64 ground-truth pose of the sensor at ``stamp_ns``, or None.
    """

    index: int
    stamp_ns: int
    points: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    frame_id: str = APOLLO_LIDAR_FRAME
    T_world_lidar: np.ndarray | None = None

    def point_times(self) -> np.ndarray | None:
        """(N,) float64 seconds since ``stamp_ns`` from the first of :data:`TIME_FIELDS` present, else the absolute
        ``timestamp`` (:func:`time_offsets`), or None."""
        name = time_field(self.fields)
        return None if name is None else time_offsets(name, self.fields[name], self.stamp_ns)

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float32).reshape(-1, 3)
        if self.T_world_lidar is not None:
            self.T_world_lidar = np.asarray(self.T_world_lidar, dtype=np.float64).reshape(4, 4)

    @property
    def stamp_s(self) -> float:
        return self.stamp_ns * 1e-9

    def __len__(self) -> int:
        return int(self.points.shape[0])
