"""Writing PCD v0.7 files (ascii, binary, binary_compressed with LZF over the data stored field by field, as PCL
does): :func:`write_pcd`. Reading them: datasets/pcd.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros.datasets.lzf import lzf_compress
from deepbbs_ros.datasets.pcd_format import _ENCODINGS, _TYPES
from deepbbs_ros.errors import DatasetError


def _pcd_type(dtype: np.dtype) -> tuple[str, int]:
    dtype = np.dtype(dtype)
    kind = {"f": "F", "i": "I", "u": "U", "b": "U"}.get(dtype.kind)
    if kind is None or (kind, dtype.itemsize) not in _TYPES:
        raise DatasetError(f"cannot write dtype {dtype} to PCD")
    return kind, dtype.itemsize


def write_pcd(path: Path | str, arrays: dict[str, np.ndarray], encoding: str = "binary") -> None:
    """Write a PCD v0.7 file.

    Args:
        path: output file.
        arrays: ``{name: (N,) or (N, count) array}``; ``x``, ``y``, ``z`` first when present. A
            ``points``/``xyz`` entry of shape (N, 3) is written as fields ``x y z``.
            Apollo layout: ``{"points": (N, 3) float32, "intensity": (N,) float32}``.
        encoding: ``"binary"`` (default), ``"ascii"`` or ``"binary_compressed"`` (LZF).
    """
    path = Path(path)
    if encoding not in _ENCODINGS:
        raise DatasetError(f"PCD encoding must be one of {', '.join(_ENCODINGS)}, got {encoding!r}")
    cols: dict[str, np.ndarray] = {}
    for name, arr in arrays.items():
        arr = np.asarray(arr)
        if name in ("points", "xyz"):
            arr = arr.reshape(-1, 3)
            cols.update({"x": arr[:, 0], "y": arr[:, 1], "z": arr[:, 2]})
        else:
            cols[name] = arr
    order = [k for k in ("x", "y", "z") if k in cols] + [k for k in cols if k not in ("x", "y", "z")]
    cols = {k: (cols[k].reshape(len(cols[k]), -1) if cols[k].ndim > 1 else cols[k].reshape(-1, 1)) for k in order}
    sizes_n = {len(v) for v in cols.values()}
    if len(sizes_n) > 1:
        raise DatasetError(f"{path}: PCD fields have different lengths {sorted(sizes_n)}")
    npoints = sizes_n.pop() if sizes_n else 0
    types = [_pcd_type(v.dtype) for v in cols.values()]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        f"FIELDS {' '.join(cols)}\n"
        f"SIZE {' '.join(str(s) for _, s in types)}\n"
        f"TYPE {' '.join(t for t, _ in types)}\n"
        f"COUNT {' '.join(str(v.shape[1]) for v in cols.values())}\n"
        f"WIDTH {npoints}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {npoints}\nDATA {encoding}\n"
    ).encode("ascii")
    le = {k: np.ascontiguousarray(v.astype(v.dtype.newbyteorder("<"))) for k, v in cols.items()}
    if encoding == "binary":
        rec = np.empty(npoints, dtype=[(f"f{i}", v.dtype, (v.shape[1],)) for i, v in enumerate(le.values())])
        for i, v in enumerate(le.values()):  # interleave: one record per point
            rec[f"f{i}"] = v
        body = rec.tobytes()
    elif encoding == "binary_compressed":
        raw = b"".join(v.tobytes() for v in le.values())
        comp = lzf_compress(raw) if raw else b""
        body = np.array([len(comp), len(raw)], dtype="<u4").tobytes() + comp
    else:
        fmts = []
        for v in cols.values():
            f = "%.9g" if v.dtype == np.float32 else "%.17g" if v.dtype.kind == "f" else "%d"
            fmts += [f] * v.shape[1]
        table = [v.astype(object) if v.dtype.kind != "f" else v for v in cols.values()]
        lines = []
        for i in range(npoints):
            vals = [x for v in table for x in v[i]]
            lines.append(" ".join(f % x for f, x in zip(fmts, vals)))
        body = ("\n".join(lines) + ("\n" if lines else "")).encode("ascii")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(header + body)
