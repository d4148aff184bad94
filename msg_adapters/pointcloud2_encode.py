"""numpy -> ``sensor_msgs/PointCloud2`` (packed little-endian layout, x y z first), as an rclpy message or a
rosbags one (for writing bags); each flavour's message types are imported only when one is built."""

from __future__ import annotations

import array
import functools
from collections.abc import Mapping
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from msg_adapters.pointcloud2_layout import DATATYPE_OF, XYZ

FLAVORS = ("rclpy", "rosbags")


@functools.lru_cache(maxsize=1)
def typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _as_field_array(name: str, value: Any, lead_shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    if arr.dtype.newbyteorder("=") not in DATATYPE_OF:
        raise PointCloudFormatError(
            f"field {name!r} has dtype {arr.dtype}, which PointCloud2 cannot hold "
            "(int8/uint8/int16/uint16/int32/uint32/float32/float64)"
        )
    nlead = len(lead_shape)
    if arr.shape[:nlead] != lead_shape or arr.ndim > nlead + 1:
        raise PointCloudFormatError(
            f"field {name!r} has shape {arr.shape}; expected {lead_shape} or {lead_shape} + (count,)"
        )
    return arr


def arrays_to_pointcloud2(
    xyz: np.ndarray,
    fields: Mapping[str, np.ndarray] | None = None,
    *,
    stamp_ns: int = 0,
    frame_id: str = "",
    flavor: str = "rclpy",
    xyz_dtype: Any = np.float32,
) -> Any:
    """Encode numpy arrays as a PointCloud2 (packed little-endian layout, x y z first).

    Args:
        xyz: (N, 3) points, or (H, W, 3) for an organised cloud (``height=H``, ``width=W``).
        fields: extra per-point fields, each (N,) / (N, count) (or (H, W) / (H, W, count)); the
            PointField datatype follows the array's dtype (bool is written as UINT8).
        stamp_ns: ``header.stamp`` in nanoseconds. frame_id: ``header.frame_id``.
        flavor: ``"rclpy"`` (``sensor_msgs.msg.PointCloud2``) or ``"rosbags"`` (typestore
            ROS2_JAZZY ``sensor_msgs__msg__PointCloud2``, for writing bags).
        xyz_dtype: ``np.float32`` (default) or ``np.float64`` coordinates.

    Returns:
        The message; ``data`` is filled from a memoryview of one contiguous buffer.
    """
    if flavor not in FLAVORS:
        raise PointCloudFormatError(f"unknown message flavor {flavor!r} (expected 'rclpy' or 'rosbags')")
    xyz = np.asarray(xyz)
    if xyz.ndim not in (2, 3) or xyz.shape[-1] != 3:
        raise PointCloudFormatError(f"xyz has shape {xyz.shape}; expected (N, 3) or (H, W, 3)")
    xyz_dt = np.dtype(xyz_dtype)
    if xyz_dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise PointCloudFormatError(f"xyz_dtype must be float32 or float64, not {xyz_dt}")
    lead = xyz.shape[:-1]
    height, width = (1, lead[0]) if xyz.ndim == 2 else lead
    extra = {}
    for name, value in (fields or {}).items():
        if name in XYZ:
            raise PointCloudFormatError(f"field {name!r} collides with the coordinates x/y/z")
        extra[str(name)] = _as_field_array(name, value, lead)

    # packed layout: x y z, then each field in the order given
    names, formats, offsets, pfields = [], [], [], []
    offset = 0
    for n in XYZ:
        names.append(n)
        formats.append(xyz_dt.newbyteorder("<"))
        offsets.append(offset)
        pfields.append((n, offset, DATATYPE_OF[xyz_dt], 1))
        offset += xyz_dt.itemsize
    for n, arr in extra.items():
        base = arr.dtype.newbyteorder("=")
        count = 1 if arr.ndim == len(lead) else int(arr.shape[-1])
        names.append(n)
        formats.append(base.newbyteorder("<") if count == 1 else (base.newbyteorder("<"), (count,)))
        offsets.append(offset)
        pfields.append((n, offset, DATATYPE_OF[base], count))
        offset += base.itemsize * count
    point_step = offset
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    npoints = height * width
    rec = np.empty(npoints, dtype=dtype)
    flat_xyz = xyz.reshape(npoints, 3)
    for i, n in enumerate(XYZ):
        rec[n] = flat_xyz[:, i]
    for n, arr in extra.items():
        rec[n] = arr.reshape((npoints,) + arr.shape[len(lead) :])
    raw = rec.view(np.uint8).reshape(-1)
    is_dense = bool(np.isfinite(flat_xyz).all())

    if flavor == "rclpy":
        return _rclpy_cloud(raw, pfields, height, width, point_step, stamp_ns, frame_id, is_dense)
    return _rosbags_cloud(raw, pfields, height, width, point_step, stamp_ns, frame_id, is_dense)


def _split_ns(stamp_ns: int) -> tuple[int, int]:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if not -(2**31) <= sec < 2**31:
        raise PointCloudFormatError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return sec, nanosec


def _cloud_kwargs(Time, Header, PointField, pfields, height, width, point_step, stamp_ns, frame_id, is_dense) -> dict:
    """Every PointCloud2 field but ``data``, built from either flavour's Time, Header and PointField types."""
    sec, nanosec = _split_ns(stamp_ns)
    return dict(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=str(frame_id)),
        height=int(height),
        width=int(width),
        fields=[PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in pfields],
        is_bigendian=False,
        point_step=int(point_step),
        row_step=int(point_step * width),
        is_dense=is_dense,
    )


def _rclpy_cloud(raw, pfields, height, width, point_step, stamp_ns, frame_id, is_dense):
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    kwargs = _cloud_kwargs(Time, Header, PointField, pfields, height, width, point_step, stamp_ns, frame_id, is_dense)
    try:
        # Jazzy: with field checks on, the data setter keeps an array.array('B') as is (off, it copies it)
        msg = PointCloud2(check_fields=True, **kwargs)
    except (AssertionError, TypeError):  # older generators have no check_fields (and always check)
        msg = PointCloud2(**kwargs)
    # fast path: one memcpy from a memoryview of the contiguous buffer into an array.array('B')
    data = array.array("B")
    data.frombytes(memoryview(raw))
    msg.data = data
    return msg


def _rosbags_cloud(raw, pfields, height, width, point_step, stamp_ns, frame_id, is_dense):
    ts = typestore()
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    PointField = ts.types["sensor_msgs/msg/PointField"]
    PointCloud2 = ts.types["sensor_msgs/msg/PointCloud2"]
    return PointCloud2(
        **_cloud_kwargs(Time, Header, PointField, pfields, height, width, point_step, stamp_ns, frame_id, is_dense),
        data=np.frombuffer(memoryview(raw), dtype=np.uint8),  # the packed buffer itself, no extra copy
    )
