"""Apollo-SouthBay session folders: ``pcds/N.pcd`` + ``poses/gt_poses.txt``.

Layout (CONVENTIONS.md)::

    <session>/pcds/1.pcd, 2.pcd, ...        1-based, no zero padding; x y z intensity float32, NaNs possible
    <session>/poses/gt_poses.txt            one line per frame: index timestamp x y z qx qy qz qw

The pose is ``T_world_lidar`` (the LiDAR in the world frame), the timestamp seconds. Stamps are kept
as exact integer nanoseconds (the timestamp text is parsed as a decimal, not through float64).
A folder without ``poses/gt_poses.txt`` reads without ground truth, stamps then being index * 0.1 s.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.base import (
    APOLLO_LIDAR_FRAME,
    Scan,
    ScanSource,
    check_ground_truth,
    missing_pose_error,
    numbered_files,
    prepare_output,
    scan_intensity,
)
from deepbbs_ros.datasets.pcd import read_pcd_points, write_pcd
from deepbbs_ros.datasets.poses import T_to_xyzquat, parse_stamp, stamp_to_str, xyzquat_to_T
from deepbbs_ros.errors import DatasetError

POSE_FILE = Path("poses") / "gt_poses.txt"


def is_apollo_folder(path: Path) -> bool:
    return path.is_dir() and (path / "pcds").is_dir()


def read_gt_poses(path: Path) -> tuple[dict[int, tuple[int, np.ndarray]], DatasetError | None]:
    """Parse ``gt_poses.txt``: ``{index: (stamp_ns, T_world_lidar (4, 4))}`` up to the first bad line.

    Returns the poses read before the first malformed line and that line's error (None if clean).
    Blank lines and ``#`` comments are skipped.
    """
    poses: dict[int, tuple[int, np.ndarray]] = {}
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        return poses, DatasetError(f"{path}: cannot read pose file: {err}")
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            if len(parts) != 9:
                raise ValueError(f"{len(parts)} values, expected 9 (index timestamp x y z qx qy qz qw)")
            index = int(parts[0])
            stamp_ns = parse_stamp(parts[1])
            T = xyzquat_to_T([float(v) for v in parts[2:]])
            if index in poses:
                raise ValueError(f"frame {index} appears twice")
        except ValueError as err:
            return poses, DatasetError(f"{path}: line {lineno}: malformed pose line: {err}")
        poses[index] = (stamp_ns, T)
    return poses, None


class ApolloSource(ScanSource):
    """Scans of an Apollo-SouthBay session folder, in file-number order (index = file number)."""

    format = "apollo"

    def __init__(self, path: Path | str, *, lenient: bool = False) -> None:
        super().__init__(path, lenient=lenient)
        pcd_dir, self.files = numbered_files(self.path, "pcds", ".pcd", kind="an Apollo session folder", names="N.pcd")
        self.pose_file = self.path / POSE_FILE
        self.poses: dict[int, tuple[int, np.ndarray]] = {}
        self.pose_error: DatasetError | None = None
        if self.pose_file.exists():
            self.has_ground_truth = True
            self.poses, self.pose_error = read_gt_poses(self.pose_file)
            if self.pose_error is not None:
                self.defer(self.pose_error)  # strict: raise now; lenient: keep what was read
        self.topic = str(pcd_dir)
        self.gt_topic = str(self.pose_file) if self.has_ground_truth else None

    def __len__(self) -> int:
        return len(self.files)

    def _scans(self) -> Iterator[Scan]:
        for index, f in self.files:
            T = None
            if self.has_ground_truth:
                if index not in self.poses:
                    raise missing_pose_error(self.pose_file, self.pose_error, index, f.name)
                stamp_ns, T = self.poses[index]
            else:
                stamp_ns = index * 100_000_000
            try:
                xyz, fields = read_pcd_points(f, require_points=True)
            except DatasetError as err:
                self.skip(err)  # a damaged PCD costs its own frame
                continue
            yield Scan(index, stamp_ns, xyz, fields, frame_id=APOLLO_LIDAR_FRAME, T_world_lidar=T)

    def info(self) -> dict:
        d = super().info()
        if self.poses:
            stamps = [s for s, _ in self.poses.values()]
            d["duration_s"] = (max(stamps) - min(stamps)) * 1e-9
        return d


def write_apollo(scans: Iterable[Scan], out: Path | str, *, encoding: str = "binary") -> int:
    """Write scans as an Apollo session folder; files are numbered 1..n in the order given.

    Each PCD holds ``x y z intensity`` float32 (intensity 0 when the scan has none; other fields
    are not part of the format and are dropped). ``poses/gt_poses.txt`` is written when the scans
    carry ground truth; a scan without it among scans with it raises DatasetError.

    Returns:
        the number of frames written.
    """
    out = Path(out)
    prepare_output(out)
    (out / "pcds").mkdir(parents=True, exist_ok=True)
    lines: list[str] = []
    n = 0
    with_gt: bool | None = None
    for n, scan in enumerate(scans, start=1):
        with_gt = check_ground_truth(out, scan, with_gt)
        write_pcd(out / "pcds" / f"{n}.pcd", {"points": scan.points, "intensity": scan_intensity(scan)}, encoding)
        if with_gt:
            v = T_to_xyzquat(scan.T_world_lidar)
            lines.append(f"{n} {stamp_to_str(scan.stamp_ns)} " + " ".join(repr(float(x)) for x in v))
    if with_gt:
        (out / "poses").mkdir(exist_ok=True)
        (out / POSE_FILE).write_text("\n".join(lines) + "\n")
    return n
