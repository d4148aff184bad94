"""``sensor_msgs/PointCloud2`` <-> numpy, for rclpy messages and rosbags-deserialized messages.

Decoding builds one structured numpy dtype from the message's fields (offsets, datatypes, ``count``,
byte order, ``itemsize = point_step``) and lays it over the raw buffer with
``strides = (row_step, point_step)``: no copy of the buffer, row padding skipped, organised clouds
(``height > 1``) read row-major as ``(height, width)`` and flattened to ``N = height * width``.
One validity mask (finite xyz and ``||p|| >= min_range``) is applied to xyz and to every requested
field, so per-point arrays always stay aligned.

The two message flavours are duck-typed: both carry the same field names; rclpy holds ``data`` as an
``array.array('B')``, rosbags as a ``numpy`` ``uint8`` array; both expose the buffer protocol.

Nothing here imports rclpy or rosbags at module level; encoding imports the flavour it builds.

Modules: this one decodes (:func:`pointcloud2_to_arrays`); :mod:`msg_adapters.pointcloud2_layout` holds the datatypes
and the buffer's layout and checks, :mod:`msg_adapters.pointcloud2_encode` encodes (:func:`arrays_to_pointcloud2`,
imported from here too).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from deepbbs_ros.reprs import short_repr
from msg_adapters.pointcloud2_encode import arrays_to_pointcloud2
from msg_adapters.pointcloud2_layout import (
    DATATYPES,
    XYZ,
    buffer,
    check_layout,
    field_dtypes,
    take,
    typed,
    xyz_float32_view,
)
from msg_adapters.transforms import time_to_ns

__all__ = [
    "CloudArrays",
    "DATATYPES",
    "arrays_to_pointcloud2",
    "field_names",
    "pointcloud2_to_arrays",
    "pointcloud2_to_xyz",
]


@dataclass
class CloudArrays:
    """A decoded PointCloud2.

    Attributes:
        xyz: (N, 3) float32 point coordinates in the message's ``frame_id``, metres.
        fields: requested per-point fields by name, each (N,) or (N, count) in the field's own
            dtype (native byte order), masked exactly like ``xyz``.
        stamp_ns: ``header.stamp`` in nanoseconds.
        frame_id: ``header.frame_id``.
        height, width: the message's layout; with ``remove_invalid=False`` an organised cloud's
            arrays reshape to ``(height, width, ...)`` row-major.
        mask: (height * width,) bool, which raw points were kept (all True when nothing was removed).
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    xyz: np.ndarray
    fields: dict[str, np.ndarray]
    stamp_ns: int
    frame_id: str
    height: int = 1
    width: int = 0
    mask: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])


# --------------------------------------------------------------------------------------------------
# decoding
# --------------------------------------------------------------------------------------------------


def field_names(msg: Any) -> list[str]:
    """Names of the fields a PointCloud2 message declares, in message order."""
    return [str(f.name) for f in msg.fields]


def _stamp_ns(header: Any) -> int:
    """``header.stamp`` in ns; PointCloudFormatError for a stamp that does not fit builtin_interfaces/Time
    (``sec`` outside int32, ``nanosec`` >= 1e9): the outputs could not carry it."""
    stamp = header.stamp
    return time_to_ns(stamp.sec, stamp.nanosec, PointCloudFormatError)


def pointcloud2_to_arrays(
    msg: Any, fields: Sequence[str] = (), *, remove_invalid: bool = True, min_range: float = 1e-3
) -> CloudArrays:
    """Decode a PointCloud2 (rclpy or rosbags flavour) to numpy.

    Args:
        msg: ``sensor_msgs/PointCloud2`` with any field layout: offsets, datatypes INT8..FLOAT64,
            ``count >= 1``, ``point_step``/``row_step`` padding, ``is_bigendian``, ``height >= 1``.
        fields: extra per-point fields to return by name (e.g. ``("intensity", "time", "ring")``).
        remove_invalid: drop points whose xyz is NaN/Inf or within ``min_range`` of the origin (the
            same mask is applied to every returned array). With False every raw point is kept.
        min_range: metres; ``<= 0`` keeps near-origin points (non-finite ones are still dropped).

    Returns:
        :class:`CloudArrays` with ``xyz`` (N, 3) float32 and the requested ``fields``. Organised
        clouds are flattened row-major: raw point ``(row, col)`` is index ``row * width + col``.

    Raises:
        PointCloudFormatError: no x/y/z field, a requested field missing, an unknown datatype, a
            field past ``point_step``, ``row_step < width * point_step``, ``len(data) !=
            row_step * height``, ``width * height`` not matching the data, or a ``header.stamp`` that
            does not fit ``builtin_interfaces/Time`` (``sec`` outside int32, ``nanosec >= 1e9``).
    """
    byteorder = ">" if bool(msg.is_bigendian) else "<"
    specs = field_dtypes(msg, byteorder)
    missing_xyz = [n for n in XYZ if n not in specs]
    if missing_xyz:
        raise PointCloudFormatError(
            f"PointCloud2 has no {'/'.join(missing_xyz)} field (fields: {', '.join(specs) or 'none'})"
        )
    for n in XYZ:
        if specs[n][2] != 1:
            raise PointCloudFormatError(f"PointCloud2 coordinate field {n!r} has count {specs[n][2]}; expected 1")
    wanted = list(dict.fromkeys(str(n) for n in fields))
    missing = [n for n in wanted if n not in specs]
    if missing:
        raise PointCloudFormatError(
            f"PointCloud2 has no field {', '.join(map(repr, missing))} (fields: {', '.join(specs)})"
        )
    buf = buffer(msg)
    height, width, point_step, row_step = check_layout(msg, buf.size)
    header = msg.header
    stamp_ns, frame_id = _stamp_ns(header), str(header.frame_id)
    npoints = height * width

    if npoints == 0:
        out_fields = {}
        for n in wanted:
            dtype, _, count = specs[n]
            shape = (0,) if count == 1 else (0, count)
            out_fields[n] = np.empty(shape, dtype=dtype.newbyteorder("="))
        return CloudArrays(
            np.empty((0, 3), np.float32), out_fields, stamp_ns, frame_id, height, width, np.zeros(0, bool)
        )

    # one structured dtype over the buffer: each field as raw bytes at its offset, itemsize point_step,
    # strides (row_step, point_step); a view, no copy. Typing/byte order are applied after compaction.
    names = list(dict.fromkeys([*XYZ, *wanted]))
    raw_dtype = np.dtype(
        {
            "names": names,
            "formats": [np.dtype(f"V{specs[n][0].itemsize * specs[n][2]}") for n in names],
            "offsets": [specs[n][1] for n in names],
            "itemsize": point_step,
        }
    )
    rec = np.ndarray(shape=(height, width), dtype=raw_dtype, buffer=buf, strides=(row_step, point_step))
    rec = rec.reshape(npoints)  # a view unless rows are padded (then one compact copy)

    # xyz as float32 for the validity test: a strided view in the common layout, else converted
    xyz_view = xyz_float32_view(buf, specs, height, width, point_step, row_step)
    if xyz_view is not None:
        xyz_all = xyz_view.reshape(npoints, 3)
    else:
        xyz_all = np.empty((npoints, 3), np.float32)
        for i, n in enumerate(XYZ):
            xyz_all[:, i] = typed(rec[n].copy(), specs[n][0], 1)

    # one validity mask: finite and at least min_range from the sensor (NaN/Inf propagate into |p|^2)
    mask = None
    if remove_invalid:
        with np.errstate(invalid="ignore", over="ignore"):
            x, y, z = xyz_all[:, 0], xyz_all[:, 1], xyz_all[:, 2]
            sq = x * x
            sq += y * y
            sq += z * z
            mask = np.isfinite(sq)
            if min_range > 0:
                mask &= sq >= np.float32(min_range) ** 2
        if mask.all():
            mask = None

    # outputs own their memory (C-contiguous, native byte order): never views into the message buffer
    v12 = np.dtype("V12")
    if xyz_view is not None and row_step == width * point_step:  # strided 12-byte items in the buffer
        xyz_bytes = np.ndarray((npoints,), v12, buffer=buf, offset=specs["x"][1], strides=(point_step,))
        xyz = take(xyz_bytes, mask).view(np.float32).reshape(-1, 3)
    elif mask is not None:  # xyz_all is a compact copy here
        xyz = xyz_all.view(v12).reshape(npoints)[mask].view(np.float32).reshape(-1, 3)
    else:
        xyz = np.ascontiguousarray(xyz_all)
    out_fields = {n: typed(take(rec[n], mask), specs[n][0], specs[n][2]) for n in wanted}
    kept = mask if mask is not None else np.ones(npoints, dtype=bool)
    return CloudArrays(xyz, out_fields, stamp_ns, frame_id, height, width, kept)


def pointcloud2_to_xyz(msg: Any) -> np.ndarray:
    """Valid points of a PointCloud2 as (N, 3) float32 (finite, ``||p|| >= 1e-3`` m), message frame."""
    return pointcloud2_to_arrays(msg).xyz

