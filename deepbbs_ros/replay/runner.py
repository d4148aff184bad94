"""Replay loops: the Apollo pair protocol, scan-to-scan odometry and localization in a prior map, over any
iterable of scans.

The loops stream the recording once (only the scans still needed are kept), run every selected
method on the same inputs, and fill a :class:`PairResults` / :class:`OdometryResults` /
:class:`LocalizationResults` as they go, so that an interruption (Ctrl-C) or a reader fault leaves
everything computed so far in the results (``complete = False``). No ROS import, no output files
(see :mod:`deepbbs_ros.replay.report`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.config import Config
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import DeepBBSError

# --------------------------------------------------------------------------------------------------
# the threads of an offline run
# --------------------------------------------------------------------------------------------------
#: the thread settings ``eval.threads`` replaces in an offline run (small_gicp in DeepBBS++'s precision stage and
#: odometry, torch in the network); the baselines (small_gicp, KISS-ICP) read ``eval.threads`` itself
OFFLINE_THREAD_KEYS = ("registration.polish_threads", "odometry.threads", "registration.threads")


def offline_threads(config: Config) -> Config:
    """The config an offline run uses: every thread setting ``eval.threads`` (when > 0; 0 leaves each section's).

    small_gicp sums its GICP terms in per-thread partial sums over an OpenMP ``schedule(guided)`` loop (one
    thread whatever the count with ``registration.exact_gicp``) and writes odometry's voxel grid
    (``preprocess_points``) in the order its threads finish (the precision stage's grid is built on one thread,
    core/polish.py); KISS-ICP sums with TBB's ``parallel_reduce``, grouped by the CPUs it may use. With one thread
    each sum runs in index order (KISS-ICP and KISS-Matcher on one CPU, :func:`deepbbs_ros.baselines.one_cpu`), so
    one thread (the default) gives the same figures, bit for bit, on any number of cores and in a Ray task (1 CPU,
    Ray's ``OMP_NUM_THREADS=1``) as in a single run on every core. The results folder's config_used.yaml records
    the settings applied."""
    n = config.eval.threads
    if n <= 0:
        return config
    return config.replace(**{key: n for key in OFFLINE_THREAD_KEYS})


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


def _count_frames(scans: Iterable[Scan], results: Any) -> Iterator[Scan]:
    for scan in scans:
        results.frames_read += 1
        yield scan


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
    last_read = 0

    observers = [m for m in methods.values() if hasattr(m, "observe")]

    def counted():
        nonlocal last_read
        for scan in _count_frames(scans, res):
            if progress:
                progress(res.frames_read - last_read)
            last_read = res.frames_read
            times = scan.point_times()
            for m in observers if times is not None else ():
                try:  # the recording's velocity at every scan, in order (deskew of raw sweeps)
                    m.observe(scan.points, times, scan.stamp_ns)
                except DeepBBSError:
                    pass  # the scan's own prepare() reports the error where it is used
            yield scan

    try:
        for src, tgt in iter_pairs(counted(), ev.stride, ev.max_dist, ev.max_pair_frames):
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
    except KeyboardInterrupt:
        res.complete = False
        res.errors.append("interrupted by the user (Ctrl-C)")
    return res


def _failed(name, pair, trial, src, tgt, dist, T_init, T_gt, err) -> PairRecord:
    nan = float("nan")
    return PairRecord(name, pair, trial, src.index, tgt.index, src.stamp_ns, tgt.stamp_ns, tgt.frame_id, dist,
                      T_init, T_gt, np.full((4, 4), np.nan), nan, nan, False, nan, nan, False, err)


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
    try:
        for pos, scan in enumerate(scans):
            res.frames_read += 1
            if progress:
                progress(1)
            if pos % ev.odom_stride or pos in drops:
                continue
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
    except KeyboardInterrupt:
        res.complete = False
        res.errors.append("interrupted by the user (Ctrl-C)")
    n = res.frames  # drop a frame only some methods finished
    for name in res.T_world_est:
        del res.T_world_est[name][n:]
        del res.runtime_ms[name][n:]
    del res.stamps_ns[n:], res.indices[n:], res.T_world_gt[n:]
    return res


# --------------------------------------------------------------------------------------------------
# localization in a prior map
# --------------------------------------------------------------------------------------------------
@dataclass
class LocalizationRecord:
    """One scan through the map tracker (:class:`~deepbbs_ros.core.localization.MapTracker`).

    T_map_est: (4, 4) float64 the tracker's pose of the scan in the map frame (NaN when it gave none);
    published only when ``valid``. T_map_gt: (4, 4) the recording's ground truth (taken to be in the map frame),
    or None. rot_err_deg / trans_err_m: of ``T_map_est`` against it (NaN without either). time_ms: the
    tracker's wall time for the scan (``step``), ms."""

    index: int
    stamp_ns: int
    event: str
    valid: bool
    score: float
    mode: str
    path: str
    reason: str
    candidates: int
    time_ms: float
    T_map_est: np.ndarray
    T_map_gt: np.ndarray | None
    rot_err_deg: float
    trans_err_m: float
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class LocalizationResults:
    records: list[LocalizationRecord] = field(default_factory=list)
    frame_id: str = ""
    frames_read: int = 0
    complete: bool = True
    errors: list[str] = field(default_factory=list)
    recoveries: int = 0
    setup_ms: float = float("nan")  # building the localizer (places, descriptors)
    map_points: int = 0
    places: np.ndarray | None = None  # (P, 4, 4) the localizer's candidate places (plots)
    map_xyz: np.ndarray | None = None  # (N, 3) the map (plots, results bag)
    warnings: list[str] = field(default_factory=list)  # e.g. a map trajectory that does not fit the map

    @property
    def frames(self) -> int:
        return len(self.records)

    @property
    def has_ground_truth(self) -> bool:
        return bool(self.records) and all(r.T_map_gt is not None for r in self.records)


def run_localization(
    scans: Iterable[Scan],
    tracker: Any,
    config: Config,
    *,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    results: LocalizationResults | None = None,
) -> LocalizationResults:
    """Every ``config.eval.odom_stride``-th scan through ``tracker.step(points, stamp_ns, times)`` (a
    :class:`~deepbbs_ros.core.localization.MapTracker`: no initial pose, it searches the map first), one
    :class:`LocalizationRecord` per scan. A :class:`~deepbbs_ros.errors.DeepBBSError` on a scan (too few points)
    is that scan's "error" event (no pose) and the run goes on. KeyboardInterrupt stops the loop with
    ``complete=False``, the scans so far kept."""
    ev = config.eval
    res = results or LocalizationResults()
    nan4 = np.full((4, 4), np.nan)
    try:
        for pos, scan in enumerate(scans):
            res.frames_read += 1
            if progress:
                progress(1)
            if pos % ev.odom_stride:
                continue
            if max_frames is not None and len(res.records) >= max_frames:
                break
            res.frame_id = res.frame_id or scan.frame_id
            t0 = time.perf_counter()
            try:
                out = tracker.step(scan.points, scan.stamp_ns, scan.point_times())
            except DeepBBSError as err:
                out = None
                reason = str(err)
            ms = (time.perf_counter() - t0) * 1e3
            gt = None if scan.T_world_lidar is None else scan.T_world_lidar.copy()
            if out is None:
                rec = LocalizationRecord(scan.index, scan.stamp_ns, "error", False, float("nan"), "", "", reason, 0, ms,
                                         nan4.copy(), gt, float("nan"), float("nan"))
            else:
                T = np.asarray(out.T_map_scan, dtype=np.float64)
                if not out.valid or not np.isfinite(T).all():
                    T = nan4.copy()
                rot, tr = (metrics.pair_errors(T, gt) if gt is not None and np.isfinite(T).all()
                           else (float("nan"), float("nan")))
                event = out.event or ("found" if out.valid else "searching")
                rec = LocalizationRecord(
                    scan.index, scan.stamp_ns, event, bool(out.valid), float(out.score), out.mode,
                    getattr(out, "path", ""), out.reason, int(getattr(out, "candidates", 0)), ms, T, gt, float(rot),
                    float(tr), dict(getattr(out, "timings_ms", {}) or {}))
            res.records.append(rec)
            res.recoveries = int(getattr(tracker, "recoveries", 0))
    except KeyboardInterrupt:
        res.complete = False
        res.errors.append("interrupted by the user (Ctrl-C)")
    return res
