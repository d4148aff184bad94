"""The same sums on any x86-64 computer: the CPU kernels that numpy, its OpenBLAS and torch pick at run time, pinned.

numpy's math functions and OpenBLAS (inverses, SVDs, matrix products) and torch's own kernels choose their code by
the CPU they run on: AVX-512 on one computer, AVX2 on another. Each order of operations rounds in its own way, so
the same registration of the same scans on two computers ends a few units in the last place apart (measured: every
pose of three KITTI registrations differed, bit for bit, between the AVX-512 and the AVX2 kernels of one computer),
and a figure can round the other way. :func:`pin` makes every x86-64 CPU with AVX2 (x86-64-v3: Intel since 2013,
AMD since 2015) run the AVX2 kernels, so answers and figures are the same to the last digit on any of them.

Each library reads its setting once, when it loads: ``import deepbbs_ros`` calls :func:`pin` before numpy and torch
are imported (the ``deepbbs-*`` commands import it first). ``DEEPBBS_CPU_KERNELS=native`` keeps each library's own
choice (a little faster on AVX-512 CPUs; answers that may differ from another computer's in the last digits). A
setting the user made already (``OPENBLAS_CORETYPE``, ``ATEN_CPU_CAPABILITY``, ``NPY_DISABLE_CPU_FEATURES``, ...)
wins. Not covered: other CPU architectures (ARM), and libraries compiled for one instruction set (small_gicp,
KISS-ICP: the same code on every CPU).
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import MutableMapping

__all__ = ["ENV", "pin", "state"]

#: what this module sets: OpenBLAS's kernels (numpy's and scipy's), torch's ATen, MKL and oneDNN kernels
ENV = {"OPENBLAS_CORETYPE": "Haswell", "ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "AVX2",
       "ONEDNN_MAX_CPU_ISA": "AVX2"}
#: numpy's optimizations above AVX2, by the names its releases give them (2.4 grouped them into x86-64 levels)
NUMPY_ABOVE_AVX2 = {(2, 4): "X86_V4 AVX512_ICL AVX512_SPR",
                    (0, 0): "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
                            "AVX512_SPR"}

_state = "not pinned yet"


def _has_avx2() -> bool:
    """The CPU runs AVX2 and FMA (Linux: /proc/cpuinfo; elsewhere unknown: False)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return {"avx2", "fma"} <= flags
    except OSError:
        pass
    return False


def _numpy_features() -> str:
    """numpy's optimizations above AVX2 for the installed numpy's naming (read without importing numpy)."""
    from importlib import metadata

    try:
        version = tuple(int(p) for p in metadata.version("numpy").split(".")[:2])
    except (metadata.PackageNotFoundError, ValueError):
        version = (0, 0)
    return next(names for since, names in NUMPY_ABOVE_AVX2.items() if version >= since)


def pin(environ: MutableMapping[str, str] | None = None) -> str:
    """Set the environment so that numpy, OpenBLAS and torch load their AVX2 kernels (module docstring); a setting
    already in ``environ`` (default ``os.environ``) is kept. Returns (and keeps, see :func:`state`) what holds:
    "avx2", "avx2 except numpy" (or torch: imported before this call, it keeps its own), or "native (why)"."""
    global _state
    env = os.environ if environ is None else environ
    if env.get("DEEPBBS_CPU_KERNELS", "").lower() == "native":
        _state = "native (DEEPBBS_CPU_KERNELS=native)"
    elif platform.machine().lower() not in ("x86_64", "amd64"):
        _state = f"native ({platform.machine() or 'unknown'} CPU)"
    elif not _has_avx2():
        _state = "native (no AVX2 found)"
    else:
        for key, value in ENV.items():
            env.setdefault(key, value)
        env.setdefault("NPY_DISABLE_CPU_FEATURES", _numpy_features())
        early = [m for m in ("numpy", "torch") if m in sys.modules]
        _state = "avx2" + (f" except {' and '.join(early)} (imported before deepbbs_ros)" if early else "")
    return _state


def state() -> str:
    """What :func:`pin` achieved in this process ("avx2", "avx2 except ...", "native (why)")."""
    return _state
