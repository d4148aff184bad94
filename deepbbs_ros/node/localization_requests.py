"""The requests the live localization takes from other threads (no ROS import): a map to build (:meth:`build`, on the
map input's thread), a relocalization (``~/relocalize``) and a pose hint (``/initialpose``, both on the executor
thread). Each only leaves a request under the lock; the worker thread's next scan applies them
(:meth:`_take_requests`), so that none waits for a registration.

:class:`LocalizationRequests` is a part of :class:`~deepbbs_ros.node.localization.NodeLocalization` (a mixin).
"""

from __future__ import annotations

import time

import numpy as np

from deepbbs_ros.errors import DeepBBSError, NodeError
from deepbbs_ros.node.inputs import Cloud
from deepbbs_ros.node.map_data import MapData


class LocalizationRequests:
    """A new map, a relocalization, a hint: left by any thread, applied on the worker thread (module docstring)."""

    def build(self, data: MapData) -> str:
        """Build the localizer over ``data`` (places, descriptors: seconds on a big map) and queue it for the next
        scan (the tracker starts searching). Returns the log line. Raises NodeError on a map the localizer refuses."""
        from deepbbs_ros.core.localization import MapLocalizer

        t0 = time.perf_counter()
        try:
            localizer = MapLocalizer(data.points, self.config, registration=self.registration,
                                     trajectory=data.trajectory)
        except DeepBBSError as err:
            raise NodeError(f"map from {data.source}: {err}") from err
        build_s = time.perf_counter() - t0
        with self._lock:
            self._pending_map = data
            self._pending_localizer = localizer
            self.map_build_s = build_s
        places = len(localizer.places)
        #: one line when the map's trajectory does not fit it (core/map_fit.py; the node logs it as a warning)
        self.map_warning = f"map from {data.source}: {localizer.trajectory_warning}" if (
            getattr(localizer, "trajectory_warning", "")) else ""
        fits = data.trajectory is not None and not self.map_warning
        how = "keyframes of its trajectory" if fits else "a grid over its free space"
        return (f"map from {data.source}: {len(data.points)} points in {data.frame_id!r}, {places} candidate places "
                f"({how}), built in {build_s:.1f} s")

    @property
    def has_map(self) -> bool:
        with self._lock:
            return self.tracker is not None or self._pending_map is not None

    def relocalize(self) -> None:
        """Forget the pose: the next scan searches the whole map (applied by the next :meth:`step`)."""
        with self._lock:
            self._relocalize = True

    def hint(self, T_map_base: np.ndarray, covariance: np.ndarray) -> None:
        """A pose hint (``/initialpose``: the base's pose in the map, (4, 4), and its (6, 6) covariance): the next
        :meth:`step` searches near it first (``MapTracker.hint``), then the whole map."""
        with self._lock:
            self._hint = (np.asarray(T_map_base, dtype=np.float64), np.asarray(covariance, dtype=np.float64))

    def _take_requests(self, cloud: Cloud) -> None:
        from deepbbs_ros.core.tracking import MapTracker

        with self._lock:
            data, self._pending_map = self._pending_map, None
            localizer, self._pending_localizer = self._pending_localizer, None
            relocalize, self._relocalize = self._relocalize, False
            hint, self._hint = self._hint, None
        if data is not None or relocalize:
            self._bridge.forget_until(cloud.stamp_ns - 1)  # scans before the request: not this search's
        if data is not None:
            self.map, self.localizer = data, localizer
            self.tracker = MapTracker(localizer, self.config)
            self._search_t0 = None
            self.first_pose_s = float("nan")
        elif relocalize and self.tracker is not None:
            self.tracker.reset()
            self._search_t0 = None
        if hint is not None and self.tracker is not None:
            self.tracker.hint(hint[0] @ self.extrinsic(cloud.frame_id), hint[1])  # the sensor's pose
            self._search_t0 = None
