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
"""

from __future__ import annotations

import array
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError
from deepbbs_ros.reprs import short_repr
from msg_adapters.transforms import time_to_ns

__all__ = [
    "CloudArrays",
    "DATATYPES",
    "arrays_to_pointcloud2",
    "field_names",
    "pointcloud2_to_arrays",
    "pointcloud2_to_xyz",
]

#: ``sensor_msgs/PointField`` datatype constant -> numpy dtype (native byte order).
DATATYPES: dict[int, np.dtype] = {
    1: np.dtype(np.int8),  # INT8
    2: np.dtype(np.uint8),  # UINT8
    3: np.dtype(np.int16),  # INT16
    4: np.dtype(np.uint16),  # UINT16
    5: np.dtype(np.int32),  # INT32
    6: np.dtype(np.uint32),  # UINT32
    7: np.dtype(np.float32),  # FLOAT32
    8: np.dtype(np.float64),  # FLOAT64
}
_DATATYPE_OF: dict[np.dtype, int] = {dt: code for code, dt in DATATYPES.items()}
_XYZ = ("x", "y", "z")
_FLAVORS = ("rclpy", "rosbags")


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


def _buffer(msg: Any) -> np.ndarray:
    """The message's ``data`` as a 1-D uint8 array, without copying when the buffer allows it."""
    data = msg.data
    if isinstance(data, np.ndarray):
        buf = data.reshape(-1)
        if buf.dtype != np.uint8:
            buf = buf.view(np.uint8) if buf.flags.c_contiguous else np.ascontiguousarray(buf).view(np.uint8)
        return buf
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError):  # a list of ints (e.g. a message built by hand)
        try:
            return np.asarray(data, dtype=np.uint8).reshape(-1)
        except (TypeError, ValueError, OverflowError) as err:
            raise PointCloudFormatError(f"PointCloud2 data is not a byte buffer ({type(data).__name__})") from err


def _field_dtypes(msg: Any, byteorder: str) -> dict[str, tuple[np.dtype, int, int]]:
    """Validate every declared field; return name -> (dtype, offset, count)."""
    point_step = int(msg.point_step)
    out: dict[str, tuple[np.dtype, int, int]] = {}
    for f in msg.fields:
        name = str(f.name)
        datatype, offset, count = int(f.datatype), int(f.offset), int(f.count)
        if datatype not in DATATYPES:
            raise PointCloudFormatError(
                f"PointCloud2 field {name!r} has unknown datatype {datatype} (expected 1..8, INT8..FLOAT64)"
            )
        if name in out:
            raise PointCloudFormatError(f"PointCloud2 declares field {name!r} twice")
        count = max(count, 1)  # count 0 is written by some tools; it means one element
        dtype = DATATYPES[datatype].newbyteorder(byteorder)
        end = offset + dtype.itemsize * count
        if offset < 0 or end > point_step:
            raise PointCloudFormatError(
                f"PointCloud2 field {name!r} (offset {offset}, {count} x {dtype.itemsize} bytes) "
                f"runs past point_step {point_step}"
            )
        out[name] = (dtype, offset, count)
    return out


def _check_layout(msg: Any, nbytes: int) -> tuple[int, int, int, int]:
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    npoints = height * width
    if npoints == 0:
        if nbytes:
            raise PointCloudFormatError(
                f"PointCloud2 width*height mismatch: width {width} x height {height} = 0 points "
                f"but data holds {nbytes} bytes"
            )
        return height, width, point_step, row_step
    if point_step <= 0:
        raise PointCloudFormatError(f"PointCloud2 point_step is {point_step} for {npoints} points")
    if row_step < width * point_step:
        raise PointCloudFormatError(
            f"PointCloud2 row_step {row_step} < width*point_step = {width}*{point_step} = {width * point_step}"
        )
    if nbytes != row_step * height:
        detail = ""
        if row_step and nbytes % row_step == 0:
            detail = f"; the data holds {nbytes // row_step} rows, so width*height does not match the data"
        raise PointCloudFormatError(
            f"PointCloud2 data length {nbytes} != row_step*height = {row_step}*{height} = {row_step * height} "
            f"(width {width}, point_step {point_step}){detail}"
        )
    return height, width, point_step, row_step


def _xyz_float32_view(
    buf: np.ndarray, specs: dict[str, tuple[np.dtype, int, int]], height: int, width: int, point_step: int,
    row_step: int,
) -> np.ndarray | None:  # fmt: skip
    """(H, W, 3) float32 view of the buffer when x, y, z are consecutive, native, aligned float32; else None."""
    (dx, ox, _), (dy, oy, _), (dz, oz, _) = specs["x"], specs["y"], specs["z"]
    f4 = np.dtype(np.float32)
    if not (dx == dy == dz == f4 and oy == ox + 4 and oz == ox + 8):
        return None
    if ox % 4 or point_step % 4 or row_step % 4 or buf.ctypes.data % 4:
        return None
    return np.ndarray(shape=(height, width, 3), dtype=f4, buffer=buf, offset=ox, strides=(row_step, point_step, 4))


def _take(column: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Compact (N,) raw-bytes column -> owned array of the kept points (boolean indexing of 1-D void
    items is several times faster than of a strided 2-D float array)."""
    return column[mask] if mask is not None else column.copy()


def _typed(raw: np.ndarray, dtype: np.dtype, count: int) -> np.ndarray:
    """Compact raw-bytes items -> (N,) or (N, count) array of ``dtype`` in native byte order."""
    arr = raw.view(dtype)
    if count > 1:
        arr = arr.reshape(-1, count)
    return arr if arr.dtype.isnative else arr.astype(arr.dtype.newbyteorder("="))


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
    specs = _field_dtypes(msg, byteorder)
    missing_xyz = [n for n in _XYZ if n not in specs]
    if missing_xyz:
        raise PointCloudFormatError(
            f"PointCloud2 has no {'/'.join(missing_xyz)} field (fields: {', '.join(specs) or 'none'})"
        )
    for n in _XYZ:
        if specs[n][2] != 1:
            raise PointCloudFormatError(f"PointCloud2 coordinate field {n!r} has count {specs[n][2]}; expected 1")
    wanted = list(dict.fromkeys(str(n) for n in fields))
    missing = [n for n in wanted if n not in specs]
    if missing:
        raise PointCloudFormatError(
            f"PointCloud2 has no field {', '.join(map(repr, missing))} (fields: {', '.join(specs)})"
        )
    buf = _buffer(msg)
    height, width, point_step, row_step = _check_layout(msg, buf.size)
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
    names = list(dict.fromkeys([*_XYZ, *wanted]))
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
    xyz_view = _xyz_float32_view(buf, specs, height, width, point_step, row_step)
    if xyz_view is not None:
        xyz_all = xyz_view.reshape(npoints, 3)
    else:
        xyz_all = np.empty((npoints, 3), np.float32)
        for i, n in enumerate(_XYZ):
            xyz_all[:, i] = _typed(rec[n].copy(), specs[n][0], 1)

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
        xyz = _take(xyz_bytes, mask).view(np.float32).reshape(-1, 3)
    elif mask is not None:  # xyz_all is a compact copy here
        xyz = xyz_all.view(v12).reshape(npoints)[mask].view(np.float32).reshape(-1, 3)
    else:
        xyz = np.ascontiguousarray(xyz_all)
    out_fields = {n: _typed(_take(rec[n], mask), specs[n][0], specs[n][2]) for n in wanted}
    kept = mask if mask is not None else np.ones(npoints, dtype=bool)
    return CloudArrays(xyz, out_fields, stamp_ns, frame_id, height, width, kept)


def pointcloud2_to_xyz(msg: Any) -> np.ndarray:
    """Valid points of a PointCloud2 as (N, 3) float32 (finite, ``||p|| >= 1e-3`` m), message frame."""
    return pointcloud2_to_arrays(msg).xyz


# --------------------------------------------------------------------------------------------------
# encoding
# --------------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1)
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _as_field_array(name: str, value: Any, lead_shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    if arr.dtype.newbyteorder("=") not in _DATATYPE_OF:
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
    if flavor not in _FLAVORS:
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
        if name in _XYZ:
            raise PointCloudFormatError(f"field {name!r} collides with the coordinates x/y/z")
        extra[str(name)] = _as_field_array(name, value, lead)

    # packed layout: x y z, then each field in the order given
    names, formats, offsets, pfields = [], [], [], []
    offset = 0
    for n in _XYZ:
        names.append(n)
        formats.append(xyz_dt.newbyteorder("<"))
        offsets.append(offset)
        pfields.append((n, offset, _DATATYPE_OF[xyz_dt], 1))
        offset += xyz_dt.itemsize
    for n, arr in extra.items():
        base = arr.dtype.newbyteorder("=")
        count = 1 if arr.ndim == len(lead) else int(arr.shape[-1])
        names.append(n)
        formats.append(base.newbyteorder("<") if count == 1 else (base.newbyteorder("<"), (count,)))
        offsets.append(offset)
        pfields.append((n, offset, _DATATYPE_OF[base], count))
        offset += base.itemsize * count
    point_step = offset
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    npoints = height * width
    rec = np.empty(npoints, dtype=dtype)
    flat_xyz = xyz.reshape(npoints, 3)
    for i, n in enumerate(_XYZ):
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
    ts = _typestore()
    Time = ts.types["builtin_interfaces/msg/Time"]
    Header = ts.types["std_msgs/msg/Header"]
    PointField = ts.types["sensor_msgs/msg/PointField"]
    PointCloud2 = ts.types["sensor_msgs/msg/PointCloud2"]
    return PointCloud2(
        **_cloud_kwargs(Time, Header, PointField, pfields, height, width, point_step, stamp_ns, frame_id, is_dense),
        data=np.frombuffer(memoryview(raw), dtype=np.uint8),  # the packed buffer itself, no extra copy
    )
