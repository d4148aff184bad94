"""The Apollo pair protocol (CONVENTIONS.md) over any iterable of scans: the pairs, the seeded initial perturbations,
every method on every pair, :class:`PairResults` filled as it goes (see :mod:`deepbbs_ros.replay.runner`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.config import Config
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.replay.loop import counted, keep_on_interrupt


# --------------------------------------------------------------------------------------------------
# pair protocol
# --------------------------------------------------------------------------------------------------
def iter_pairs(scans: Iterable[Scan], stride: int, max_dist: float, max_gap: int = 300) -> Iterator[tuple[Scan, Scan]]:
    """Apollo-style pairs (CONVENTIONS.md), streaming.

    Source frames are every ``stride``-th scan of the stream (0, stride, 2 stride, ...). The target of
    source ``i`` is the last scan ``j > i`` of the run of scans after ``i`` whose ground-truth position
    stays within ``max_dist`` metres of scan ``i``'s (the run ends at the first scan farther away or
    ``max_gap`` scans after ``i``). Sources without such a scan (or without ground truth) are skipped.
    Pairs are yielded as soon as they are decided, in source order; only the pending sources and their
    current best targets are kept in memory.
    """
    pending: list[list[Any]] = []  # [pos, scan, best_target or None]

    def done(entry):
        return (entry[1], entry[2]) if entry[2] is not None else None

    for pos, scan in enumerate(scans):
        still = []
        for entry in pending:
            src_pos, src, _ = entry
            ok = (scan.T_world_lidar is not None and pos - src_pos <= max_gap
                  and np.linalg.norm(scan.T_world_lidar[:3, 3] - src.T_world_lidar[:3, 3]) <= max_dist)
            if ok:
                entry[2] = scan
                still.append(entry)
            else:
                pair = done(entry)
                if pair:
                    yield pair
        pending = still
        if pos % stride == 0 and scan.T_world_lidar is not None:
            pending.append([pos, scan, None])
    for entry in pending:
        pair = done(entry)
        if pair:
            yield pair


def random_perturbation(rng: np.random.Generator, yaw_deg: float, trans_m: float) -> np.ndarray:
    """(4, 4) float64: yaw uniform in [-yaw_deg, yaw_deg] about z, horizontal offset of uniform direction
    and length uniform in [0, trans_m]. Identity when both are 0."""
    T = np.eye(4)
    if yaw_deg > 0:
        a = np.radians(rng.uniform(-yaw_deg, yaw_deg))
        T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    if trans_m > 0:
        phi = rng.uniform(0, 2 * np.pi)
        r = rng.uniform(0, trans_m)
        T[:2, 3] = [r * np.cos(phi), r * np.sin(phi)]
    return T


@dataclass
class PairRecord:
    """One registration of one pair by one method (one trial)."""

    method: str
    pair: int
    trial: int
    src_index: int
    tgt_index: int
    src_stamp_ns: int
    tgt_stamp_ns: int
    frame_id: str
    gt_dist_m: float
    T_init: np.ndarray
    T_gt: np.ndarray
    T_est: np.ndarray
    rot_err_deg: float
    trans_err_m: float
    success: bool
    runtime_ms: float
    preprocess_ms: float
    converged: bool
    error: str = ""
    valid: bool | None = None  # the method's verdict on its pose (DeepBBS++); None: the method gives none
    score: float = float("nan")  # the verdict's score
    path: str = ""  # which registration path answered (DeepBBS++: "gicp", "deepbbs", "search"); "" for the others


@dataclass
class PairResults:
    methods: list[str]
    records: list[PairRecord] = field(default_factory=list)
    inputs: dict[str, str] = field(default_factory=dict)
    frames_read: int = 0
    pairs: int = 0
    complete: bool = True
    errors: list[str] = field(default_factory=list)
    clouds: list[dict] = field(default_factory=list)  # a few pairs' clouds for the results bag

    def of(self, method: str) -> list[PairRecord]:
        return [r for r in self.records if r.method == method]


def run_pairs(
    scans: Iterable[Scan],
    methods: dict[str, Any],
    config: Config,
    *,
    max_pairs: int | None = None,
    progress: Callable[[int], None] | None = None,
    results: PairResults | None = None,
) -> PairResults:
    """Run every method on every protocol pair (``config.eval``: stride, max_dist, perturbations, trials).

    ``T_init`` of trial t is a seeded random perturbation (identity without ``perturb_*``): starting from
    ``P`` is the same as registering the source cloud moved by ``P`` from identity. ``progress(n)`` is
    called with the number of newly read frames. KeyboardInterrupt stops the loop with ``complete=False``
    (results so far kept); other errors propagate.
    """
    ev = config.eval
    res = results or PairResults(list(methods))
    res.inputs = {name: getattr(m, "input", "") for name, m in methods.items()}
    rng = np.random.default_rng(ev.seed)
    observers = [m for m in methods.values() if hasattr(m, "observe")]

    def observed():
        for _, scan in counted(scans, res, progress):
            times = scan.point_times()
            for m in observers if times is not None else ():
                try:  # the recording's velocity at every scan, in order (deskew of raw sweeps)
                    m.observe(scan.points, times, scan.stamp_ns)
                except DeepBBSError:
                    pass  # the scan's own prepare() reports the error where it is used
            yield scan

    with keep_on_interrupt(res):
        for src, tgt in iter_pairs(observed(), ev.stride, ev.max_dist, ev.max_pair_frames):
            if max_pairs is not None and res.pairs >= max_pairs:
                break
            T_gt = np.linalg.inv(tgt.T_world_lidar) @ src.T_world_lidar  # T_target_source
            dist = float(np.linalg.norm(T_gt[:3, 3]))
            inits = [random_perturbation(rng, ev.perturb_yaw_deg, ev.perturb_trans) for _ in range(ev.trials)]
            keep_cloud = len(res.clouds) < ev.bag_aligned_clouds
            if keep_cloud:
                res.clouds.append({"pair": res.pairs, "stamp_ns": src.stamp_ns, "frame_id": tgt.frame_id,
                                   "source": src.points, "target": tgt.points, "T_gt": T_gt, "T_est": {}})
            for name, method in methods.items():
                try:
                    p_src, ms_src = method.prepare(src.points, src.point_times(), src.stamp_ns)
                    p_tgt, ms_tgt = method.prepare(tgt.points, tgt.point_times(), tgt.stamp_ns)
                except DeepBBSError as err:
                    for t, T_init in enumerate(inits):
                        res.records.append(_failed(name, res.pairs, t, src, tgt, dist, T_init, T_gt, str(err)))
                    continue
                for t, T_init in enumerate(inits):
                    try:
                        T_est, info, ms = method.align(p_src, p_tgt, T_init)
                        err = ""
                    except DeepBBSError as exc:
                        T_est, info, ms, err = np.full((4, 4), np.nan), {"converged": False}, float("nan"), str(exc)
                    rot, tr = metrics.pair_errors(T_est, T_gt)
                    ok = bool(metrics.success_mask(rot, tr, ev.success_rot_deg, ev.success_trans))
                    res.records.append(PairRecord(
                        name, res.pairs, t, src.index, tgt.index, src.stamp_ns, tgt.stamp_ns, tgt.frame_id, dist,
                        T_init, T_gt, T_est, float(rot), float(tr), ok, ms_src + ms_tgt + ms, ms_src + ms_tgt,
                        bool(info.get("converged", False)), err, info.get("valid"),
                        float(info.get("score", float("nan"))), str(info.get("path", ""))))
                    if keep_cloud and t == 0:
                        res.clouds[-1]["T_est"][name] = T_est
            res.pairs += 1
    return res


def _failed(name, pair, trial, src, tgt, dist, T_init, T_gt, err) -> PairRecord:
    nan = float("nan")
    return PairRecord(name, pair, trial, src.index, tgt.index, src.stamp_ns, tgt.stamp_ns, tgt.frame_id, dist,
                      T_init, T_gt, np.full((4, 4), np.nan), nan, nan, False, nan, nan, False, err)

