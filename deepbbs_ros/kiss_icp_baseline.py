"""KISS-ICP as a frame-by-frame odometry baseline (:class:`KissICPOdometry`, no ROS import): its own pipeline on the
raw scan, its end-of-sweep poses converted to the poses at the scans' stamps."""

from __future__ import annotations

import time

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.odometry import se3_power
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.one_cpu import one_cpu


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
