"""The scan record every reader yields, every writer takes and the simulator produces."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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


def _slerp_T(T0: np.ndarray, T1: np.ndarray, alpha: float) -> np.ndarray:
    """Interpolate two (4, 4) poses: translation linearly, rotation by SLERP; alpha in [0, 1]."""
    from scipy.spatial.transform import Rotation, Slerp

    rots = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
    T = np.eye(4)
    T[:3, :3] = Slerp([0.0, 1.0], rots)([alpha]).as_matrix()[0]
    T[:3, 3] = (1.0 - alpha) * T0[:3, 3] + alpha * T1[:3, 3]
    return T


class PoseTrack:
    """Ground-truth poses ``T_world_lidar`` sorted by stamp, looked up by a scan's header stamp.

    Matching rule (:meth:`lookup`): a pose whose stamp equals the scan's is used as is; otherwise,
    when the scan stamp lies between two poses that are both within ``tolerance_ns`` of it, the pose
    is interpolated (translation linearly, rotation by SLERP); otherwise the nearest pose within
    ``tolerance_ns`` is used; otherwise there is no ground truth for that scan (None).
    """

    def __init__(self, stamps_ns: Sequence[int], poses: Sequence[np.ndarray], tolerance_ns: int) -> None:
        order = np.argsort(np.asarray(stamps_ns, dtype=np.int64), kind="stable")
        self.stamps_ns: list[int] = [int(stamps_ns[i]) for i in order]
        self.poses = [np.asarray(poses[i], dtype=np.float64) for i in order]
        self.tolerance_ns = int(tolerance_ns)

    def __len__(self) -> int:
        return len(self.poses)

    def add(self, stamp_ns: int, T: np.ndarray) -> None:
        """Add one pose (poses read in recording order: appended; out of order: inserted)."""
        import bisect

        i = bisect.bisect_right(self.stamps_ns, int(stamp_ns))
        self.stamps_ns.insert(i, int(stamp_ns))
        self.poses.insert(i, np.asarray(T, dtype=np.float64))

    def decided(self, stamp_ns: int) -> bool:
        """True once a pose later than ``stamp_ns + tolerance_ns`` is known: poses still to come (in
        stamp order) cannot change :meth:`lookup` at ``stamp_ns``."""
        return bool(self.stamps_ns) and self.stamps_ns[-1] > stamp_ns + self.tolerance_ns

    def lookup(self, stamp_ns: int) -> np.ndarray | None:
        """(4, 4) float64 ``T_world_lidar`` at ``stamp_ns``, or None when no pose is close enough."""
        import bisect

        if not self.poses:
            return None
        i = bisect.bisect_left(self.stamps_ns, stamp_ns)
        if i < len(self.poses) and self.stamps_ns[i] == stamp_ns:
            return self.poses[i].copy()
        lo, hi = i - 1, i
        d_lo = stamp_ns - self.stamps_ns[lo] if lo >= 0 else None
        d_hi = self.stamps_ns[hi] - stamp_ns if hi < len(self.poses) else None
        ok_lo = d_lo is not None and d_lo <= self.tolerance_ns
        ok_hi = d_hi is not None and d_hi <= self.tolerance_ns
        if ok_lo and ok_hi:
            return _slerp_T(self.poses[lo], self.poses[hi], d_lo / float(d_lo + d_hi))
        if ok_lo:
            return self.poses[lo].copy()
        if ok_hi:
            return self.poses[hi].copy()
        return None


def stamp_to_str(stamp_ns: int) -> str:
    """Seconds as an exact decimal string, ``"1700000000.100000000"`` (no float rounding)."""
    sign = "-" if stamp_ns < 0 else ""
    sec, nsec = divmod(abs(int(stamp_ns)), 1_000_000_000)
    return f"{sign}{sec}.{nsec:09d}"


def parse_stamp(text: str) -> int:
    """Decimal seconds (``"1700000000.1"``, ``"1.7e9"``) to integer nanoseconds, exactly; ValueError."""
    from decimal import Decimal, InvalidOperation

    try:
        value = Decimal(text) * 1_000_000_000
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    if not value.is_finite():
        raise ValueError(f"not a finite time: {text!r}")
    return int(value.to_integral_value())


def T_to_xyzquat(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose -> (7,) float64 ``x y z qx qy qz qw`` (unit quaternion, w >= 0)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(T, dtype=np.float64)[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([np.asarray(T, dtype=np.float64)[:3, 3], q])


def xyzquat_to_T(values: Sequence[float]) -> np.ndarray:
    """``x y z qx qy qz qw`` -> (4, 4) float64 pose; ValueError on a zero or non-finite quaternion.

    The quaternion is normalised first (a pose file's few digits leave its norm off 1), so the rotation
    block is a rotation to about 1e-16 whatever the file held."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(values, dtype=np.float64)
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise ValueError("expected 7 finite numbers x y z qx qy qz qw")
    if np.linalg.norm(v[3:]) < 1e-9:
        raise ValueError("quaternion has zero norm")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:] / np.linalg.norm(v[3:])).as_matrix()
    T[:3, 3] = v[:3]
    return T


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
