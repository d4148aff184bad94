"""The QoS profiles of the node's subscriptions (the inputs, a latched map, TF) and their one-line text."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def input_qos(ncfg) -> QoSProfile:
    """A new QoS profile from ``node.qos_reliability`` / ``node.qos_depth`` (``ncfg``: the ``node`` section)."""
    return QoSProfile(
        depth=ncfg.qos_depth,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.BEST_EFFORT
        if ncfg.qos_reliability == "best_effort"
        else ReliabilityPolicy.RELIABLE,
    )


def reliable_qos(depth: int, durability: DurabilityPolicy) -> QoSProfile:
    """Reliable, keep last ``depth``: TF (``/tf_static`` transient local as robot_state_publisher latches it,
    ``/tf`` volatile) and a latched map."""
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                      durability=durability)


def latched_qos() -> QoSProfile:
    """A map server's QoS: reliable, transient local (the map published once reaches late joiners)."""
    return reliable_qos(1, DurabilityPolicy.TRANSIENT_LOCAL)


def qos_text(qos: QoSProfile) -> str:
    """``reliable/5`` or ``best_effort/5`` (reliability / history depth)."""
    rel = "reliable" if qos.reliability == ReliabilityPolicy.RELIABLE else "best_effort"
    return f"{rel}/{qos.depth}"
