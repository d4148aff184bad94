"""The scan record every reader yields, every writer takes and the simulator produces."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.datasets.poses import (  # noqa: F401  (re-exported)
    PoseTrack,
    T_to_xyzquat,
    parse_stamp,
    stamp_to_str,
    xyzquat_to_T,
)
from deepbbs_ros.errors import DatasetError

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


class ScanSource:
    """A recording read as a sequence of :class:`Scan` in stamp order.

    Subclasses fill ``path``, ``topic``, ``has_ground_truth`` and implement :meth:`_scans` and
    :meth:`__len__`. With ``lenient=True`` iteration stops quietly at the first fault, after yielding
    every valid scan before it, and appends the fault's message to :attr:`errors`; damage that costs
    only itself (a damaged scan file, a damaged bag chunk: :meth:`skip`) is recorded the same way and
    reading goes on after it. Otherwise every fault raises :class:`~deepbbs_ros.errors.DatasetError`
    (or its subclass ``BagError``).
    """

    format: str = "?"

    def __init__(self, path: Path | str, *, lenient: bool = False) -> None:
        self.path = Path(path)
        self.lenient = lenient
        self.topic: str | None = None
        self.gt_topic: str | None = None
        self.has_ground_truth = False
        self.errors: list[str] = []
        self.fault_at: list[int] = []
        self._deferred: list[DatasetError] = []
        self.warnings: list[str] = []  # damage that cost nothing (e.g. a summary rebuilt by reading)

    def _scans(self) -> Iterator[Scan]:  # pragma: no cover - abstract
        raise NotImplementedError

    def __len__(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def __iter__(self) -> Iterator[Scan]:
        self.yielded = 0
        try:
            for scan in self._scans():
                self.yielded += 1
                yield scan
        except DatasetError as err:
            if not self.lenient:
                raise
            self.fault(err)
        else:  # damage found on opening that no scan ran into (e.g. a bad line after the last frame's pose)
            self.warnings.extend(str(e) for e in self._deferred if str(e) not in self.warnings)

    def defer(self, err: DatasetError) -> None:
        """Damage found on opening (a pose file's bad line): raise when strict; when lenient, the scans
        before it are read and the scan that needs what it lost raises it (then recorded by
        :meth:`fault`, with its position)."""
        if not self.lenient:
            raise err
        self._deferred.append(err)

    def fault(self, err: DatasetError) -> None:
        """Raise ``err``, or record it (once) when lenient; the caller then stops as it documents.
        ``fault_at`` keeps, for each recorded fault, how many scans had been yielded before it."""
        if not self.lenient:
            raise err
        if str(err) not in self.errors:
            self.errors.append(str(err))
            self.fault_at.append(getattr(self, "yielded", 0))

    def skip(self, err: DatasetError) -> None:
        """Damage that costs only itself (one scan file, one bag chunk): raise ``err`` when strict;
        when lenient record it and let reading go on after it."""
        if not self.lenient:
            raise err
        self.fault(type(err)(f"{err}; skipped, reading went on"))

    def close(self) -> None:
        """Release open files (bags); iterating afterwards is not supported."""

    def __enter__(self) -> ScanSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> dict[str, Any]:
        """Summary for ``deepbbs-bag info``: format, path, topic, frames, ground truth."""
        return {
            "path": str(self.path),
            "format": self.format,
            "topic": self.topic,
            "gt_topic": self.gt_topic,
            "frames": len(self),
            "ground_truth": self.has_ground_truth,
        }

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, frames={len(self)}, ground_truth={self.has_ground_truth})"


def prepare_output(out: Path) -> None:
    """Refuse to write into an existing non-empty path (like rosbags' Writer): DatasetError."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DatasetError(f"{out} exists already, not overwriting")


def numbered_files(root: Path, sub: str, suffix: str, *, kind: str, names: str) -> tuple[Path, list[tuple[int, Path]]]:
    """``(root / sub, [(number, file), ...])``: the files ``<digits><suffix>`` in ``root / sub``, sorted by number.

    DatasetError when ``root / sub`` is not a directory (``root`` is then not ``kind``) or holds no such
    file (``names`` says which are expected, e.g. ``"N.pcd"``).
    """
    folder = root / sub
    if not folder.is_dir():
        raise DatasetError(f"{root}: not {kind} (no {sub}/ directory)")
    files = sorted((int(f.stem), f) for f in folder.glob(f"*{suffix}") if f.stem.isdigit())
    if not files:
        raise DatasetError(f"{folder}: no {names} files")
    return folder, files


def missing_pose_error(pose_file: Path | None, pose_error: DatasetError | None, index: int, name: str) -> DatasetError:
    """The error for frame ``index`` (file ``name``) that has no ground-truth pose in ``pose_file``.

    The pose file's own fault when reading it stopped early (``pose_error``), else "has no ground-truth pose".
    """
    if pose_error is not None:
        return pose_error
    return DatasetError(f"{pose_file}: frame {index} ({name}) has no ground-truth pose")


def check_ground_truth(out: Path, scan: Scan, with_gt: bool | None) -> bool:
    """For writers: whether ``scan`` carries ground truth, which must match the scans before it.

    ``with_gt`` is what the first scan decided (None before the first); DatasetError when ``scan``
    differs from it.
    """
    has = scan.T_world_lidar is not None
    if with_gt is not None and has != with_gt:
        raise DatasetError(f"{out}: scan {scan.index} {'has' if has else 'lacks'} ground truth, unlike the first")
    return has


def scan_intensity(scan: Scan) -> np.ndarray:
    """(N,) float32 intensity of ``scan``, zeros when it has none (for formats that always store one)."""
    intensity = scan.fields.get("intensity")
    intensity = np.zeros(len(scan), np.float32) if intensity is None else np.asarray(intensity, np.float32)
    return intensity.reshape(-1)


def valid_mask(points: np.ndarray) -> np.ndarray:
    """(N,) bool: rows of (N, 3) ``points`` whose coordinates are all finite."""
    return np.all(np.isfinite(points), axis=1)


def check_scan_file(path: Path, total: int, kept: int) -> None:
    """DatasetError when a scan file held ``total`` points of which ``kept`` are finite and none is left
    (an all-NaN or empty file is a damaged frame, not a scan)."""
    if kept == 0:
        what = "no points" if total == 0 else f"no finite point (all {total} points are NaN/Inf)"
        raise DatasetError(f"{path}: {what}")


class SizedIterable:
    """Wrap an iterator with a known length, so progress bars show a total (``write_scans(SizedIterable(it, n))``)."""

    def __init__(self, iterable: Iterable[Scan], length: int) -> None:
        self._iterable = iterable
        self._length = int(length)

    def __iter__(self) -> Iterator[Scan]:
        return iter(self._iterable)

    def __len__(self) -> int:
        return self._length
