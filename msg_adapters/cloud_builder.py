"""A PointCloud2 built in any field layout (:func:`build_cloud`, rclpy or rosbags), its bytes written through a
structured numpy dtype with the layout's offsets and byte order, padding filled with ``0xAB`` (not through
:func:`arrays_to_pointcloud2`, so tests of the decoder against it are not circular). The layouts real drivers
publish: msg_adapters/layouts.py."""

from __future__ import annotations

import array
from collections.abc import Mapping
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from msg_adapters.pointcloud2 import DATATYPES

Layout = tuple[tuple[tuple[str, int, int, int], ...], int]  # (fields (name, offset, datatype, count), point_step)


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
