"""The registration node's services: ``~/reset`` (odometry at identity, synchroniser and frame memory cleared)
and, in localization mode, ``~/relocalize`` (std_srvs/Trigger).

:class:`NodeServices` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin).
"""

from __future__ import annotations


class NodeServices:
    """The node's std_srvs/Trigger services."""

    def _on_reset(self, request, response):
        self.sync.reset()
        for inp in self.inputs:
            inp.reset()
        if self.odometry is not None:
            with self._odom_lock:
                self.odometry.reset()
                self._last_odom_stamp = None
        if self._map_target is not None:
            self._map_target.reset()
        if self.localization is not None:
            self.localization.relocalize()
        self._pair_start.reset()
        response.success = True
        response.message = "odometry restarted at identity; synchroniser and frame memory cleared"
        self.get_logger().info(response.message)
        return response

    def _on_relocalize(self, request, response):
        """``~/relocalize``: forget the pose; the next scan searches the whole map."""
        self.localization.relocalize()
        response.success = True
        response.message = "pose forgotten: the next scan searches the whole map"
        self.get_logger().info(f"~/relocalize: {response.message}")
        return response
