"""The registration node's TF inputs: ``/tf_static`` (``T_base_sensor``) and, in localization mode with
``node.localization_odom: tf``, ``/tf`` into its :class:`~deepbbs_ros.node.tf_buffer.TransformBuffer`.

:class:`NodeTf` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin).
"""

from __future__ import annotations

import time

from rclpy.qos import DurabilityPolicy

from deepbbs_ros.errors import TransformFormatError
from deepbbs_ros.node.inputs import BadInput
from deepbbs_ros.node.qos import reliable_qos
from deepbbs_ros.node.tf_static import BAD_MOUNT, unusable_mount
from msg_adapters.transforms import invert


class NodeTf:
    """``T_base_sensor`` from ``/tf_static``; the TF subscriptions."""

    def _subscribe_tf_static(self):
        """Subscribe ``/tf_static`` (transient local, as robot_state_publisher latches it) where odometry mode
        needs ``T_base_sensor``; None elsewhere, or without tf2_msgs (then the base frame moves as the sensor)."""
        ncfg = self.cfg.node
        if (ncfg.mode != "odometry" and self.localization is None) or not ncfg.base_frame:
            return None
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warning(
                f"tf2_msgs is not installed: no /tf_static lookup of {ncfg.base_frame} <- the cloud frame "
                "(identity used); build it with `deepbbs-ros build-interfaces`"
            )
            return None
        qos = reliable_qos(100, DurabilityPolicy.TRANSIENT_LOCAL)
        return self.create_subscription(TFMessage, "/tf_static", self._on_tf_static, qos)

    def _subscribe_tf(self):
        """Localization mode with ``node.localization_odom: tf``: ``/tf`` into the TF buffer (``odom -> base`` at
        each scan's stamp); None without tf2_msgs."""
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            return None
        qos = reliable_qos(100, DurabilityPolicy.VOLATILE)
        return self.create_subscription(TFMessage, "/tf", self._on_tf, qos)

    def _on_tf_static(self, msg) -> None:
        self._add_transforms("/tf_static", self.static_tf.add_message, msg)

    def _on_tf(self, msg) -> None:
        self._add_transforms("/tf", self.static_tf.add_dynamic_message, msg)

    def _add_transforms(self, topic: str, add, msg) -> None:
        """The usable transforms of ``msg`` into the TF buffer; each malformed one (zero quaternion, NaN, no frame
        names, a frame its own parent) is a rate-limited warning ``bad_transform`` naming its frames."""
        rejected: list[str] = []
        add(msg, rejected)
        for why in rejected:
            self._warnings.log("bad_transform", f"{topic}: transform {why}: ignored")

    def _base_from_sensor(self, frame: str):
        """``T_base_sensor`` for a cloud in ``frame`` (odometry and localization, on the worker thread): looked up
        on ``/tf_static`` for every scan (a transform published again is used from then on, with one log line). The
        first scan waits for it until ``node.tf_timeout`` s after the subscription was made (during start-up: the
        model and the warm-up usually take longer, so a running robot_state_publisher's transform is there before
        the first scan and nothing waits), then the identity is used with one warning until it arrives. A transform
        the node cannot compose poses with (it or its inverse is not finite: a finite but absurd translation such as
        1e308 m) is :class:`BadInput` ``bad_tf_static`` (one rate-limited error line naming the frames): the scan's
        outputs are withheld, the odometry goes on, until a usable transform arrives."""
        import numpy as np

        base = self.cfg.node.base_frame
        if not base or base == frame:
            return np.eye(4)
        known = self._extrinsics.get(frame)
        if known is None:
            left = self._t_tf + self.cfg.node.tf_timeout - time.monotonic()
            T = self.static_tf.wait(base, frame, max(0.0, left))
        else:
            T = self.static_tf.lookup(base, frame)
        if T is None:
            if known is None:
                self._extrinsics[frame] = (np.eye(4), False)
                self.get_logger().warning(
                    f"no transform {base} <- {frame} on /tf_static within node.tf_timeout={self.cfg.node.tf_timeout} "
                    f"s: publishing the sensor's {'pose' if self.localization is not None else 'motion'} as {base}'s "
                    "(identity); publish it (robot_state_publisher) "
                    "or set -p \"node.base_frame:=''\" to use the cloud frame"
                )
            return self._extrinsics[frame][0]
        try:
            invert(T)  # the node composes every pose with T and its inverse
        except TransformFormatError as err:
            raise BadInput(BAD_MOUNT, unusable_mount(base, frame, str(err))) from err
        if known is None or not known[1] or not np.array_equal(known[0], T):
            self._extrinsics[frame] = (T, True)
            t, log = T[:3, 3], self.get_logger().info
            log(f"{base} <- {frame} from /tf_static: translation [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] m; "
                f"publishing the {'pose' if self.localization is not None else 'motion'} of {base}"
                + (" from now on" if known is not None else ""))
        return T

