"""Where ``good_start=True`` spends its CPU time beyond GICP's, part by part (families.py ``--parts``).

Each part's CPU time (this process: ``time.process_time``, small_gicp's threads included) is read by wrapping the
function that computes it for the duration of one measurement, on the pair both methods are timed on: ``prepare``
(both raw scans: crop, grids, k-d trees, covariances, the sensor guess), ``spread`` (the source's spread voxels the
verdict judges), ``gicp_from_start``, ``verdict`` (its probabilities: ``tables``, the target's direction
cells and own plane residuals, built once per target cloud, and the features of the spread voxels), ``check`` (the
second-minimum check where the verdict's ``pinned`` leaves the pose loose), ``finish`` (GICP again on the scene-sized
grids, with their building), ``coarse`` (the coarse-to-fine try), ``degenerate`` (the finished pose judged on both
grids), ``answer`` (its score, the target's spread voxels), ``skew`` (the skew check); GICP alone's
``gicp_alone_prepare`` (both raw scans) and ``gicp_alone_align``; ``good_total`` and ``gicp_total``: the calls'.
Nested parts are counted in their own line and in the part that calls them (``tables`` within ``verdict``).
"""

from __future__ import annotations

import contextlib
import functools
import time

import numpy as np

#: part -> (module, class or None, function): what each part's CPU time is read from
PARTS = {
    "prepare": ("deepbbs_ros.core.registration", "DeepBBSRegistration", "preprocess"),
    "spread": ("deepbbs_ros.core.good_start", None, "good_start_points"),
    "gicp_from_start": ("deepbbs_ros.core.good_start", None, "from_start"),
    "verdict": ("deepbbs_ros.core.good_start", None, "_probability"),
    "tables": ("deepbbs_ros.core.visibility", None, "_target"),
    "check": ("deepbbs_ros.core.good_start", None, "_slides"),
    "finish": ("deepbbs_ros.core.good_start", None, "_finished"),
    "coarse": ("deepbbs_ros.core.coarse_rescue", None, "coarse_then_fine"),
    "degenerate": ("deepbbs_ros.core.finish_verdict", None, "degenerate"),
    "answer": ("deepbbs_ros.core.good_start", None, "answer"),
    "skew": ("deepbbs_ros.core.sweep_skew", None, "judge"),
    "gicp_alone_prepare": ("deepbbs_ros.gicp_baseline", "SmallGicpRegistration", "preprocess"),
    "gicp_alone_align": ("deepbbs_ros.gicp_baseline", "SmallGicpRegistration", "align"),
}


@contextlib.contextmanager
def _wrapped(acc: dict[str, float]):
    """Every :data:`PARTS` function wrapped to add its CPU seconds to ``acc[part]``; restored on exit."""
    import importlib

    saved = []
    for part, (mod, cls, name) in PARTS.items():
        owner = getattr(importlib.import_module(mod), cls) if cls else importlib.import_module(mod)
        f = getattr(owner, name, None)
        if f is None:
            continue

        def timed(*a, _f=f, _part=part, **k):
            t = time.process_time()
            try:
                return _f(*a, **k)
            finally:
                acc[_part] = acc.get(_part, 0.0) + time.process_time() - t

        saved.append((owner, name, f, name in vars(owner)))
        setattr(owner, name, functools.wraps(f)(timed))
    try:
        yield
    finally:
        for owner, name, f, own in saved:
            if own:
                setattr(owner, name, f)
            else:  # inherited: the class's own attribute goes, the base's shows again
                delattr(owner, name)


def parts(good_reg, gicp_reg, src: np.ndarray, tgt: np.ndarray, repeats: int) -> dict[str, list[float]]:
    """Both methods on the raw pair ``repeats`` times each, alternately (as families.py's ``alternate``), each part's
    CPU ms per call -> {"good_total": [...], "gicp_total": [...], part: [...]} (0 where a part did not run)."""
    out: dict[str, list[float]] = {"good_total": [], "gicp_total": [], **{p: [] for p in PARTS}}
    calls = {"good": lambda: good_reg.register(src, tgt, T_init=np.eye(4), good_start=True),
             "gicp": lambda: gicp_reg.align(gicp_reg.preprocess(src), gicp_reg.preprocess(tgt))}
    for k in range(repeats):
        for m in ("gicp", "good") if k % 2 == 0 else ("good", "gicp"):
            acc: dict[str, float] = {}
            with _wrapped(acc):
                t = time.process_time()
                calls[m]()
                out[f"{m}_total"].append((time.process_time() - t) * 1e3)
            for p in PARTS:
                if p.startswith("gicp_alone") == (m == "gicp"):
                    out[p].append(acc.get(p, 0.0) * 1e3)
    return out


def summary(inside: list[dict]) -> dict:
    """The in-basin pairs' :func:`parts`: each pair's median per part, their p50 over the pairs, ms -> {"good_total",
    "gicp_total": the calls' CPU, part: ...}; {} when a pair has none."""
    if not inside or not all(r.get("parts") for r in inside):
        return {}
    keys = set.intersection(*(set(r["parts"]) for r in inside))
    p50 = {k: float(np.median([np.median(r["parts"][k]) for r in inside])) for k in sorted(keys)}
    return {k: round(v, 2) for k, v in p50.items()}
