"""Writing scans as a KITTI odometry sequence folder (:func:`write_kitti`), with KITTI's own calibration of
sequences 00-02 (:data:`KITTI_TR`); datasets/kitti.py's module docstring gives the layout and the poses' frames."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.base import Scan, check_ground_truth, prepare_output, scan_intensity
from deepbbs_ros.datasets.poses import stamp_to_str

# KITTI odometry sequences 00-02: T_cam0_velo and the cam0 projection, written by the writer.
KITTI_TR = np.array(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
_KITTI_P0 = "7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 " \
    "7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 " \
    "1.000000000000e+00 0.000000000000e+00"


def write_kitti(scans: Iterable[Scan], out: Path | str) -> int:
    """Write scans as a KITTI odometry sequence folder (files 000000.bin, ... in the order given).

    Writes ``velodyne/*.bin`` (x y z intensity float32; intensity 0 when absent), ``times.txt``
    (seconds since the first scan), ``calib.txt`` (KITTI's P0..P3 and ``Tr``) and, when the scans
    carry ground truth, ``poses.txt`` (``P_k = Tr @ T_world_lidar_k @ Tr^-1``).

    Returns:
        the number of frames written.
    """
    out = Path(out)
    prepare_output(out)
    (out / "velodyne").mkdir(parents=True, exist_ok=True)
    Tr = KITTI_TR
    Tr_inv = np.linalg.inv(Tr)
    poses: list[str] = []
    times: list[str] = []
    t0: int | None = None
    with_gt: bool | None = None
    n = 0
    for n, scan in enumerate(scans, start=1):
        with_gt = check_ground_truth(out, scan, with_gt)
        rec = np.concatenate([scan.points, scan_intensity(scan).reshape(-1, 1)], axis=1).astype("<f4")
        (out / "velodyne" / f"{n - 1:06d}.bin").write_bytes(rec.tobytes())
        t0 = scan.stamp_ns if t0 is None else t0
        times.append(stamp_to_str(scan.stamp_ns - t0))
        if with_gt:
            P = Tr @ scan.T_world_lidar @ Tr_inv
            poses.append(" ".join(repr(float(v)) for v in P[:3, :].reshape(-1)))
    tr_line = " ".join(f"{v:.12e}" for v in Tr[:3, :].reshape(-1))
    (out / "calib.txt").write_text("".join(f"P{i}: {_KITTI_P0}\n" for i in range(4)) + f"Tr: {tr_line}\n")
    (out / "times.txt").write_text("".join(t + "\n" for t in times))
    if with_gt:
        (out / "poses.txt").write_text("".join(p + "\n" for p in poses))
    return n
