"""Shared helpers of the benchmark scripts: the --out folder, the JSON figures file, plots without a display."""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # run from a checkout without installing


def clean(v):
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python numbers, tuples -> lists."""
    if isinstance(v, dict):
        return {str(k): clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [clean(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):
        try:
            v = v.item()
        except (ValueError, AttributeError):
            return str(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def split_passthrough(argv: list[str]) -> tuple[list[str], list[str]]:
    """``argv`` split at ``--``: (the script's own arguments, those passed on to deepbbs-replay)."""
    if "--" not in argv:
        return list(argv), []
    k = argv.index("--")
    return argv[:k], argv[k + 1:]


def read_reference_pair(folder: str | Path) -> tuple:
    """A real reference pair (``--pair``): two ``.pcd`` files (target, source in name order) and ``relative.txt``
    (their reference ``T_target_source``, 4x4) -> (target (N, 3) float32, source (M, 3) float32, T (4, 4))."""
    import numpy as np

    from deepbbs_ros.datasets.pcd import read_pcd_points

    folder = Path(folder)
    pcds = sorted(folder.glob("*.pcd"))
    if len(pcds) != 2 or not (folder / "relative.txt").is_file():
        raise SystemExit(f"--pair {folder}: expected two .pcd files (target, source in name order) and "
                         "relative.txt (T_target_source)")
    T = np.loadtxt(folder / "relative.txt").reshape(4, 4)
    return (read_pcd_points(pcds[0])[0].astype(np.float32), read_pcd_points(pcds[1])[0].astype(np.float32), T)


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux, else platform.processor()); "" when unknown."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def machine() -> dict:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {"cpus": os.cpu_count(), "cpu_model": cpu_model(), "platform": platform.platform(),
            "python": platform.python_version(), "load_avg_1min": load,
            "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def write_json(out: Path, name: str, figures: dict, command: list[str] | None = None) -> Path:
    """``out/name``: {"command", "machine", "figures"}; returns the path."""
    out.mkdir(parents=True, exist_ok=True)
    doc = {"command": " ".join(command if command is not None else sys.argv), "machine": machine(),
           "figures": figures}
    path = out / name
    path.write_text(json.dumps(clean(doc), indent=2) + "\n")
    print(f"figures: {path}")
    return path


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, out: Path, name: str) -> Path:
    path = out / name
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"plot: {path}")
    return path
