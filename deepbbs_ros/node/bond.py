"""The bond heartbeat ``nav2_lifecycle_manager`` waits for from each node it activates (ROS layer).

bondcpp's protocol, as Nav2's own servers run it from activate to deactivate: ``bond/msg/Status`` on the topic
``bond`` (relative: the node's namespace), ``id`` = the node's name, ``instance_id`` = a UUID of this side,
``active`` true every ``period`` s (0.1), ``heartbeat_timeout`` 4.0 s; breaking the bond publishes ``active`` false.
The manager's side is the status with the same ``id`` and another ``instance_id``. Needs the ``bond`` messages
(a ROS install, or ``deepbbs-ros build-interfaces``).
"""

from __future__ import annotations

import uuid
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile

from deepbbs_ros.node.destroyable import publisher_events, subscription_events

PERIOD_S = 0.1  # nav2_util::LifecycleNode's heartbeat period
TIMEOUT_S = 4.0  # and heartbeat timeout
TOPIC = "bond"


def available() -> bool:
    """Whether the bond messages import here."""
    try:
        from bond.msg import Status  # noqa: F401
    except ImportError:
        return False
    return True


class BondHeartbeat:
    """Publish the heartbeat of ``node`` (its name as the bond's id) until :meth:`close`."""

    def __init__(self, node: Any, period_s: float = PERIOD_S, timeout_s: float = TIMEOUT_S) -> None:
        from bond.msg import Status

        self._node, self._status = node, Status
        self.id, self.instance_id = node.get_name(), str(uuid.uuid4())
        self.period_s, self.timeout_s = period_s, timeout_s
        self.sister: str | None = None  # the other side's instance_id once heard (the manager's)
        self.sister_active = False
        # plain publisher and timer: the heartbeat is not a lifecycle output (bondcpp's QoS: keep last 5, reliable)
        self._pub = Node.create_publisher(node, Status, TOPIC, QoSProfile(depth=5),
                                          event_callbacks=publisher_events())
        self._sub = node.create_subscription(Status, TOPIC, self._on_status, QoSProfile(depth=100),
                                             event_callbacks=subscription_events())
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = node.create_timer(period_s, self._heartbeat, clock=steady)
        self._publish(True)

    def _heartbeat(self) -> None:
        self._publish(True)

    def _publish(self, active: bool) -> None:
        msg = self._status(id=self.id, instance_id=self.instance_id, active=active,
                           heartbeat_timeout=float(self.timeout_s), heartbeat_period=float(self.period_s))
        msg.header.stamp = Clock(clock_type=ClockType.STEADY_TIME).now().to_msg()
        self._pub.publish(msg)

    def _on_status(self, msg: Any) -> None:
        if msg.id == self.id and msg.instance_id != self.instance_id:
            self.sister, self.sister_active = msg.instance_id, bool(msg.active)

    def close(self) -> None:
        """Break the bond (``active`` false, as bondcpp's breakBond): the heartbeat and the subscription end; the
        publisher stays (destroyed with the node's other entities) so that the last status reaches the manager."""
        self._node.destroy_timer(self._timer)
        self._node.destroy_subscription(self._sub)
        self._publish(False)
