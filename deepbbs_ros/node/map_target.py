"""The latched map target of pair mode (no ROS import): :class:`MapTarget` registers every source against the latest
map, cropped around the current estimate, and answers in the map frame (see :mod:`deepbbs_ros.node.pipeline`)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.inputs import BadInput, Cloud
from deepbbs_ros.node.pair_registration import Registered, register_clouds

#: latched target: the map is cropped again once the estimate moved this share of the crop radius from its centre
RECROP_SHARE = 0.2


def pose_from_xyzrpy(values: Any) -> np.ndarray:
    """``[x, y, z, roll, pitch, yaw]`` (m, rad; ``R = Rz(yaw) Ry(pitch) Rx(roll)``) -> (4, 4) float64."""
    from scipy.spatial.transform import Rotation

    x, y, z, roll, pitch, yaw = (float(v) for v in values)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


@dataclass
class _Crop:
    map_id: int
    T_map_crop: np.ndarray  # the estimate the crop is centred on
    cloud: Cloud  # the cropped map in the crop frame, preprocessed


class MapTarget:
    """A latched, static target (a map or any reference cloud, ``node.target_mode: latched``).

    The latest map (:meth:`set_map`, raw points in the map frame) pairs with every source, with no stamp
    matching. For each source the map is cropped around the current estimate ``T_map_sensor`` (points within
    ``node.map_crop_radius``, default ``preprocess.max_range``), expressed in that estimate's frame and
    preprocessed like a scan (kept until the estimate moves ``RECROP_SHARE`` of the radius); the source is
    registered against the crop from the estimate, and the answer ``T_map_source`` is the next estimate.
    The first estimate is ``node.initial_pose`` (and again after :meth:`reset`). A valid answer is the next source's
    good start (``register(..., good_start=True)``, ``node.good_start``); the initial pose and the pose before a
    rejected answer get the full pipeline.
    """

    def __init__(self, config: Any) -> None:
        self.config = config
        self._lock = threading.Lock()
        self.map: Cloud | None = None
        self._crop: _Crop | None = None
        self.reset()

    def reset(self) -> None:
        """The next source starts from ``node.initial_pose`` again."""
        with self._lock:
            self.T_map_sensor = pose_from_xyzrpy(self.config.node.initial_pose)
            self._answered = False  # the estimate is the last valid answer (a good start), not the initial pose

    def set_map(self, cloud: Cloud) -> None:
        with self._lock:
            self.map, self._crop = cloud, None

    def _crop_at(self, registration: Any, map_cloud: Cloud, T_map_c: np.ndarray) -> _Crop:
        radius = self.config.node.map_crop_radius or self.config.preprocess.max_range
        pts = np.asarray(map_cloud.xyz, dtype=np.float64)
        local = (pts - T_map_c[:3, 3]) @ T_map_c[:3, :3]  # inv(T_map_c) applied to the map points
        local = local[np.einsum("ij,ij->i", local, local) <= radius * radius].astype(np.float32)
        if len(local) < self.config.node.min_points:
            raise BadInput("registration_failed",
                           f"target (map): {len(local)} points within {radius:.1f} m of the estimate "
                           f"[{T_map_c[0, 3]:.1f}, {T_map_c[1, 3]:.1f}, {T_map_c[2, 3]:.1f}] "
                           "(node.initial_pose / node.map_crop_radius; ~/reset restarts there)")
        try:
            pp = registration.preprocess(local)
        except RegistrationError as err:
            raise BadInput("preprocess_failed", f"target (map) crop: {err}") from err
        return _Crop(id(map_cloud), T_map_c.copy(),
                     Cloud(local, map_cloud.stamp_ns, map_cloud.frame_id, map_cloud.t_recv, pp=pp))

    def register(self, registration: Any, source: Cloud) -> tuple[Registered, np.ndarray]:
        """(``Registered`` with ``T = T_map_source``, the crop's preprocessed points (M, 3) in the map frame).

        Raises:
            BadInput: no map yet, too few map points around the estimate, or the registration failed.
        """
        with self._lock:
            map_cloud, T_start, crop = self.map, self.T_map_sensor.copy(), self._crop
            good = self._answered and self.config.node.good_start
        if map_cloud is None:
            raise BadInput("no_target", "no target (map) received yet")
        radius = self.config.node.map_crop_radius or self.config.preprocess.max_range
        timings: dict[str, float] = {}
        if (crop is None or crop.map_id != id(map_cloud)
                or np.linalg.norm(T_start[:3, 3] - crop.T_map_crop[:3, 3]) > RECROP_SHARE * radius):
            t0 = time.perf_counter()
            crop = self._crop_at(registration, map_cloud, T_start)
            timings["map_crop"] = (time.perf_counter() - t0) * 1e3
        T_init = np.linalg.inv(crop.T_map_crop) @ T_start
        reg = register_clouds(registration, source, crop.cloud, T_init=T_init, good_start=good)
        T_map_source = crop.T_map_crop @ reg.T
        with self._lock:
            if self.map is map_cloud:
                self._crop = crop
                if getattr(reg.result, "valid", True):  # a pose the verdict rejects is not the next start
                    self.T_map_sensor = T_map_source.copy()
                    self._answered = True
                else:  # nor a good one: the next source gets the full pipeline from the last valid pose
                    self._answered = False
        reg.timings_ms.update(timings)
        pts = getattr(crop.cloud.pp, "points", None)
        pts_map = None if pts is None else (np.asarray(pts, np.float64) @ crop.T_map_crop[:3, :3].T
                                            + crop.T_map_crop[:3, 3])
        return Registered(T_map_source, reg.result, reg.timings_ms), pts_map
