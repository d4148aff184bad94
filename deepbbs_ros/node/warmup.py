"""The node's warm-up: every stage the first scans would run for the first time, run on a synthetic drive."""

from __future__ import annotations

import threading
import time
from typing import Any

from deepbbs_ros.node.inputs import Cloud, decode_cloud
from deepbbs_ros.node.pipeline import LocalMapOdometry, register_clouds


def warm_up(max_range: float, reg: Any, odometry: Any, odom_lock: threading.Lock, preprocess_on_arrival: bool) -> None:
    """Run what the first scans would run for the first time (PointCloud2 decoding, preprocessing, the
    precision stage's GICP, the network process, the odometry or pair path) on a synthetic drive, then
    forget it: the first real scans are answered at the node's usual speed.

    Args:
        max_range: the preprocessing's range (m); the drive reaches at most 60 m of it.
        reg: the node's registration (``preprocess``, ``register``).
        odometry: the odometry of odometry mode (stepped through the drive, then reset), None in pair mode (a pair
            registered from scratch, with the kept target state, and from a good start).
        odom_lock: held while the odometry steps.
        preprocess_on_arrival: the node's scans are preprocessed on arrival (the odometry's too).
    """
    from deepbbs_ros.replay.synthetic import synthetic_drive
    from msg_adapters.layouts import VELODYNE, build_cloud

    scans = synthetic_drive(3, motion_distortion=True, max_range=min(60.0, max_range))
    clouds = []
    for s in scans:
        p = s.points
        msg = build_cloud(VELODYNE, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2],
                                     "intensity": s.fields["intensity"], "time": s.fields["time"]},
                          stamp_ns=s.stamp_ns, frame_id="deepbbs_warmup")  # fmt: skip
        xyz, times, stamp_ns, frame = decode_cloud(msg, "warm-up", 3)
        clouds.append(Cloud(xyz, stamp_ns, frame, time.perf_counter(), times))
    if odometry is not None:
        with odom_lock:
            for c in clouds:
                if preprocess_on_arrival:
                    c.pp = reg.preprocess(c.xyz, c.times, c.stamp_ns)
                odometry.step(c)
            odometry.reset()
            if isinstance(odometry, LocalMapOdometry):
                odometry.consulted = odometry.won = 0
    else:
        for c in clouds[:2]:
            c.pp = reg.preprocess(c.xyz, c.times, c.stamp_ns)
        first = register_clouds(reg, clouds[1], clouds[0])
        register_clouds(reg, clouds[1], clouds[0])  # the kept target state's path too
        register_clouds(reg, clouds[1], clouds[0], T_init=first.T, good_start=True)  # the good-start path
