"""KITTI odometry sequence folders: ``velodyne/NNNNNN.bin`` + ``poses.txt`` + ``calib.txt`` (+ ``times.txt``).

* ``velodyne/NNNNNN.bin``: float32 records ``x y z reflectance`` (read into ``Scan.fields["intensity"]``).
* ``poses.txt``: one 3x4 row-major matrix per frame, ``P_k`` = the pose of the left camera (cam0) of
  frame k in the cam0 frame of frame 0 (KITTI's own convention). The official layout keeps it in
  ``dataset/poses/<seq>.txt``; both places are accepted.
* ``calib.txt``: ``Tr`` = ``T_cam0_velo`` (3x4), mapping LiDAR points into the camera frame. Only the ground
  truth needs it: without it the folder reads as one without ground truth (a warning says why).
* ``times.txt``: seconds since the start of the sequence, one per frame (else index * 0.1 s).

Ground truth in the LiDAR frame (as kiss-icp's KITTI loader does)::

    T_world_lidar_k = Tr^-1 @ P_k @ Tr

with its rotation block made a rotation once, here (:func:`deepbbs_ros.metrics.nearest_rotation`:
KITTI's poses keep 6-7 significant digits, leaving ``R^T R`` about 1e-6 off the identity), so the
poses are the same whatever format the scans are converted to. ``world`` is the LiDAR frame of frame 0
(KITTI's "first camera frame" expressed through ``Tr``; ``T_world_lidar_0`` is the identity for a real
KITTI sequence). The writer inverts it,
``P_k = Tr @ T_world_lidar_k @ Tr^-1``, with KITTI's own ``Tr`` of sequences 00-02, so a write/read
round trip returns the same ``T_world_lidar``. Written ``times.txt`` holds stamps relative to the first
scan (KITTI keeps no absolute time), so absolute stamps are not preserved by this format. The writer is in
datasets/kitti_write.py (imported from here too).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.base import APOLLO_LIDAR_FRAME, Scan, ScanSource, missing_pose_error, numbered_files
from deepbbs_ros.datasets.kitti_write import KITTI_TR, write_kitti  # noqa: F401  (re-exported)
from deepbbs_ros.datasets.poses import parse_stamp
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.metrics import project_pose


def read_bin(path: Path):
    """A KITTI ``.bin`` scan (see :func:`deepbbs_ros.datasets.folder.read_bin`)."""
    from deepbbs_ros.datasets.folder import read_bin as _read_bin

    return _read_bin(path)


def is_kitti_folder(path: Path) -> bool:
    return path.is_dir() and (path / "velodyne").is_dir()


def _rows(path: Path, ncols: int, what: str) -> tuple[list[np.ndarray], DatasetError | None]:
    """Rows of ``ncols`` floats from a text file, up to the first malformed line (and its error)."""
    rows: list[np.ndarray] = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        return rows, DatasetError(f"{path}: cannot read {what}: {err}")
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        try:
            if len(parts) != ncols:
                raise ValueError(f"{len(parts)} values, expected {ncols}")
            vals = np.array([float(v) for v in parts])
            if not np.all(np.isfinite(vals)):
                raise ValueError("non-finite value")
        except ValueError as err:
            return rows, DatasetError(f"{path}: line {lineno}: malformed {what} line: {err}")
        rows.append(vals)
    return rows, None


def read_calib_tr(path: Path) -> np.ndarray:
    """``Tr`` (4, 4) float64 ``T_cam0_velo`` from a KITTI ``calib.txt``; DatasetError if absent/bad."""
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DatasetError(f"{path}: cannot read calibration: {err.strerror or err}") from None
    for lineno, line in enumerate(lines, start=1):
        key, _, rest = line.partition(":")
        if key.strip() == "Tr" or key.strip() == "Tr_velo_to_cam":
            try:
                vals = [float(v) for v in rest.split()]
                if len(vals) != 12:
                    raise ValueError(f"{len(vals)} values, expected 12")
            except ValueError as err:
                raise DatasetError(f"{path}: line {lineno}: malformed Tr: {err}") from None
            T = np.eye(4)
            T[:3, :] = np.reshape(vals, (3, 4))
            return T
    raise DatasetError(f"{path}: no 'Tr:' line (LiDAR-to-camera calibration)")


class KittiSource(ScanSource):
    """Scans of a KITTI odometry sequence folder, in file order (index = file number, 0-based)."""

    format = "kitti"

    def __init__(self, path: Path | str, *, lenient: bool = False) -> None:
        super().__init__(path, lenient=lenient)
        vdir, self.files = numbered_files(
            self.path, "velodyne", ".bin", kind="a KITTI sequence folder", names="NNNNNN.bin"
        )
        self.topic = str(vdir)
        self.pose_file: Path | None = None
        for cand in (self.path / "poses.txt", self.path.parent.parent / "poses" / f"{self.path.name}.txt"):
            if cand.is_file():
                self.pose_file = cand
                break
        self.poses: list[np.ndarray] = []
        self.pose_error: DatasetError | None = None
        #: why a pose file is left unused (no calib.txt), "" otherwise; among :attr:`warnings`
        self.truth_note = ""
        if self.pose_file is not None and not (self.path / "calib.txt").is_file():
            self.truth_note = (f"{self.pose_file} left unused: KITTI poses are camera 0's and need calib.txt with its "
                               f"'Tr:' line (LiDAR to camera 0) in {self.path} to become the LiDAR's; without it no "
                               "ground truth (odometry still runs)")
            self.warnings.append(self.truth_note)
            self.pose_file = None
        if self.pose_file is not None:
            self.has_ground_truth = True
            self.gt_topic = str(self.pose_file)
            Tr = read_calib_tr(self.path / "calib.txt")
            Tr_inv = np.linalg.inv(Tr)
            rows, self.pose_error = _rows(self.pose_file, 12, "pose")
            for r in rows:
                P = np.eye(4)
                P[:3, :] = r.reshape(3, 4)
                self.poses.append(project_pose(Tr_inv @ P @ Tr))
            if self.pose_error is not None:
                self.defer(self.pose_error)
        self.stamps_ns: list[int] | None = None
        self.times_error: DatasetError | None = None
        times = self.path / "times.txt"
        if times.is_file():
            stamps: list[int] = []
            for lineno, line in enumerate(times.read_text().splitlines(), start=1):
                if not line.strip():
                    continue
                try:
                    stamps.append(parse_stamp(line.strip()))
                except ValueError as err:
                    self.times_error = DatasetError(f"{times}: line {lineno}: malformed time: {err}")
                    self.defer(self.times_error)
                    break
            self.stamps_ns = stamps

    def __len__(self) -> int:
        return len(self.files)

    def _scans(self) -> Iterator[Scan]:
        for index, f in self.files:
            T = None
            if self.has_ground_truth:
                if index >= len(self.poses):
                    raise missing_pose_error(self.pose_file, self.pose_error, index, f.name)
                T = self.poses[index]
            if self.stamps_ns is not None:
                if index >= len(self.stamps_ns):
                    if self.times_error is not None:
                        raise self.times_error
                    raise DatasetError(f"{self.path / 'times.txt'}: frame {index} ({f.name}) has no time")
                stamp_ns = self.stamps_ns[index]
            else:
                stamp_ns = index * 100_000_000
            try:
                xyz, fields = read_bin(f)
            except DatasetError as err:
                self.skip(err)  # a damaged scan file costs its own frame
                continue
            yield Scan(index, stamp_ns, xyz, fields, frame_id=APOLLO_LIDAR_FRAME, T_world_lidar=T)
