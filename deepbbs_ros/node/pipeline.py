"""The node's pipeline, run on the registration worker thread (no ROS import).

* :func:`register_clouds`: one pair of preprocessed :class:`~deepbbs_ros.node.inputs.Cloud` s ->
  ``T_target_source``, the registration result and its timings.
* :class:`LocalMapOdometry` (odometry mode, the default): one :meth:`~LocalMapOdometry.step` per scan runs
  :class:`deepbbs_ros.core.odometry.DeepBBSOdometry`, the pipeline of ``deepbbs-replay --mode odometry
  --method deepbbs++`` (deskew + GICP against a local voxel map, DeepBBS++ consulted on long stamp gaps, fit
  drops and the first motion), on the raw points, per-point times and stamp of each scan.
* :class:`MapTarget` (pair mode, ``node.target_mode: latched``): every source against the latest map, cropped
  around the current estimate (the last answer; ``node.initial_pose`` at first), answered in the map frame.
* :class:`ScanToScanOdometry` (``RegistrationNode(odometry_method="scan_to_scan")``, the GICP anchor):
  ``T_odom_k = T_odom_{k-1} @ T_{k-1}_k`` (CONVENTIONS.md), every scan preprocessed once (on arrival) and
  kept as the next scan's target.

Both return an :class:`OdometryEstimate`, everything the outputs need (pose, twist, covariances), from
``step(cloud)``, and restart at identity on ``reset()``; ``RegistrationNode._make_odometry`` picks one.
The cloud gives them the raw points ``cloud.xyz``, the per-point times ``cloud.times`` (s since the stamp,
or None), ``cloud.stamp_ns``, and the preprocessed ``cloud.pp`` (computed on arrival for scan-to-scan
only; None for the local map, which preprocesses for DeepBBS++ itself, only when it consults it).

Modules: :mod:`~deepbbs_ros.node.pair_registration` (:func:`register_clouds`, :class:`PairStart`),
:mod:`~deepbbs_ros.node.odometry_pipeline` (both odometries: the scan-to-scan one in
:mod:`~deepbbs_ros.node.scan_to_scan`, their estimate in :mod:`~deepbbs_ros.node.odometry_estimate`),
:mod:`~deepbbs_ros.node.map_target` (:class:`MapTarget`); every name is imported from here too.
"""

from __future__ import annotations

from deepbbs_ros.node.map_target import RECROP_SHARE, MapTarget, pose_from_xyzrpy
from deepbbs_ros.node.odometry_pipeline import (
    SCAN_FLOOR_SHARE,
    LocalMapOdometry,
    OdometryEstimate,
    ScanToScanOdometry,
    motion_twist,
)
from deepbbs_ros.node.pair_registration import (
    UNKNOWN_TWIST_COV,
    PairStart,
    Registered,
    register_clouds,
    registration_covariance,
    takes_good_start,
)

__all__ = [
    "RECROP_SHARE", "SCAN_FLOOR_SHARE", "UNKNOWN_TWIST_COV", "LocalMapOdometry", "MapTarget", "OdometryEstimate",
    "PairStart", "Registered", "ScanToScanOdometry", "motion_twist", "pose_from_xyzrpy", "register_clouds",
    "registration_covariance", "takes_good_start",
]
