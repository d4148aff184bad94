"""The managed (lifecycle) localization node ``deepbbs_localizer`` (console script ``deepbbs-localizer``).

The same node as ``deepbbs-node`` (:class:`~deepbbs_ros.node.registration_node.RegistrationNode`: the same parameters,
inputs and outputs), driven through the ROS 2 node lifecycle the way ``nav2_lifecycle_manager`` drives Nav2's
servers (``<node>/change_state``, ``<node>/get_state``; lifecycle_msgs), with ``node.target_mode: localization``
by default:

* constructed (unconfigured): the parameters are declared (set them now, or with a params file);
* **configure**: read the parameters, load the map (``localization.map_path``) and the model, start the pipeline's
  threads, create the publishers, services and the diagnostics timer, warm up. A missing or bad map or model is
  one error line and FAILURE: the node stays unconfigured, serves its lifecycle services and can be configured
  again (after ``ros2 param set`` of the parameter named);
* **activate**: subscribe to the inputs, publishers on;
* **deactivate**: unsubscribe, publishers off (nothing answered or published); the map, the model and the
  tracker's state stay;
* **cleanup**: stop the threads, release the map and the model, destroy what configure made (back to
  unconfigured; the parameters stay and may be changed);
* **shutdown** (from any state) and **error** processing: release everything as cleanup does.

Parameters of the node's own sections can be changed while unconfigured; in the other states a change is refused
naming the transitions that allow it.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.node.bond import BondHeartbeat
from deepbbs_ros.node.bond import available as bond_available
from deepbbs_ros.node.destroyable import publisher_events, subscription_events
from deepbbs_ros.node.managed_steps import FAILURE, SUCCESS, ManagedSteps
from deepbbs_ros.node.outputs import TfBroadcaster
from deepbbs_ros.node.parameters import node_parameters
from deepbbs_ros.node.registration_node import RegistrationNode
from deepbbs_ros.node.run import run_node

NODE_NAME = "deepbbs_localizer"  # Nav2's naming: the name lifecycle_manager's node_names lists


def localizer_defaults(cfg: Config | None = None) -> Config:
    """``cfg`` (default ``Config()``) with ``node.target_mode: localization`` where it is pair mode's default,
    ``stamped``: the managed node localizes unless told otherwise."""
    cfg = cfg or Config()
    if cfg.node.mode == "pair" and cfg.node.target_mode == "stamped":
        return cfg.replace(**{"node.target_mode": "localization"})
    return cfg


class LocalizerNode(LifecycleNodeMixin, ManagedSteps, RegistrationNode):
    """See the module docstring (configure, deactivate and teardown: node/managed_steps.py). Args as
    :class:`RegistrationNode` (``registration`` given: used at every configure and never closed by the node)."""

    def __init__(
        self,
        config: Config | None = None,
        *,
        registration: Any = None,
        tf_broadcaster: TfBroadcaster | None = None,
        node_name: str = NODE_NAME,
        remaps: Any = (),
        **node_kwargs: Any,
    ) -> None:
        Node.__init__(self, node_name, **node_kwargs)
        LifecycleNodeMixin.__init__(self)
        self._defaults = localizer_defaults(config)
        self._given = (registration, tf_broadcaster, remaps)
        self._made: dict[str, list] | None = None  # the entities that existed before configure (None: unconfigured)
        self._active = self._configured = False
        self._activated: list = []  # the subscriptions activate made
        self.bond: BondHeartbeat | None = None  # the heartbeat to nav2_lifecycle_manager while active
        self._declare_config(self._defaults)  # declared now, read at each configure (as Nav2's servers do)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info("unconfigured: waiting for the configure transition (a lifecycle manager, or "
                               f"`ros2 lifecycle set {self.get_fully_qualified_name()} configure`)")

    # -- transitions (the executor's thread; rclpy turns an exception into ERROR without a word: logged here) -----
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("configure", self._configure)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        def activate() -> None:
            before = list(self._subscriptions)
            self._subscribe()  # every subscription it makes is undone by deactivate
            self._activated = [sub for sub in self._subscriptions if sub not in before]
            LifecycleNodeMixin.on_activate(self, state)  # the lifecycle publishers on
            self._active = True
            self.bond = BondHeartbeat(self) if bond_available() else None  # what Nav2's manager waits for
            if self.bond is None:
                self.get_logger().warning("no bond heartbeat: the bond messages are not installed (deepbbs-ros "
                                          "build-interfaces); a lifecycle manager with bond_timeout > 0 gives up")
            self.get_logger().info("active")

        return self._transition("activate", activate)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        def deactivate() -> None:
            self._deactivate(state)
            self.get_logger().info("inactive: inputs unsubscribed, nothing published; the map is kept")

        return self._transition("deactivate", deactivate)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("cleanup", lambda: self._teardown("unconfigured: map and model released"))

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        def shutdown() -> None:
            self._deactivate(state)
            self._teardown("finalized")

        return self._transition("shutdown", shutdown)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        def recover() -> None:
            self._deactivate(state)
            self._teardown("unconfigured after an error: everything released")

        return self._transition("error processing", recover)

    def _transition(self, name: str, step: Callable[[], Any]) -> TransitionCallbackReturn:
        try:
            result = step()
        except DeepBBSError as err:  # a user's mistake (a missing map, a bad parameter): one line
            self.get_logger().error(f"{name} failed: {err}")
            return FAILURE
        except Exception as err:  # noqa: BLE001 - a bug: one line and the trace at debug level
            self.get_logger().error(f"{name} failed: unexpected {type(err).__name__}: {err}")
            self.get_logger().debug("".join(traceback.format_exception(err)))
            return FAILURE
        return result if isinstance(result, TransitionCallbackReturn) else SUCCESS

    # -- the node's outputs are lifecycle publishers: on while active -------------------------------------------
    def create_publisher(self, *args: Any, **kwargs: Any):
        if getattr(self, "_made", None) is not None:  # during configure (rclpy's own publishers stay plain)
            kwargs.setdefault("event_callbacks", publisher_events())
            return self.create_lifecycle_publisher(*args, **kwargs)
        return Node.create_publisher(self, *args, **kwargs)

    def create_subscription(self, *args: Any, **kwargs: Any):
        if getattr(self, "_made", None) is not None:  # destroyed again by deactivate / cleanup
            kwargs.setdefault("event_callbacks", subscription_events())
        return super().create_subscription(*args, **kwargs)  # guarded (node/callbacks.py)

    def _on_set_parameters(self, params) -> SetParametersResult:
        if not self._configured:
            return SetParametersResult(successful=True)  # read at the next configure
        declared = node_parameters(self.cfg, self.cfg.node.mode, self.cfg.node.target_mode)
        ours = [p.name for p in params if p.name in declared]
        if ours:
            return SetParametersResult(successful=False, reason=f"deactivate and clean up the node, then configure "
                                       f"it again, to change {', '.join(ours)}")
        return SetParametersResult(successful=True)

    def destroy_node(self):
        self._deactivate(LifecycleState("active", 3))
        self._teardown("stopped")
        return Node.destroy_node(self)


@cli_entry("deepbbs-localizer")
def main(argv: list[str] | None = None) -> int:
    """``deepbbs-localizer [--config YAML] [--ros-args ...]``: run until Ctrl-C, unconfigured until told."""
    return run_node(argv, "deepbbs-localizer", "Managed (lifecycle) DeepBBS++ localization node: configure loads "
                    "the map and the model, activate subscribes to the scans (nav2_lifecycle_manager, or "
                    "`ros2 lifecycle set`).", LocalizerNode)


if __name__ == "__main__":
    import sys

    sys.exit(main())
