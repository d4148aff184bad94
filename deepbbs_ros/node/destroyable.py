"""Entities a node destroys while an executor may be spinning (ROS layer): a managed node's inputs and outputs at
deactivate and cleanup, the bond's subscription when the bond breaks.

rclpy's executor still adds a destroyed entity's QoS-event handlers to its wait set, and the spinning thread dies
with ``InvalidHandle`` (ros2/rclpy#1142). Such an entity is therefore created with no QoS-event handlers (the
``event_callbacks`` below); what is lost is rclpy's "incompatible QoS" warning on it.
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks


def publisher_events() -> PublisherEventCallbacks:
    """``event_callbacks`` of a publisher the node may destroy while spinning: no handlers."""
    return PublisherEventCallbacks(use_default_callbacks=False)


def subscription_events() -> SubscriptionEventCallbacks:
    """``event_callbacks`` of a subscription the node may destroy while spinning: no handlers."""
    return SubscriptionEventCallbacks(use_default_callbacks=False)
