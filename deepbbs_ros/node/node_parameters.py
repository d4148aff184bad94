"""The registration node's ROS parameters: declared from the config's sections and read back as the node's config
(names it does not use reported), and refused once the node runs (a restart changes them).

:class:`NodeParameters` is a part of :class:`~deepbbs_ros.node.registration_node.RegistrationNode` (a mixin); what
the parameters are (no node) is :mod:`deepbbs_ros.node.parameters`.
"""

from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError, NodeError
from deepbbs_ros.node.parameters import check_parameter_names, node_parameters, validate_frame


class NodeParameters:
    """Declare and read the node's parameters."""

    def _declare_config(self, defaults: Config) -> Config:
        """Declare the parameters of :data:`NODE_SECTIONS` (and ``odometry.*`` in odometry mode), read them
        and return the config (the other sections keep ``defaults``). Names the node does not use are
        reported (:func:`check_parameter_names`): a misspelt name in a declared section is a NodeError, any
        other unknown or unused name a warning naming the nearest parameter."""
        flat = defaults.to_flat()
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        mode = overrides["node.mode"].value if "node.mode" in overrides else defaults.node.mode
        target = overrides["node.target_mode"].value if "node.target_mode" in overrides else defaults.node.target_mode
        used = node_parameters(defaults, mode, target)
        ignore = [n for n in overrides if n not in used and (self.has_parameter(n) or n.startswith("qos_overrides."))]
        if not any(self.has_parameter(k) for k in used):  # the first time (the managed node reads them again)
            errors, warnings, notes = check_parameter_names([n for n in overrides if n not in ignore], used, flat, mode)
            if errors:
                raise NodeError("; ".join(errors))
            for text in warnings:
                self.get_logger().warning(text)
            for text in notes:
                self.get_logger().info(text)
            self.parameter_warnings = warnings
        for key, value in used.items():
            if not self.has_parameter(key):
                self.declare_parameter(key, value, ParameterDescriptor(name=key, dynamic_typing=True))
        values = {k: self.get_parameter(k).value for k in used}
        try:
            return Config.from_flat({**flat, **values})
        except ConfigError as err:
            raise NodeError(str(err)) from err

    def _on_set_parameters(self, params) -> SetParametersResult:
        declared = node_parameters(self.cfg, self.cfg.node.mode, self.cfg.node.target_mode)
        ours = [p.name for p in params if p.name in declared]
        if ours:
            return SetParametersResult(successful=False, reason=f"restart the node to change {', '.join(ours)}")
        return SetParametersResult(successful=True)


def check_frames(ncfg) -> None:
    """The frame ids of the ``node`` section (``ncfg``) are valid and ``node.odom_frame`` is not empty (NodeError)."""
    validate_frame("node.odom_frame", ncfg.odom_frame)
    validate_frame("node.base_frame", ncfg.base_frame)
    validate_frame("node.map_frame", ncfg.map_frame)
    if not ncfg.odom_frame:
        raise NodeError("node.odom_frame: must not be empty")
