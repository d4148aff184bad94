"""The managed node's steps that make and release its parts: :class:`ManagedSteps` (``_configure``: the parts,
outputs and warm-up of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` made once per configure;
``_deactivate``: the subscriptions, publishers and bond of activate undone; ``_teardown``: the threads stopped,
the model closed and every entity configure made destroyed), a mixin of node/managed.py's ``LocalizerNode``.
"""

from __future__ import annotations

import time

from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.lifecycle.publisher import LifecyclePublisher

_ENTITIES = ("_publishers", "_subscriptions", "_services", "_clients", "_timers")
SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE


class ManagedSteps:
    """Configure, deactivate and teardown of the managed node (the transitions call them; see node/managed.py)."""

    def _configure(self) -> TransitionCallbackReturn:
        t_start = time.perf_counter()
        self._made = {k: list(getattr(self, k)) for k in _ENTITIES}
        registration, tf_broadcaster, remaps = self._given
        try:
            t_model = self._configure_parts(self._defaults, registration, "local_map", remaps, t_start)
            self._create_outputs(tf_broadcaster)
            t_warm = time.perf_counter()
            self._warm()
        except BaseException:
            self._teardown(None)
            raise
        t_end = time.perf_counter()
        self._configured = True
        self.startup_s = t_end - t_start
        self.get_logger().info(f"inactive: configured in {self.startup_s:.1f} s (model {t_model:.1f} s, warm-up "
                               f"{t_end - t_warm:.1f} s); activate to subscribe to the inputs")
        return SUCCESS

    def _deactivate(self, state: LifecycleState) -> None:
        if self._active:
            if self.bond is not None:
                self.bond.close()
                self.bond = None
            for sub in self._activated:
                self.destroy_subscription(sub)
            self._activated = self._subs = []
            LifecycleNodeMixin.on_deactivate(self, state)  # the lifecycle publishers off
            self._active = False

    def _teardown(self, line: str | None) -> None:
        """Stop the threads, close the node's own model, destroy what configure made; ``line`` logged after the
        counts (None: a configure that failed halfway, nothing logged)."""
        if self._made is None:
            if line is not None:
                self.get_logger().info(line)
            return
        if line is not None and self._configured:
            self._release()  # the threads stopped, the counts logged, the model closed
        else:
            for inp in getattr(self, "inputs", []):
                inp.stop()
            for part in ("worker", "localization"):
                if getattr(self, part, None) is not None:
                    getattr(self, part).stop()
            if getattr(self, "_owns_reg", False) and hasattr(getattr(self, "reg", None), "close"):
                self.reg.close()
        for kind in _ENTITIES:
            for entity in [e for e in getattr(self, kind) if e not in self._made[kind]]:
                if isinstance(entity, LifecyclePublisher):
                    self.destroy_lifecycle_publisher(entity)
                else:
                    getattr(self, "destroy_" + kind[1:-1])(entity)
        self._made, self._configured = None, False
        self.reg = self.localization = self.odometry = self._map_file = None
        if line is not None:
            self.get_logger().info(line)
