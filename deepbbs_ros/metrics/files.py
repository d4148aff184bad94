"""TUM and KITTI trajectory files (plain text that ``evo`` reads): writers that keep every float64, readers that make
each rotation one (:func:`~deepbbs_ros.metrics.pairs.nearest_rotation`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from deepbbs_ros.errors import DatasetError
from deepbbs_ros.metrics.pairs import project_pose
from deepbbs_ros.metrics.sequence import stack_poses


# --------------------------------------------------------------------------------------------------
# trajectory files (evo-compatible)
# --------------------------------------------------------------------------------------------------
def _matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # (..., 4) x y z w
    q = np.where(q[..., 3:4] < 0, -q, q)
    return q


def _quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def _num(v: float) -> str:
    """A float64 as the shortest text that reads back as the same float (``repr``: up to 17 digits)."""
    return repr(float(v))


def write_tum(
    path: str | Path, stamps_s: Sequence[float] | np.ndarray, T_world: Sequence[np.ndarray] | np.ndarray
) -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` per line (seconds, metres; unit quaternion, w >= 0).

    Every number is written in full (the shortest text that reads back as the same float64), so evo reads
    back the poses that were scored. ``stamps_s``: (N,) float seconds, or an integer array of nanoseconds
    (written exactly).
    """
    P = stack_poses(T_world, "write_tum") if len(T_world) else np.zeros((0, 4, 4))
    raw = np.asarray(stamps_s).ravel()
    if np.issubdtype(raw.dtype, np.integer):
        stamps = [f"{int(v) // 1_000_000_000}.{int(v) % 1_000_000_000:09d}" for v in raw]
    else:
        stamps = [_num(v) for v in raw.astype(np.float64)]
    if len(stamps) != P.shape[0]:
        raise ValueError(f"write_tum: {len(stamps)} stamps for {P.shape[0]} poses")
    with open(path, "w") as fh:
        if P.shape[0]:
            q = _matrix_to_quat_xyzw(P[:, :3, :3])
            for s, T, qq in zip(stamps, P, q):
                x, y, z = T[:3, 3]
                fh.write(" ".join([s, *(_num(v) for v in (x, y, z, *qq))]) + "\n")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory; returns ((N,) stamps s, (N, 4, 4) float64). ``#`` lines are comments.

    Quaternions are normalised on reading (the rotation of a quaternion of any norm).
    """
    stamps, poses = [], []
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DatasetError(f"cannot read TUM trajectory {path}: {err.strerror or err}") from err
    for lineno, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: TUM line must hold 8 numbers: {line!r}") from err
        if len(vals) != 8:
            raise DatasetError(f"{path}:{lineno}: TUM line must hold 8 numbers, got {len(vals)}")
        T = np.eye(4)
        q = np.asarray(vals[4:8])
        if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise DatasetError(f"{path}:{lineno}: invalid quaternion {vals[4:8]}")
        T[:3, :3] = _quat_xyzw_to_matrix(q / np.linalg.norm(q))
        T[:3, 3] = vals[1:4]
        stamps.append(vals[0])
        poses.append(T)
    return np.asarray(stamps, dtype=np.float64), np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)


def write_kitti(path: str | Path, T_world: Sequence[np.ndarray] | np.ndarray) -> None:
    """Write the first three rows of every pose, 12 numbers row-major per line, each in full (the shortest
    text that reads back as the same float64)."""
    P = stack_poses(T_world, "write_kitti") if len(T_world) else np.zeros((0, 4, 4))
    with open(path, "w") as fh:
        for T in P:
            fh.write(" ".join(_num(v) for v in T[:3, :].ravel()) + "\n")


def read_kitti(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file; returns (N, 4, 4) float64, each rotation block made a rotation
    (:func:`nearest_rotation`: a file with 6-7 digits per entry leaves it about 1e-6 off orthonormal)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DatasetError(f"cannot read KITTI trajectory {path}: {err.strerror or err}") from err
    poses = []
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            vals = [float(v) for v in line.split()]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: KITTI pose line must hold 12 numbers: {line.strip()!r}") from err
        if len(vals) != 12:
            raise DatasetError(f"{path}:{lineno}: KITTI pose line must hold 12 numbers, got {len(vals)}")
        if not np.isfinite(vals).all():
            raise DatasetError(f"{path}:{lineno}: KITTI pose line holds a non-finite number: {line.strip()!r}")
        T = np.eye(4)
        T[:3, :] = np.asarray(vals).reshape(3, 4)
        poses.append(T)
    return project_pose(np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4))
