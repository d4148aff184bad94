"""Deskewing a stream of raw sweeps for pairwise registration (no ROS).

A raw sweep is measured while the sensor moves (per-point times: Velodyne ``time``, Ouster ``t``). For
the relative transform of two scans what matters is their *differential* distortion: each scan bent by
its own velocity. One pair alone does not give each scan's velocity, and deskewing both scans with the
pair's mean motion leaves the difference untouched (measured: no gain on held-out raw pairs, while
sweeps deskewed with their own velocities are registered several times more precisely; docs/benchmarks.md).
:class:`StreamDeskew` therefore follows one stream (a topic, a recording): each new scan is aligned to
the previous one (DeepBBS++ for the first motion of a stream and whenever GICP from the
constant-velocity prediction strays from it; else GICP alone), the motion over the stamp gap is the
scan's velocity, and a deskewed copy of the scan's GICP cloud is built with it
(``DeepBBSRegistration.deskew_scan``). The registration uses the deskewed clouds only when both scans'
velocities agree with the pair's own mean motion: on highways, traffic moving with the sensor biases
consecutive-scan velocities (measured up to 12 m/s low), and such a deskew would do harm. The local-map
odometry (``core/odometry.py``) deskews with its own, map-based velocity.

Transforms follow CONVENTIONS.md: ``T_prev_cur`` (4, 4) is the pose of the current scan (at its stamp)
in the previous scan's frame; the deskew twist is ``log(T_prev_cur) / (stamp_cur - stamp_prev)``.
"""

from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np

from deepbbs_ros.core.polish import polish
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.errors import RegistrationError

__all__ = ["StreamDeskew"]

GATE_TRANS, GATE_ROT_DEG = 0.3, 1.0  # GICP straying this far from the constant-velocity prediction: ask DeepBBS++


class StreamDeskew:
    """Per-stream velocity estimate and deskew of each new scan's precision-stage cloud.

    Args:
        registration: a ``DeepBBSRegistration`` (its ``register`` for the first motion, its GICP settings,
            ``deskew_scan``).
        max_gap_s: a stamp gap longer than this (dropped scans, a pause) restarts the stream.
        max_speed: m/s; a faster estimate is a failed alignment (no deskew, the stream restarts).

    ``apply(pre)`` takes the scans of one stream in stamp order (``PreprocessResult`` s that kept their raw
    points and times, i.e. from ``preprocess(points, times, stamp_ns)``) and returns each one with
    ``deskewed_cloud`` and ``velocity`` set and ``deskew`` saying what was done (a copy; ``pre`` is not
    changed).
    ``velocity(pre)`` only estimates. Not thread-safe: one per stream.
    """

    def __init__(self, registration: Any, max_gap_s: float = 0.5, max_speed: float = 70.0) -> None:
        self.reg = registration
        self.max_gap_s, self.max_speed = float(max_gap_s), float(max_speed)
        self._prev: PreprocessResult | None = None  # the previous scan, raw GICP cloud
        self._delta: tuple[np.ndarray, float] | None = None  # last motion and its duration (s)
        self.deepbbs_calls = 0  # DeepBBS++ alignments (first motions, GICP strays)
        self.last_ms = 0.0  # time of the last velocity estimate

    def reset(self) -> None:
        self._prev, self._delta = None, None

    def apply(self, pre: PreprocessResult) -> PreprocessResult:
        if pre.times is None or pre.stamp_ns is None or pre.polish_cloud is None or pre.deskew:
            return pre  # nothing to deskew, or already done (the same cloud reached two inputs)
        motion = self.velocity(pre)
        if motion is None:
            out = copy.copy(pre)  # dataclasses.replace would run a waiting sampling (PreprocessResult.sample)
            out.deskew = "no velocity yet (first scan of the stream, after a gap or a failure)"
            return out
        return self.reg.deskew_scan(pre, motion)

    def velocity(self, pre: PreprocessResult) -> tuple[np.ndarray, float] | None:
        """The next scan of the stream (a raw ``PreprocessResult`` with its stamp) -> its velocity as the
        motion ``(T_prev_cur (4, 4), seconds)`` since the previous scan, or None (first scan, gap, failure)."""
        from deepbbs_ros.core.odometry import se3_power

        t0 = time.perf_counter()
        prev, self._prev = self._prev, pre
        if prev is None or pre.stamp_ns is None or prev.stamp_ns is None:
            return None
        dt = (pre.stamp_ns - prev.stamp_ns) * 1e-9
        if not 1e-3 < dt <= self.max_gap_s:
            self._delta = None
            return None
        T = None
        # the constant-velocity prediction, scaled to the stamp gap (none for a stream's first motion)
        pred = None if self._delta is None else se3_power(self._delta[0], dt / self._delta[1])
        if pred is not None:  # GICP from the prediction
            res = polish(pre.polish_cloud, prev.polish_cloud, pred, self.reg.config.registration)
            if res.applied and res.delta_trans_m <= GATE_TRANS and res.delta_rot_deg <= GATE_ROT_DEG:
                T = res.T_target_source
        if T is None:  # first motion, or GICP strayed: the wide basin of DeepBBS++ (+ its GICP stage)
            try:
                T = self.reg.register(pre, prev, T_init=pred).T_target_source
                self.deepbbs_calls += 1
            except RegistrationError:
                T = None
        self.last_ms = (time.perf_counter() - t0) * 1e3
        if T is None or np.linalg.norm(T[:3, 3]) / dt > self.max_speed:
            self._delta = None
            return None
        self._delta = (T, dt)
        return self._delta
