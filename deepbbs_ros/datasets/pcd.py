"""PCD files (PCL's Point Cloud Data format, v0.7): ascii, binary and binary_compressed.

Apollo-SouthBay ships its scans as ``pcds/N.pcd`` with fields ``x y z intensity`` (float32, NaNs
possible). This module reads any PCD field layout (types F/I/U of size 1, 2, 4, 8, any COUNT,
padding fields named ``_``) and writes the three encodings. ``binary_compressed`` uses LZF
(liblzf's format, in pure Python in datasets/lzf.py, so no C extension is needed) over the data
stored field by field (all x, then all y, ...), as PCL does. The writer is in datasets/pcd_write.py, the
format's types and encodings in datasets/pcd_format.py (every name is imported from here too).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.base import check_scan_file, valid_mask
from deepbbs_ros.datasets.lzf import lzf_compress, lzf_decompress  # noqa: F401  (lzf_compress re-exported)
from deepbbs_ros.datasets.pcd_format import _ENCODINGS, _HEADER_KEYS, _TYPES
from deepbbs_ros.datasets.pcd_write import write_pcd  # noqa: F401  (re-exported)
from deepbbs_ros.errors import DatasetError


# --------------------------------------------------------------------------------------------- read
def _header_error(path: Path, lineno: int, msg: str) -> DatasetError:
    return DatasetError(f"{path}: line {lineno}: bad PCD header: {msg}")


def read_pcd(path: Path | str) -> dict[str, np.ndarray]:
    """Read a PCD file into one array per field.

    Returns:
        ``{name: array}`` in the file's field order, each ``(N,)`` (COUNT 1) or ``(N, COUNT)`` with
        the field's dtype (Apollo: ``x y z intensity`` float32). Organised clouds (HEIGHT > 1) come
        flattened, N = WIDTH * HEIGHT. Invalid points (NaN) are kept: the caller masks them.

    Raises:
        DatasetError: missing file, bad header (naming the line), unknown DATA encoding, truncated
            or corrupt data.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise DatasetError(f"{path}: cannot read PCD file: {err.strerror or err}") from None

    header: dict[str, list[str]] = {}
    lines: dict[str, int] = {}
    pos = 0
    lineno = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise _header_error(path, lineno + 1, "no DATA line (file ends inside the header)")
        lineno += 1
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise _header_error(path, lineno, "not ASCII text (is this a PCD file?)") from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        if key not in _HEADER_KEYS:
            raise _header_error(path, lineno, f"unknown keyword {key!r}")
        header[key] = values
        lines[key] = lineno
        if key == "DATA":
            break

    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH", "DATA"):
        if key not in header:
            raise _header_error(path, lineno, f"missing {key}")
    names = header["FIELDS"]
    nf = len(names)
    counts_s = header.get("COUNT", ["1"] * nf)
    for key, vals in (("SIZE", header["SIZE"]), ("TYPE", header["TYPE"]), ("COUNT", counts_s)):
        if len(vals) != nf:
            raise _header_error(path, lines.get(key, lineno), f"{key} has {len(vals)} entries, FIELDS has {nf}")
    try:
        sizes = [int(v) for v in header["SIZE"]]
        counts = [int(v) for v in counts_s]
        width = int(header["WIDTH"][0])
        height = int(header.get("HEIGHT", ["1"])[0])
        npoints = int(header["POINTS"][0]) if "POINTS" in header else width * height
    except (ValueError, IndexError):
        raise _header_error(path, lineno, "SIZE, COUNT, WIDTH, HEIGHT and POINTS must be integers") from None
    if npoints < 0 or width * height != npoints:
        raise _header_error(path, lines.get("POINTS", lineno), f"POINTS {npoints} != WIDTH*HEIGHT {width * height}")
    dtypes = []
    for name, t, s in zip(names, header["TYPE"], sizes):
        if (t, s) not in _TYPES:
            raise _header_error(path, lines["TYPE"], f"field {name!r} has unsupported TYPE {t} SIZE {s}")
        dtypes.append(np.dtype(_TYPES[(t, s)]).newbyteorder("<"))
    encoding = header["DATA"][0] if header["DATA"] else ""
    if encoding not in _ENCODINGS:
        raise _header_error(path, lines["DATA"], f"DATA {encoding!r} is not one of {', '.join(_ENCODINGS)}")

    body = raw[pos:]
    point_step = sum(s * c for s, c in zip(sizes, counts))
    out: dict[str, np.ndarray] = {}
    if encoding == "binary":
        need = npoints * point_step
        if len(body) < need:
            raise DatasetError(f"{path}: truncated binary PCD data: {len(body)} bytes, {need} expected")
        offset = 0
        rec = np.frombuffer(body, dtype=np.uint8, count=need).reshape(npoints, point_step)
        for name, dt, s, c in zip(names, dtypes, sizes, counts):
            block = np.ascontiguousarray(rec[:, offset : offset + s * c]).view(dt).reshape(npoints, c)
            offset += s * c
            if name != "_":
                out[name] = (block[:, 0] if c == 1 else block).astype(dt.newbyteorder("="))
    elif encoding == "binary_compressed":
        if len(body) < 8:
            raise DatasetError(f"{path}: truncated binary_compressed PCD data (no size words)")
        csize, usize = (int(v) for v in np.frombuffer(body[:8], dtype="<u4"))
        if len(body) - 8 < csize:
            raise DatasetError(f"{path}: truncated binary_compressed PCD data: {len(body) - 8} of {csize} bytes")
        if usize != npoints * point_step:
            raise DatasetError(f"{path}: binary_compressed size {usize} != POINTS*point size {npoints * point_step}")
        try:
            data = lzf_decompress(body[8 : 8 + csize], usize) if npoints else b""
        except ValueError as err:
            raise DatasetError(f"{path}: corrupt LZF data: {err}") from None
        offset = 0
        for name, dt, s, c in zip(names, dtypes, sizes, counts):
            nbytes = npoints * s * c
            block = np.frombuffer(data[offset : offset + nbytes], dtype=dt).reshape(npoints, c)
            offset += nbytes
            if name != "_":
                out[name] = (block[:, 0] if c == 1 else block).astype(dt.newbyteorder("="))
    else:  # ascii
        text = body.decode("ascii", errors="replace").split("\n")
        rows = [r.split() for r in text if r.strip()]
        ncols = sum(counts)
        if len(rows) < npoints:
            raise DatasetError(f"{path}: truncated ascii PCD data: {len(rows)} rows, POINTS says {npoints}")
        first_data_line = lineno + 1
        for k, r in enumerate(rows[:npoints]):
            if len(r) != ncols:
                raise DatasetError(
                    f"{path}: line {first_data_line + k}: {len(r)} values, {ncols} expected from FIELDS/COUNT"
                )
        try:
            table = np.array(rows[:npoints], dtype=np.float64).reshape(npoints, ncols)
        except ValueError:
            raise DatasetError(f"{path}: ascii PCD data holds a value that is not a number") from None
        col = 0
        for name, dt, c in zip(names, dtypes, counts):
            block = table[:, col : col + c]
            col += c
            if dt.kind in "iu":  # integers: parse exactly from the text, not through float64
                block = np.array([r[col - c : col] for r in rows[:npoints]], dtype=np.int64).reshape(npoints, c)
            arr = block.astype(dt.newbyteorder("="))
            if name != "_":
                out[name] = arr[:, 0] if c == 1 else arr
    return out


def read_pcd_points(path: Path | str, *, require_points: bool = False) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A PCD file as a point cloud: (xyz (N, 3) float32 metres, the other fields (N,)), rows with a
    non-finite coordinate dropped.

    Raises:
        DatasetError: unreadable file, or no ``x y z`` fields; with ``require_points``, also a file
            without a single finite point (a damaged scan).
    """
    arrays = read_pcd(path)
    if not all(k in arrays for k in "xyz"):
        raise DatasetError(f"{path}: PCD has no x y z fields (has {', '.join(arrays)})")
    xyz = np.stack([arrays.pop("x"), arrays.pop("y"), arrays.pop("z")], axis=1).astype(np.float32)
    keep = valid_mask(xyz)
    if require_points:
        check_scan_file(Path(path), len(xyz), int(keep.sum()))
    return xyz[keep], {k: v[keep] for k, v in arrays.items()}
