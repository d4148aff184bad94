"""A node input's message made a cloud: :class:`Cloud` (the decoded, checked and preprocessed points),
:func:`decode_cloud` (PointCloud2 -> valid xyz, per-point times, stamp, frame) and :class:`BadInput`, the
rejection every input and pair check raises (no ROS import). The threads that call them: node/inputs.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.datasets.base import time_field, time_offsets
from deepbbs_ros.errors import PointCloudFormatError


class BadInput(Exception):
    """A message or pair the node rejects; ``kind`` names the error class in logs and /diagnostics."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass
class Cloud:
    """A decoded, checked and preprocessed input cloud.

    Attributes:
        xyz: (N, 3) float32 valid points, sensor frame ``frame_id``, metres.
        times: (N,) float64 per-point time offsets from the stamp, seconds, from the driver's time field
            (``datasets.base.time_field``: Velodyne ``time``, Ouster ``t``, Livox / Hesai absolute ``timestamp``);
            None when the cloud has no time field. The local-map odometry
            deskews with its velocity; with ``node.pair_deskew`` each input of pair mode follows its
            topic's velocity (``core.deskew.StreamDeskew``) and deskews the scan's GICP cloud with it.
        stamp_ns: ``header.stamp`` in nanoseconds.
        frame_id: ``header.frame_id`` (never empty).
        t_recv: ``time.perf_counter()`` when the message reached the node's callback.
        pp: what ``registration.preprocess(xyz)`` returned (a PreprocessResult for DeepBBS++); None when
            the input does not preprocess (local-map odometry: DeepBBS++ preprocesses only when consulted).
        t_ready: ``time.perf_counter()`` when preprocessing finished.
        timings_ms: ``input_wait`` (callback -> input thread), ``decode``, ``preprocess`` (absent on a
            cache hit).
        driver: the driver that publishes the topic (``node.drivers.recognise``, from its first message), or None.
    """

    xyz: np.ndarray
    stamp_ns: int
    frame_id: str
    t_recv: float
    times: np.ndarray | None = None
    pp: Any = None
    t_ready: float = 0.0
    timings_ms: dict[str, float] = field(default_factory=dict)
    driver: str | None = None


def decode_cloud(msg: Any, topic: str, min_points: int) -> tuple[np.ndarray, np.ndarray | None, int, str]:
    """PointCloud2 (rclpy or rosbags) -> ((N, 3) float32 valid xyz, (N,) float64 per-point times in
    seconds since the stamp or None, stamp ns, frame id).

    The points are read through a structured dtype over the message buffer (no copy of the buffer,
    :func:`msg_adapters.pointcloud2.pointcloud2_to_arrays`); only the valid points are copied out.
    Times come from the cloud's time field (``datasets.base.time_field``: Velodyne ``time`` s, Ouster ``t`` ns,
    Livox / Hesai absolute ``timestamp``, read as ``Scan.point_times`` reads it), as seconds since the stamp.

    A time field with the same value for every point (e.g. all 0) gives None: it carries no timing.

    Raises:
        BadInput: ``empty_cloud``, ``malformed_cloud``, ``no_valid_points``, ``too_few_points``
            (fewer than ``min_points`` valid points) or ``missing_frame``, with ``topic`` in the message.
    """
    from msg_adapters.pointcloud2 import field_names, pointcloud2_to_arrays

    if int(msg.width) * int(msg.height) == 0 and len(msg.data) == 0:
        raise BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0, no data)")
    declared = set(field_names(msg))
    tname = time_field(declared)
    try:
        arr = pointcloud2_to_arrays(msg, (tname,) if tname else ())
    except PointCloudFormatError as err:
        raise BadInput("malformed_cloud", f"{topic}: {err}") from err
    n_decl = int(msg.width) * int(msg.height)
    n = int(arr.xyz.shape[0])
    if n_decl == 0:
        raise BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0)")
    if n == 0:
        raise BadInput("no_valid_points", f"{topic}: none of the {n_decl} points is finite (NaN-only cloud)")
    if n < min_points:
        raise BadInput("too_few_points", f"{topic}: {n} valid points, fewer than node.min_points={min_points}")
    if not arr.frame_id:
        raise BadInput("missing_frame", f"{topic}: header.frame_id is empty")
    times = None
    if tname is not None:
        raw = arr.fields[tname]
        # a count > 1 time field is not a per-point time; one value for every point (a driver without per-point
        # timing writes 0) says nothing about when each point was measured: no times, as without the field
        if raw.ndim == 1 and raw.min() != raw.max():
            times = time_offsets(tname, raw, int(arr.stamp_ns))
    return arr.xyz, times, int(arr.stamp_ns), arr.frame_id
