"""PointCloud2 field layouts that real LiDAR drivers publish, and a builder for messages in any layout.

Used by the tests, the adapter benchmark and anything that needs a driver-shaped cloud (a player
imitating a Velodyne, say). The builder writes the bytes itself (structured numpy dtype with the
layout's offsets and byte order); it does not go through :func:`arrays_to_pointcloud2`, so tests of
the decoder against it are not circular. Padding bytes (inside a point and at the end of each row)
are filled with ``0xAB`` so a decoder that reads padding returns visible garbage.

A layout is ``(fields, point_step)`` where ``fields`` is a tuple of ``(name, offset, datatype,
count)`` with PointField datatype codes (1 INT8 ... 7 FLOAT32, 8 FLOAT64).
"""

from __future__ import annotations

import array
from collections.abc import Mapping
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from msg_adapters.pointcloud2 import DATATYPES

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
Layout = tuple[tuple[tuple[str, int, int, int], ...], int]

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


def _header(flavor: str, stamp_ns: int, frame_id: str):
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if flavor == "rclpy":
        from builtin_interfaces.msg import Time
        from std_msgs.msg import Header

        return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)
    from msg_adapters.pointcloud2_encode import typestore

    t = typestore().types
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)


def build_cloud(
    layout: Layout,
    values: Mapping[str, np.ndarray],
    *,
    height: int = 1,
    width: int | None = None,
    row_padding: int = 0,
    is_bigendian: bool = False,
    flavor: str = "rclpy",
    stamp_ns: int = 0,
    frame_id: str = "lidar",
) -> Any:
    """Build a PointCloud2 in ``layout`` from per-point ``values``.

    Args:
        layout: ``(fields, point_step)`` (e.g. :data:`OUSTER`).
        values: field name -> (N,) or (N, count) array, ``N = height * width`` in row-major order;
            fields left out are written as zeros.
        height, width: the cloud's shape (``width`` defaults to ``N // height``).
        row_padding: extra bytes at the end of each row (``row_step = width * point_step + row_padding``).
        is_bigendian: write every field big-endian and set the flag.
        flavor: ``"rclpy"`` or ``"rosbags"``.
    """
    fields, point_step = layout
    n = len(next(iter(values.values()))) if values else 0
    width = n // max(height, 1) if width is None else width
    n = height * width
    order = ">" if is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [DATATYPES[f[2]].newbyteorder(order) if f[3] == 1 else (DATATYPES[f[2]].newbyteorder(order),
                                                                                 (f[3],)) for f in fields],
            "offsets": [f[1] for f in fields],
            "itemsize": point_step,
        }
    )  # fmt: skip
    row_step = width * point_step + row_padding
    raw = np.full(row_step * height, 0xAB, dtype=np.uint8)
    rows = np.ndarray((height, width), dtype=dtype, buffer=raw, strides=(row_step, point_step))
    for name, offset, datatype, count in fields:
        del offset, datatype
        col = np.asarray(values[name]) if name in values else np.zeros((n, count) if count > 1 else n)
        if col.shape[0] != n:
            raise PointCloudFormatError(f"value {name!r} has {col.shape[0]} points, expected {n}")
        rows[name] = col.reshape((height, width) + rows[name].shape[2:])
    common = dict(
        height=height, width=width, is_bigendian=is_bigendian, point_step=point_step, row_step=row_step, is_dense=False
    )
    if flavor == "rclpy":
        from sensor_msgs.msg import PointCloud2, PointField

        msg = PointCloud2(
            header=_header(flavor, stamp_ns, frame_id),
            fields=[PointField(name=f[0], offset=f[1], datatype=f[2], count=f[3]) for f in fields],
            **common,
        )
        data = array.array("B")
        data.frombytes(memoryview(raw))
        msg.data = data
        return msg
    from msg_adapters.pointcloud2_encode import typestore

    t = typestore().types
    PointField = t["sensor_msgs/msg/PointField"]
    return t["sensor_msgs/msg/PointCloud2"](
        header=_header(flavor, stamp_ns, frame_id),
        fields=[PointField(name=f[0], offset=f[1], datatype=f[2], count=f[3]) for f in fields],
        data=raw,
        **common,
    )


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
