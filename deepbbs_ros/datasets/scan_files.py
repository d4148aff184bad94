"""What the file readers and writers share: refusing to overwrite (:func:`prepare_output`), numbered scan files
(:func:`numbered_files`), the errors of a missing pose and of an empty scan file, ground truth kept consistent by a
writer, a scan's intensity and its finite points."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.scan import Scan
from deepbbs_ros.errors import DatasetError


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
