"""Plain folders of scans: ``*.bin`` (KITTI's float32 ``x y z reflectance`` records) or ``*.pcd`` files.

The files are read in name order, digits compared as numbers (``2.pcd`` before ``10.pcd``; zero-padded
names sort the same either way), as kiss-icp's generic loader reads a folder. Such a folder has no
stamps and no ground truth: scan k is stamped k * 0.1 s (10 Hz) and carries no pose, so a replay can
measure trajectories and runtime but no error (odometry mode; pairs mode needs ground truth). For
errors, put the scans in an Apollo (``pcds/`` + ``poses/gt_poses.txt``) or KITTI (``velodyne/`` +
``poses.txt`` + ``calib.txt``) layout.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.base import (
    APOLLO_LIDAR_FRAME,
    Scan,
    ScanSource,
    check_scan_file,
    valid_mask,
)
from deepbbs_ros.datasets.pcd import read_pcd_points
from deepbbs_ros.errors import DatasetError

SUFFIXES = (".bin", ".pcd")
PERIOD_NS = 100_000_000  # 10 Hz: the stamp of scan k is k * 0.1 s


def _name_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def scan_files(path: Path) -> list[Path]:
    """The ``.bin`` / ``.pcd`` files directly in ``path``, in name order (digits as numbers)."""
    if not path.is_dir():
        return []
    return sorted((f for f in path.iterdir() if f.is_file() and f.suffix.lower() in SUFFIXES), key=_name_key)


def is_scan_folder(path: Path) -> bool:
    return bool(scan_files(path))


def read_bin(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A KITTI-style ``.bin`` scan: (xyz (N, 3) float32, {"intensity": (N,)}), non-finite rows dropped;
    DatasetError on a size that is not whole records or a file without a finite point."""
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise DatasetError(f"{path}: cannot read scan: {err.strerror or err}") from None
    if len(raw) % 16:
        raise DatasetError(f"{path}: size {len(raw)} bytes is not a multiple of 16 (x y z r float32)")
    rec = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    keep = valid_mask(rec[:, :3])
    check_scan_file(path, len(rec), int(keep.sum()))
    return rec[keep, :3], {"intensity": np.ascontiguousarray(rec[keep, 3])}


class FolderSource(ScanSource):
    """Scans of a plain folder of ``.bin`` or ``.pcd`` files, in name order, index 0-based, no ground truth."""

    format = "folder"

    def __init__(self, path: Path | str, *, lenient: bool = False) -> None:
        super().__init__(path, lenient=lenient)
        self.files = scan_files(self.path)
        if not self.files:
            raise DatasetError(f"{self.path}: no .bin or .pcd files")
        kinds = {f.suffix.lower() for f in self.files}
        if len(kinds) > 1:
            raise DatasetError(f"{self.path}: holds both .bin and .pcd files; keep one kind per folder")
        self.topic = str(self.path)

    def __len__(self) -> int:
        return len(self.files)

    def _scans(self) -> Iterator[Scan]:
        for index, f in enumerate(self.files):
            try:
                xyz, fields = read_bin(f) if f.suffix.lower() == ".bin" else read_pcd_points(f, require_points=True)
            except DatasetError as err:
                self.skip(err)  # a damaged scan file costs its own frame
                continue
            yield Scan(index, index * PERIOD_NS, xyz, fields, frame_id=APOLLO_LIDAR_FRAME)

    def info(self) -> dict:
        d = super().info()
        d["duration_s"] = (len(self.files) - 1) * PERIOD_NS * 1e-9
        d["stamps"] = "none in the files: scan k at k * 0.1 s"
        return d
