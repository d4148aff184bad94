"""The baselines replay compares DeepBBS++ with (no ROS import): small_gicp's ``icp``, ``plane-icp`` and ``gicp``,
KISS-Matcher (global) and KISS-ICP (an odometry), each behind replay/methods.py's interface."""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.replay.method_names import INPUTS


class SmallGicpMethod:
    """``icp``, ``plane-icp``, ``gicp`` via :class:`deepbbs_ros.baselines.SmallGicpRegistration`."""

    def __init__(self, name: str, config: Config) -> None:
        from deepbbs_ros.baselines import SmallGicpRegistration

        self.name = name
        self.reg = SmallGicpRegistration(name, config)
        ev = config.eval
        if ev.baseline_input == "dense":
            self.input = (f"crop [{config.preprocess.min_range}, {config.preprocess.max_range}] m + "
                          f"{ev.baseline_voxel_size} m voxel grid, ground kept (small_gicp)")
        else:
            self.input = "DeepBBS++ preprocessing (small_gicp on the same 1000 points)"

    def prepare(self, points: np.ndarray, times: np.ndarray | None = None,
                stamp_ns: int | None = None) -> tuple[Any, float]:
        """The baseline as small_gicp runs it: per-point times are not used (no deskew)."""
        prep = self.reg.preprocess(points)
        return prep, prep.preprocess_ms

    def align(self, src: Any, tgt: Any, T_init: np.ndarray | None) -> tuple[np.ndarray, dict, float]:
        res = self.reg.align(src, tgt, T_init)
        info = {"converged": res.converged, "iterations": res.iterations, "num_inliers": res.num_inliers}
        return res.T_target_source, info, res.timings_ms["register"]


class KissMatcherMethod(SmallGicpMethod):
    """``kiss-matcher``, ``kiss-matcher+gicp`` via :class:`deepbbs_ros.baselines.KissMatcherRegistration`
    (the start guess moves the source cloud: a global method is judged from every start alike); ``prepare`` and
    ``align`` as the small_gicp baselines'."""

    def __init__(self, name: str, config: Config) -> None:
        from deepbbs_ros.baselines import KissMatcherRegistration

        self.name = name
        self.reg = KissMatcherRegistration(name, config)
        self.input = INPUTS[name]


class KissMethod:
    """KISS-ICP odometry (scan-to-map); ``step`` returns the pose relative to the first scan."""

    def __init__(self, name: str, config: Config) -> None:
        from deepbbs_ros.baselines import KissICPOdometry

        self.name = name
        self.odom = KissICPOdometry(config)
        self.input = INPUTS[name]

    def step(self, points: np.ndarray, times: np.ndarray | None,
             stamp_ns: int | None = None) -> tuple[np.ndarray, float]:
        return self.odom.register(points, times)

    def corrupt_prior(self, T: np.ndarray) -> None:
        """Robustness benchmark: the next constant-velocity prediction is off by ``T`` (4, 4)."""
        self.odom.corrupt_prior(T)
