"""Prior map files: a point cloud (``.pcd`` or ``.ply``) in the map frame and, beside it, the trajectory of the
drive it was built from (same name, ``.tum`` suffix: ``timestamp x y z qx qy qz qw`` per line, the sensor's
pose ``T_map_sensor``), as ``deepbbs-bag map`` writes them and localization reads them.

Coordinates are written as float32 while every one is within :data:`FLOAT32_LIMIT` metres of the origin and
as float64 beyond (UTM coordinates of hundreds of kilometres would lose centimetres in float32).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deepbbs_ros.errors import DatasetError
from deepbbs_ros.reprs import short_repr

__all__ = ["MAP_SUFFIXES", "FLOAT32_LIMIT", "PriorMap", "read_map", "trajectory_path", "write_map"]

MAP_SUFFIXES = (".pcd", ".ply")
#: metres; farther coordinates are written as float64 (float32 steps are 1 mm at 8 km, 6 cm at 500 km)
FLOAT32_LIMIT = 8192.0


@dataclass
class PriorMap:
    """points: (N, 3) float64 metres, map frame. trajectory: (K, 4, 4) float64 ``T_map_sensor`` of the drive
    the map was built from, or None (no ``.tum`` beside the map). stamps_s: (K,) the trajectory's stamps."""

    __repr__ = short_repr

    path: Path
    points: np.ndarray
    trajectory: np.ndarray | None = None
    stamps_s: np.ndarray | None = None


def trajectory_path(map_path: Path | str) -> Path:
    """The trajectory file that goes with a map file: the same name with the ``.tum`` suffix."""
    return Path(map_path).with_suffix(".tum")


def _read_ply(path: Path) -> np.ndarray:
    import trimesh

    try:
        geom = trimesh.load(path, file_type="ply", process=False)
    except Exception as err:  # noqa: BLE001 - trimesh raises many kinds on a damaged file
        raise DatasetError(f"{path}: unreadable PLY file ({type(err).__name__}: {err})") from err
    vertices = getattr(geom, "vertices", None)
    if vertices is None:
        raise DatasetError(f"{path}: PLY file without vertices")
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 3)


def read_map(path: Path | str, *, trajectory: bool = True) -> PriorMap:
    """Read a map file (``.pcd``: ascii, binary or binary_compressed; ``.ply``: ascii or binary) and, when
    ``trajectory`` and a ``.tum`` file sits beside it, its trajectory.

    Raises:
        DatasetError: no such file, another suffix, unreadable or damaged file, no x y z, no finite point,
            an unreadable trajectory file.
    """
    path = Path(path)
    if path.suffix.lower() not in MAP_SUFFIXES:
        raise DatasetError(f"{path}: a map is a .pcd or .ply point cloud, not {path.suffix or 'a file without suffix'}")
    if not path.is_file():
        raise DatasetError(f"{path}: no such map file")
    if path.suffix.lower() == ".pcd":
        from deepbbs_ros.datasets.pcd import read_pcd

        arrays = read_pcd(path)
        if not all(k in arrays for k in "xyz"):
            raise DatasetError(f"{path}: PCD has no x y z fields (has {', '.join(arrays)})")
        pts = np.stack([arrays["x"], arrays["y"], arrays["z"]], axis=1).astype(np.float64)
    else:
        pts = _read_ply(path)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        raise DatasetError(f"{path}: the map holds no finite point")
    out = PriorMap(path, pts)
    tum = trajectory_path(path)
    if trajectory and tum.is_file():
        from deepbbs_ros.metrics import read_tum

        out.stamps_s, out.trajectory = read_tum(tum)
        if not len(out.trajectory):
            out.stamps_s = out.trajectory = None
    return out


def write_map(path: Path | str, points: np.ndarray, T_map_sensor: np.ndarray | None = None,
              stamps_ns: np.ndarray | None = None) -> list[Path]:
    """Write ``points`` (N, 3) metres as a binary PCD at ``path`` and, with ``T_map_sensor`` (K, 4, 4) and
    ``stamps_ns`` (K,) int, the trajectory beside it (:func:`trajectory_path`). Returns the files written.

    Raises:
        DatasetError: ``path`` is not a ``.pcd``, or a file cannot be written (the reason from the system).
    """
    from deepbbs_ros.datasets.pcd import write_pcd
    from deepbbs_ros.metrics import write_tum

    path = Path(path)
    if path.suffix.lower() != ".pcd":
        raise DatasetError(f"{path}: the map is written as a .pcd file (give a name ending in .pcd)")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    big = bool(len(pts)) and float(np.abs(pts).max()) > FLOAT32_LIMIT
    xyz = pts if big else pts.astype(np.float32)
    written = [path]
    try:
        write_pcd(path, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, encoding="binary")
        if T_map_sensor is not None:
            tum = trajectory_path(path)
            write_tum(tum, np.asarray(stamps_ns, dtype=np.int64), np.asarray(T_map_sensor, dtype=np.float64))
            written.append(tum)
    except OSError as err:
        raise DatasetError(f"cannot write the map {err.filename or path}: {err.strerror or err}") from err
    return written
