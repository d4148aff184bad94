"""Classical baselines that DeepBBS++ is compared with: small_gicp ICP / point-to-plane ICP / GICP, KISS-ICP.

No ROS import. Transforms follow docs/CONVENTIONS.md: registration of ``source`` against ``target`` returns
``T_target_source`` (4, 4) float64 with ``p_target = R @ p_source + t`` — the same direction as
``small_gicp.align(target, source, init_T_target_source)``, pinned by ``tests/test_baselines.py``.

Input clouds ("which preprocessing"):

* ``eval.baseline_input = "dense"`` (default): crop to ``[preprocess.min_range, preprocess.max_range]``
  then a voxel grid of ``eval.baseline_voxel_size`` metres, **ground kept**. ICP-type methods need
  dense, ground-bearing clouds (the ground pins z, roll and pitch); on DeepBBS++'s 1000 non-ground
  points they are handicapped.
* ``eval.baseline_input = "deepbbs"``: exactly DeepBBS++'s preprocessing (crop, ground removal,
  voxel grid, farthest-point sampling to ``preprocess.num_points``).

KISS-ICP always runs its own pipeline on the raw scan (adaptive threshold, local voxel map, motion
compensation), with the same crop ranges; that is the point of the baseline.

Here: KISS-Matcher and KISS-ICP; the small_gicp baselines and the result type are :mod:`deepbbs_ros.gicp_baseline`'s
(exported here too).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.odometry import se3_power
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.errors import ConfigError, RegistrationError
from deepbbs_ros.gicp_baseline import (  # noqa: F401  (re-exported)
    SMALL_GICP_TYPES,
    BaselineResult,
    PreparedCloud,
    SmallGicpRegistration,
)


def _current_cpu(cpus: set[int]) -> int:
    """The CPU this thread last ran on (Linux: /proc/thread-self/stat, field 39), else the first allowed one."""
    try:
        with open("/proc/thread-self/stat", "rb") as fh:
            cpu = int(fh.read().rsplit(b")", 1)[1].split()[36])
    except (OSError, ValueError, IndexError):
        return min(cpus)
    return cpu if cpu in cpus else min(cpus)


@contextmanager
def one_cpu(on: bool = True) -> Iterator[None]:
    """The calling thread on one CPU while the block runs (Linux; elsewhere, or ``on`` False: nothing).

    KISS-ICP and KISS-Matcher compute with TBB, whose parallel sums group their terms by the number of CPUs the
    calling thread may use, even on one thread (KISS-ICP's ``max_num_threads``: 1); KISS-Matcher has no thread
    setting at all (its answer varied from run to run on 2 cores). In this block they see one CPU: one thread and
    the same sums on any machine. With ``eval.threads`` 1 every call of either runs in this block. The CPU is the
    one the thread is running on already, so that processes side by side (a fleet's tasks) do not all queue on
    the same CPU."""
    if not on or not hasattr(os, "sched_setaffinity"):
        yield
        return
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {_current_cpu(cpus)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cpus)


@dataclass
class MatcherCloud:
    """A scan ready for KISS-Matcher: the cropped points (N, 3) float32 (KISS-Matcher voxelises them itself),
    and, for ``kiss-matcher+gicp``, the GICP baseline's cloud; ``preprocess_ms`` the time it took."""

    points: np.ndarray
    gicp: PreparedCloud | None
    preprocess_ms: float


class KissMatcherRegistration:
    """KISS-Matcher (``kiss_matcher``, MIT SPARK): a global registration (FPFH-like features, graph-based
    outlier pruning, GNC solver) that needs no initial guess; ``kiss-matcher+gicp`` refines its answer with
    the small_gicp GICP baseline on the baseline's clouds (``eval.baseline_*``).

    A global method ignores the start guess; to register "from a start" ``T_init`` honestly, :meth:`align`
    moves the source points by ``T_init`` (what a wrong start means for the clouds) and composes the answer
    back, so every trial sees another cloud. Args: ``method`` "kiss-matcher" or "kiss-matcher+gicp";
    ``config`` uses the preprocess crop, ``eval.kiss_matcher_voxel`` and the ``eval.baseline_*`` keys.
    """

    def __init__(self, method: str, config: Config | None = None) -> None:
        if method not in ("kiss-matcher", "kiss-matcher+gicp"):
            raise ConfigError(f"unknown KISS-Matcher method {method!r}")
        try:
            import kiss_matcher  # noqa: F401
        except ImportError as err:  # an optional wheel on exotic platforms
            raise ConfigError(f"{method}: the kiss-matcher package is not installed ({err})") from err
        self.method = method
        self.config = config or Config()
        self.gicp = SmallGicpRegistration("gicp", self.config) if method.endswith("+gicp") else None
        self._one_cpu = self.config.eval.threads == 1  # see one_cpu: KISS-Matcher has no thread setting

    def preprocess(self, points: np.ndarray) -> MatcherCloud:
        """Raw scan (N, 3) -> :class:`MatcherCloud` (finite points within the preprocess crop)."""
        from deepbbs_ros.core.preprocess import crop_range

        pp = self.config.preprocess
        t0 = time.perf_counter()
        pts = as_xyz(points, self.method, dtype=None)
        pts = np.ascontiguousarray(np.compress(crop_range(pts, pp.min_range, pp.max_range), pts, axis=0),
                                   dtype=np.float32)
        if len(pts) < 10:
            raise RegistrationError(f"{self.method}: only {len(pts)} points within the crop range")
        gicp = self.gicp.preprocess(points) if self.gicp is not None else None
        return MatcherCloud(pts, gicp, (time.perf_counter() - t0) * 1e3)

    def align(self, source: MatcherCloud, target: MatcherCloud, T_init: np.ndarray | None = None) -> BaselineResult:
        """-> ``T_target_source``; ``T_init`` only moves the source cloud (see the class)."""
        import kiss_matcher

        P = np.eye(4) if T_init is None else as_transform(T_init)
        t0 = time.perf_counter()
        src = source.points if np.allclose(P, np.eye(4)) else \
            np.ascontiguousarray(source.points @ P[:3, :3].T.astype(np.float32) + P[:3, 3].astype(np.float32))
        voxel = self.config.eval.kiss_matcher_voxel
        matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size=voxel))
        with one_cpu(self._one_cpu):
            sol = matcher.estimate(src, target.points)
        T = np.eye(4)
        T[:3, :3] = np.asarray(sol.rotation, dtype=np.float64)
        T[:3, 3] = np.asarray(sol.translation, dtype=np.float64).reshape(3)
        T = T @ P  # the answer for the moved source, composed back: T_target_source of the original source
        inliers = int(matcher.get_num_final_inliers())
        converged, iterations = bool(sol.valid), 0
        if self.gicp is not None and source.gicp is not None and target.gicp is not None:
            g = self.gicp.align(source.gicp, target.gicp, T)
            T, converged, iterations, inliers = g.T_target_source, bool(sol.valid) and g.converged, g.iterations, \
                g.num_inliers
        ms = (time.perf_counter() - t0) * 1e3
        return BaselineResult(T_target_source=T, converged=converged, iterations=iterations, num_inliers=inliers,
                              timings_ms={"preprocess": 0.0, "register": ms, "total": ms})


class KissICPOdometry:
    """KISS-ICP (``kiss_icp.kiss_icp.KissICP``) as a frame-by-frame odometry.

    Pose convention (checked against the installed kiss-icp 1.x): the ``time`` field is min-max
    normalised per scan and deskewing maps every point into the sensor frame at the **last** point's
    time, so ``KissICP.last_pose`` is the pose at the end of the sweep, relative to the first frame's
    end-of-sweep pose. :meth:`register` converts it to the pose at the scan stamp (the time origin of
    ``times``) with KISS-ICP's own constant-velocity model: ``T_stamp = T_end @ delta^(s - 1)``,
    ``s = (0 - t_min) / (t_max - t_min)``, where ``delta`` is KISS-ICP's last inter-frame motion.
    Without per-point times (or with ``eval.kiss_deskew`` off) the pose is that of the raw scan.

    Args:
        config: uses ``preprocess.min_range``/``max_range`` (KISS-ICP's crop), ``eval.kiss_deskew``
            and ``eval.threads``; the voxel size is KISS-ICP's default ``max_range / 100``.
    """

    def __init__(self, config: Config | None = None) -> None:
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import DataConfig, MappingConfig, RegistrationConfig
        from kiss_icp.kiss_icp import KissICP

        self.config = config or Config()
        pp, ev = self.config.preprocess, self.config.eval
        self.deskew = bool(ev.kiss_deskew)
        kcfg = KISSConfig(
            data=DataConfig(max_range=pp.max_range, min_range=pp.min_range, deskew=self.deskew),
            mapping=MappingConfig(voxel_size=pp.max_range / 100.0),
            registration=RegistrationConfig(max_num_threads=ev.threads),
        )
        self.kiss_config = kcfg
        self._odom = KissICP(kcfg)
        # KISS-ICP fixes deskewing at construction and divides by the time span: scans without
        # per-point times go through a second, non-deskewing preprocessor (swapped per frame).
        from kiss_icp.preprocess import Preprocessor

        self._pre_deskew = self._odom.preprocessor
        self._pre_plain = Preprocessor(pp.max_range, pp.min_range, False, ev.threads)
        self._one_cpu = ev.threads == 1  # its sums grouped as on one CPU (see one_cpu)
        self._frames = 0
        self._s0 = 0.0
        self._origin_inv = np.eye(4)

    def corrupt_prior(self, T: np.ndarray) -> None:
        """Robustness benchmark: KISS-ICP's next constant-velocity prediction is off by ``T`` (4, 4)."""
        self._odom.last_delta = np.asarray(self._odom.last_delta) @ T

    def register(self, points: np.ndarray, times: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """Feed the next scan; returns (``T_first_k`` (4, 4) float64 pose of this scan's stamp relative
        to the first scan's, runtime ms). ``times``: (N,) seconds since the scan stamp, or None."""
        pts = as_xyz(points, "kiss-icp", dtype=np.float64)  # (N, 3) only (core/points.py)
        ok = np.isfinite(pts).all(axis=1)
        pts = pts[ok]
        if pts.shape[0] < 10:
            raise RegistrationError(f"kiss-icp: only {pts.shape[0]} valid points in the scan")
        t0 = time.perf_counter()
        use_times = self.deskew and times is not None and np.ptp(np.asarray(times)[ok]) > 0
        ts = np.asarray(times, dtype=np.float64)[ok] if use_times else np.zeros(pts.shape[0])
        self._odom.preprocessor = self._pre_deskew if use_times else self._pre_plain
        with one_cpu(self._one_cpu):
            self._odom.register_frame(pts, ts)
        T_end = np.asarray(self._odom.last_pose, dtype=np.float64)
        if not use_times:
            T = T_end.copy()
        else:
            s = float((0.0 - ts.min()) / (ts.max() - ts.min()))
            delta = np.asarray(self._odom.last_delta, dtype=np.float64)
            T = T_end @ se3_power(delta, s - 1.0)
            self._frames += 1
            if self._frames == 1:  # KISS-ICP's origin is the end of sweep 0; the stamp pose needs a motion
                self._s0 = s
                T = np.eye(4)
            else:
                if self._frames == 2:  # stamp 0 in the end-of-sweep-0 frame, from the first motion estimate
                    self._origin_inv = se3_power(se3_power(delta, self._s0 - 1.0), -1.0)
                T = self._origin_inv @ T
        return T, (time.perf_counter() - t0) * 1e3
