"""PointCloud2 field layouts that real LiDAR drivers publish, and a builder for messages in any layout.

Used by the tests, the adapter benchmark and anything that needs a driver-shaped cloud (a player
imitating a Velodyne, say). The builder writes the bytes itself (structured numpy dtype with the
layout's offsets and byte order); it does not go through :func:`arrays_to_pointcloud2`, so tests of
the decoder against it are not circular. Padding bytes (inside a point and at the end of each row)
are filled with ``0xAB`` so a decoder that reads padding returns visible garbage.

A layout is ``(fields, point_step)`` where ``fields`` is a tuple of ``(name, offset, datatype,
count)`` with PointField datatype codes (1 INT8 ... 7 FLOAT32, 8 FLOAT64). The builder: msg_adapters/cloud_builder.py
(imported from here too).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from msg_adapters.cloud_builder import Layout, _header, build_cloud  # noqa: F401  (re-exported)

__all__ = [
    "FLOAT64_XYZ",
    "HESAI",
    "LIVOX",
    "OUSTER",
    "VELODYNE",
    "Layout",
    "build_cloud",
    "driver_cloud",
    "recognise_driver",
]

INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

#: velodyne_pointcloud PointXYZIRT (ROS 2 driver): packed, point_step 22.
VELODYNE: Layout = (
    (("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("intensity", 12, FLOAT32, 1),
     ("ring", 16, UINT16, 1), ("time", 18, FLOAT32, 1)),
    22,
)  # fmt: skip
#: ouster-ros legacy PointOS (PCL EIGEN_ALIGN16): padding after z and at the end, point_step 48, organised.
OUSTER: Layout = (
    (("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("intensity", 16, FLOAT32, 1),
     ("t", 20, UINT32, 1), ("reflectivity", 24, UINT16, 1), ("ring", 26, UINT16, 1),
     ("ambient", 28, UINT16, 1), ("range", 32, UINT32, 1)),
    48,
)  # fmt: skip
#: livox_ros_driver2 PointCloud2 (xfer_format 0): float64 timestamp at unaligned offset 18, point_step 26.
LIVOX: Layout = (
    (("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("intensity", 12, FLOAT32, 1),
     ("tag", 16, UINT8, 1), ("line", 17, UINT8, 1), ("timestamp", 18, FLOAT64, 1)),
    26,
)  # fmt: skip
#: HesaiLidar_ROS_2.0: ring uint16 and float64 timestamp (unaligned), point_step 26.
HESAI: Layout = (
    (("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1), ("z", 8, FLOAT32, 1), ("intensity", 12, FLOAT32, 1),
     ("ring", 16, UINT16, 1), ("timestamp", 18, FLOAT64, 1)),
    26,
)  # fmt: skip
#: double-precision coordinates (survey / mapping tools), point_step 32 with 4 padding bytes.
FLOAT64_XYZ: Layout = (
    (("x", 0, FLOAT64, 1), ("y", 8, FLOAT64, 1), ("z", 16, FLOAT64, 1), ("intensity", 24, FLOAT32, 1)),
    32,
)  # fmt: skip


#: per-point field names that only one driver family writes -> its name (first match wins)
_DRIVER_FIELDS: tuple[tuple[frozenset[str], str], ...] = (
    (frozenset({"tag", "line"}), "livox"),  # livox_ros_driver(2): tag, line, float64 timestamp
    (frozenset({"t", "reflectivity"}), "ouster"),  # ouster-ros: t (ns), reflectivity, ring, ambient / near_ir, range
    (frozenset({"ring", "time"}), "velodyne"),  # velodyne_pointcloud PointXYZIRT: float32 time (s), ring
    (frozenset({"ring", "timestamp"}), "hesai"),  # HesaiLidar_ROS_2.0 (rslidar_sdk XYZIRT writes the same fields)
)


def recognise_driver(fields: Any) -> str | None:
    """The driver family that wrote a PointCloud2, from its field names: ``"livox"``, ``"ouster"``,
    ``"velodyne"``, ``"hesai"`` (also RoboSense's rslidar_sdk, whose XYZIRT layout is the same), or None.

    Args:
        fields: the message's field names (``msg_adapters.pointcloud2.field_names(msg)``), a message's
            ``fields`` (PointField objects) or a :data:`Layout`.
    """
    if isinstance(fields, tuple) and len(fields) == 2 and isinstance(fields[1], int):  # a Layout
        fields = fields[0]
    names = {f if isinstance(f, str) else f[0] if isinstance(f, tuple) else str(f.name) for f in fields}
    return next((driver for need, driver in _DRIVER_FIELDS if need <= names), None)


def driver_cloud(
    driver: str,
    xyz: np.ndarray,
    fields: Mapping[str, np.ndarray],
    *,
    beams: int = 0,
    columns: int = 0,
    flavor: str = "rclpy",
    stamp_ns: int = 0,
    frame_id: str = "lidar",
) -> Any:
    """A scan as the driver ``driver`` publishes it: ``"velodyne"`` (:data:`VELODYNE`, unorganised, in
    the given order), ``"ouster"`` (:data:`OUSTER`, organised ``beams`` x ``columns``, row 0 = the top
    beam as ouster-ros writes it, no return = zeros, ``t`` in ns), ``"livox"`` (:data:`LIVOX`) or
    ``"hesai"`` (:data:`HESAI`), both unorganised in the given order.

    Args:
        xyz: (N, 3) float32 points, sensor frame, metres.
        fields: ``intensity`` (N,), ``time`` (N,) seconds since the stamp, ``ring`` (N,) (0 = lowest beam),
            and for Ouster ``column`` (N,) (the simulator's :class:`~deepbbs_ros.datasets.base.Scan` fields;
            Ouster also takes ``t`` in ns instead of ``time``). Livox: ``line``, ``timestamp`` (float64 ns,
            absolute) and optionally ``tag``; Hesai: ``ring`` and ``timestamp`` (float64 s, absolute).
    """
    f = fields
    if driver in ("livox", "hesai"):
        if "timestamp" not in f:
            raise PointCloudFormatError(f"the {driver} layout needs a 'timestamp' field")
        values = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": f["intensity"],
                  "timestamp": f["timestamp"]}  # fmt: skip
        if driver == "livox":
            values.update(line=f["line"], tag=f.get("tag", np.zeros(len(xyz), np.uint8)))
        else:
            values["ring"] = f["ring"]
        return build_cloud(LIVOX if driver == "livox" else HESAI, values, flavor=flavor, stamp_ns=stamp_ns,
                           frame_id=frame_id)
    if driver == "velodyne":
        values = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": f["intensity"],
                  "ring": f["ring"], "time": f["time"]}  # fmt: skip
        return build_cloud(VELODYNE, values, flavor=flavor, stamp_ns=stamp_ns, frame_id=frame_id)
    if driver != "ouster":
        raise PointCloudFormatError(
            f"unknown driver layout {driver!r}; choose 'velodyne', 'ouster', 'livox' or 'hesai'")
    if "column" not in f or beams < 1 or columns < 1:
        raise PointCloudFormatError("the Ouster layout needs a 'column' field and the beams x columns shape")
    h, w = int(beams), int(columns)
    row = (h - 1 - np.asarray(f["ring"]).astype(np.int64)) * w + np.asarray(f["column"]).astype(np.int64)
    grid = {n: np.zeros(h * w, dtype) for n, dtype in (("x", np.float32), ("y", np.float32), ("z", np.float32),
            ("intensity", np.float32), ("t", np.uint32), ("reflectivity", np.uint16), ("ring", np.uint16),
            ("ambient", np.uint16), ("range", np.uint32))}  # fmt: skip
    for i, n in enumerate("xyz"):
        grid[n][row] = xyz[:, i]
    grid["intensity"][row] = f["intensity"]
    grid["reflectivity"][row] = np.clip(f["intensity"], 0, 255).astype(np.uint16)
    grid["t"][row] = np.asarray(f["t"], np.uint32) if "t" in f else \
        np.round(np.asarray(f["time"], dtype=np.float64) * 1e9).astype(np.uint32)
    grid["ring"] = np.repeat(np.arange(h, dtype=np.uint16), w)
    grid["range"][row] = np.round(np.linalg.norm(xyz, axis=1) * 1000.0).astype(np.uint32)
    return build_cloud(OUSTER, grid, height=h, width=w, flavor=flavor, stamp_ns=stamp_ns, frame_id=frame_id)
