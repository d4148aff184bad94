"""Odometry over any iterable of scans: a trajectory per method (scan-to-scan for the pairwise ones, KISS-ICP its own),
the seeded dropped frames and wrong priors, :class:`OdometryResults` filled as it goes (see
:mod:`deepbbs_ros.replay.runner`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.replay.loop import keep_on_interrupt, strided
from deepbbs_ros.replay.pair_loop import random_perturbation


# --------------------------------------------------------------------------------------------------
# odometry
# --------------------------------------------------------------------------------------------------
def robustness_plan(n_scans: int, ev: Any) -> tuple[set[int], dict[int, np.ndarray]]:
    """What breaks constant-velocity odometry, reproducibly (``eval.seed``): ``eval.drop_frames`` gaps of
    ``drop_min``..``drop_max`` consecutive scans (stream positions to skip), and ``eval.wrong_prior`` frames
    whose motion prior is multiplied by a random motion (yaw up to ``wrong_prior_yaw_deg``, shift up to
    ``wrong_prior_trans``). Positions are spread over the middle of a stream of ``n_scans`` scans (the
    first 10 and the last 10 are kept). Returns (positions to drop, {position: (4, 4) prior error})."""
    rng = np.random.default_rng([int(ev.seed), 7331])
    drops: set[int] = set()
    wrong: dict[int, np.ndarray] = {}
    lo, hi = 10, n_scans - 10
    if hi <= lo:
        return drops, wrong
    if ev.drop_frames:
        starts = np.sort(rng.choice(np.arange(lo, hi), size=min(ev.drop_frames, hi - lo), replace=False))
        for s in starts:
            drops.update(range(int(s), min(int(s) + int(rng.integers(ev.drop_min, ev.drop_max + 1)), hi)))
    if ev.wrong_prior:
        keep = [p for p in range(lo, hi) if p not in drops]
        for p in rng.choice(keep, size=min(ev.wrong_prior, len(keep)), replace=False):
            wrong[int(p)] = random_perturbation(rng, ev.wrong_prior_yaw_deg, ev.wrong_prior_trans)
    return drops, wrong


@dataclass
class OdometryResults:
    methods: list[str]
    stamps_ns: list[int] = field(default_factory=list)
    indices: list[int] = field(default_factory=list)
    frame_id: str = ""
    T_world_gt: list[np.ndarray | None] = field(default_factory=list)
    T_world_est: dict[str, list[np.ndarray]] = field(default_factory=dict)
    runtime_ms: dict[str, list[float]] = field(default_factory=dict)
    failed: dict[str, list[str]] = field(default_factory=dict)
    inputs: dict[str, str] = field(default_factory=dict)
    frames_read: int = 0
    complete: bool = True
    errors: list[str] = field(default_factory=list)
    registered: int = 0  # registrations (any method, frames after the first) that gave an estimate

    @property
    def frames(self) -> int:
        """Frames with an estimate from every method (a frame cut by an interruption is dropped)."""
        return min([len(self.stamps_ns)] + [len(v) for v in self.T_world_est.values()])

    @property
    def has_ground_truth(self) -> bool:
        n = self.frames
        return n > 0 and all(T is not None for T in self.T_world_gt[:n])


def run_odometry(
    scans: Iterable[Scan],
    methods: dict[str, Any],
    config: Config,
    *,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    results: OdometryResults | None = None,
) -> OdometryResults:
    """Scan-to-scan odometry of every pairwise method (KISS-ICP: its own scan-to-map odometry).

    Every ``config.eval.odom_stride``-th scan is kept; scan k (source) is registered against the
    previous kept scan (target), giving ``T_{k-1}_k``, and ``T_world_k = T_world_{k-1} @ T_{k-1}_k``
    with ``T_world_0`` = the first ground-truth pose (identity without ground truth). The initial guess
    is the previous relative motion (``odom_init = "constant_velocity"``) or identity. A failed
    registration keeps the initial guess for that frame and is recorded in ``failed``.
    Runtime of frame k = preprocessing of scan k + its registration (frame 0: preprocessing only).
    """
    ev = config.eval
    drops, wrong = robustness_plan(len(scans) if hasattr(scans, "__len__") else 0, ev)
    res = results or OdometryResults(list(methods))
    res.inputs = {name: getattr(m, "input", "") for name, m in methods.items()}
    for name in methods:
        res.T_world_est.setdefault(name, [])
        res.runtime_ms.setdefault(name, [])
        res.failed.setdefault(name, [])
    state: dict[str, dict[str, Any]] = {name: {} for name in methods}
    T_world_0 = None
    with keep_on_interrupt(res):
        for pos, scan in strided(scans, res, ev.odom_stride, progress, skip=drops):
            if max_frames is not None and len(res.stamps_ns) >= max_frames:
                break
            k = len(res.stamps_ns)
            if k == 0:
                T_world_0 = scan.T_world_lidar.copy() if scan.T_world_lidar is not None else np.eye(4)
                res.frame_id = scan.frame_id
            bad = wrong.get(pos)
            for name, method in methods.items():
                st = state[name]
                if bad is not None and k > 1:  # the motion prior of this frame is off by ``bad``
                    if hasattr(method, "corrupt_prior"):
                        method.corrupt_prior(bad)
                    elif "rel" in st:
                        st["rel"] = st["rel"] @ bad
                if hasattr(method, "step"):  # odometries with their own state (KISS-ICP, DeepBBS++ odometry)
                    try:
                        T_first_k, ms = method.step(scan.points, scan.point_times(), scan.stamp_ns)
                        st["last"] = T_first_k
                        res.registered += k > 0
                    except DeepBBSError as err:
                        T_first_k, ms = st.get("last", np.eye(4)), float("nan")
                        res.failed[name].append(f"frame {scan.index}: {err}")
                    res.T_world_est[name].append(T_world_0 @ T_first_k)
                    res.runtime_ms[name].append(ms)
                    continue
                try:
                    prep, ms_prep = method.prepare(scan.points, scan.point_times(), scan.stamp_ns)
                except DeepBBSError as err:
                    prep, ms_prep = None, float("nan")
                    res.failed[name].append(f"frame {scan.index}: {err}")
                if k == 0:
                    res.T_world_est[name].append(T_world_0.copy())
                    res.runtime_ms[name].append(ms_prep)
                    st.update(prev=prep, rel=np.eye(4))
                    continue
                T_init = st["rel"] if ev.odom_init == "constant_velocity" else np.eye(4)
                T_rel, ms = T_init, float("nan")
                if prep is not None and st.get("prev") is not None:
                    try:
                        T_rel, _, ms = method.align(prep, st["prev"], T_init)
                    except DeepBBSError as err:
                        res.failed[name].append(f"frame {scan.index}: {err}")
                if not np.isfinite(T_rel).all():
                    res.failed[name].append(f"frame {scan.index}: non-finite estimate")
                    T_rel = T_init
                elif not np.isnan(ms):
                    res.registered += 1
                res.T_world_est[name].append(res.T_world_est[name][-1] @ T_rel)
                res.runtime_ms[name].append(ms_prep + ms)
                st.update(prev=prep if prep is not None else st.get("prev"), rel=T_rel)
            res.stamps_ns.append(scan.stamp_ns)
            res.indices.append(scan.index)
            res.T_world_gt.append(None if scan.T_world_lidar is None else scan.T_world_lidar.copy())
    n = res.frames  # drop a frame only some methods finished
    for name in res.T_world_est:
        del res.T_world_est[name][n:]
        del res.runtime_ms[name][n:]
    del res.stamps_ns[n:], res.indices[n:], res.T_world_gt[n:]
    return res


