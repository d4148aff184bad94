"""A ``sensor_msgs/PointCloud2``'s byte layout: the PointField datatypes, the message's ``data`` as one uint8 buffer,
each field's dtype, offset and count, the checks of ``width``/``height``/``point_step``/``row_step`` against the
data, and the no-copy views that decoding (:mod:`msg_adapters.pointcloud2`) lays over the buffer."""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.errors import PointCloudFormatError

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
DATATYPE_OF: dict[np.dtype, int] = {dt: code for code, dt in DATATYPES.items()}
XYZ = ("x", "y", "z")


def buffer(msg: Any) -> np.ndarray:
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


def field_dtypes(msg: Any, byteorder: str) -> dict[str, tuple[np.dtype, int, int]]:
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


def check_layout(msg: Any, nbytes: int) -> tuple[int, int, int, int]:
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


def xyz_float32_view(
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


def take(column: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Compact (N,) raw-bytes column -> owned array of the kept points (boolean indexing of 1-D void
    items is several times faster than of a strided 2-D float array)."""
    return column[mask] if mask is not None else column.copy()


def typed(raw: np.ndarray, dtype: np.dtype, count: int) -> np.ndarray:
    """Compact raw-bytes items -> (N,) or (N, count) array of ``dtype`` in native byte order."""
    arr = raw.view(dtype)
    if count > 1:
        arr = arr.reshape(-1, count)
    return arr if arr.dtype.isnative else arr.astype(arr.dtype.newbyteorder("="))

