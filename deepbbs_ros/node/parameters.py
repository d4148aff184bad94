"""The node's parameters and what it loads from them (no node here): the config sections it declares, the check of
the names a user gives it, the frame ids, the weights and the registration it runs with.

Shared by :class:`~deepbbs_ros.node.registration_node.RegistrationNode`, the managed localizer and the GICP anchor.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from deepbbs_ros.config import Config
from deepbbs_ros.config import nearest_keys as nearest_parameter  # one did-you-mean for node, CLIs and YAML
from deepbbs_ros.errors import ConfigError, NodeError

#: the config sections the node reads (declared as ROS parameters); ``odometry`` too in odometry mode,
#: ``localization`` with ``node.target_mode: localization``. ``model`` comes from the checkpoint, ``train`` /
#: ``eval`` belong to deepbbs-train / deepbbs-replay.
NODE_SECTIONS = ("preprocess", "registration", "node")
#: sections of one mode only: in the other modes a params file's keys of them are one note, not warnings
MODE_SECTIONS = {"odometry": "used in node.mode odometry only",
                 "localization": "used in node.target_mode localization only"}
_NOT_NODE = {
    "model": "the model section comes from the checkpoint (registration.weights)",
    "train": "a deepbbs-train setting",
    "eval": "a deepbbs-replay setting",
    **MODE_SECTIONS,
}


def node_parameters(cfg: Config, mode: str, target_mode: str = "stamped") -> dict[str, Any]:
    """The parameters the node declares (dotted name -> value of ``cfg``) for ``mode``: every key of
    :data:`NODE_SECTIONS`, plus ``odometry.*`` in odometry mode and ``localization.*`` in pair mode with
    ``target_mode`` localization. New keys of these sections are picked up."""
    sections = NODE_SECTIONS + (("odometry",) if mode == "odometry" else ())
    if mode == "pair" and target_mode == "localization":
        sections += ("localization",)
    return {k: v for k, v in cfg.to_flat().items() if k.partition(".")[0] in sections}


def check_parameter_names(names: Any, used: dict[str, Any], flat: dict[str, Any],
                          mode: str) -> tuple[list[str], list[str], list[str]]:
    """(errors, warnings, notes) for parameter names given to the node that it does not declare.

    A name in a declared section that is not a config key (``node.mod``) is an error; a config key of a
    section the node does not use (``train.lr``) and any other unknown name (flat names such as ``mode``)
    are warnings naming the nearest declared parameter; ``odometry.*`` / ``localization.*`` in another mode (a
    params file for every mode) is one note per section. Flat names are not taken as aliases: ``voxel_size`` could
    be ``preprocess.voxel_size`` or ``odometry.voxel_size``."""
    sections = {k.partition(".")[0] for k in used}
    errors, warnings = [], []
    other_mode: dict[str, list[str]] = {}
    for name in sorted(names):
        if name in used:
            continue
        section = name.partition(".")[0]
        near = nearest_parameter(name, used)
        hint = f"; did you mean {' or '.join(near)}?" if near else ""
        if name in flat and section in MODE_SECTIONS:  # a params file for every mode: one line per section
            other_mode.setdefault(section, []).append(name)
        elif name in flat:
            why = _NOT_NODE.get(section, "not a node parameter")
            warnings.append(f"parameter {name} is ignored: {why}")
        elif "." in name and section in sections:
            errors.append(f"unknown parameter {name}{hint}")
        else:
            warnings.append(f"unknown parameter {name} is ignored (the node's parameters are dotted, "
                            f"e.g. node.mode){hint}")
    notes = [f"{len(keys)} {section}.* parameter(s) not used: {MODE_SECTIONS[section]} (node.mode={mode})"
             for section, keys in other_mode.items()]
    return errors, warnings, notes


def validate_frame(key: str, frame: str) -> None:
    if frame and (frame.startswith("/") or any(c.isspace() for c in frame)):
        raise NodeError(f"{key}: invalid frame id {frame!r} (no leading '/', no spaces)")


def check_weights(cfg: Config) -> Path:
    """The checkpoint the node will load; NodeError naming the path when it does not exist."""
    if cfg.registration.weights:
        path = Path(cfg.registration.weights).expanduser()
        if not path.is_file():
            raise NodeError(f"registration.weights: file not found: {path}")
        return path
    from deepbbs_ros.core.checkpoint import default_weights_path

    path = Path(default_weights_path())
    if not path.is_file():
        raise NodeError(
            f"registration.weights is '' (the shipped model) but {path} does not exist; "
            "train one with deepbbs-train or set registration.weights"
        )
    return path


def node_registration_config(cfg: Config) -> Config:
    """The config the node's DeepBBS++ runs with: in pair mode ``node.deep_passes`` network passes (when > 0) in
    place of ``registration.max_deep_iters`` and ``node.polish_max_voxels`` (when > 0) in place of
    ``registration.polish_max_voxels``; ``cfg`` itself elsewhere (and with ``node.target_mode: localization``: the
    global search is that of ``deepbbs-replay --mode localization``)."""
    if cfg.node.mode != "pair" or cfg.node.target_mode == "localization":
        return cfg
    rc, changes = cfg.registration, {}
    if cfg.node.deep_passes > 0 and cfg.node.deep_passes != rc.max_deep_iters:
        changes["max_deep_iters"] = cfg.node.deep_passes
    if cfg.node.polish_max_voxels > 0 and cfg.node.polish_max_voxels != rc.polish_max_voxels:
        changes["polish_max_voxels"] = cfg.node.polish_max_voxels
    if not changes:
        return cfg
    return dataclasses.replace(cfg, registration=dataclasses.replace(rc, **changes))


def load_registration(cfg: Config, log: Callable[[str], None] | None = None) -> tuple[Any, str]:
    """(registration, weights path) for the node: a DeepBBSRegistration, or in pair mode with
    ``node.registration_process`` its proxy (:class:`~deepbbs_ros.node.registration_process.RegistrationProcess`,
    the registration in a process of its own; ``log`` gets the line said if that process is lost). NodeError
    naming the parameter on a bad device, a missing checkpoint, or a registration process that does not start."""
    from deepbbs_ros.device import resolve_device
    from deepbbs_ros.errors import ModelError
    from deepbbs_ros.node import registration_process

    try:
        device = resolve_device(cfg.registration.device)
    except ConfigError as err:
        raise NodeError(str(err)) from err
    weights = str(check_weights(cfg))
    localization = cfg.node.mode == "pair" and cfg.node.target_mode == "localization"  # the localizer's: in-process
    if not localization and registration_process.wanted(cfg.node.registration_process, cfg.node.mode, device.type):
        try:
            return registration_process.RegistrationProcess(node_registration_config(cfg), weights, log), weights
        except ModelError as err:
            raise NodeError(f"node.registration_process: {err}") from err
    from deepbbs_ros.core.registration import DeepBBSRegistration

    reg = DeepBBSRegistration(node_registration_config(cfg), weights=weights)
    reg.warmup()  # the first registrations set up torch's kernels (seconds): before the first scan, not on it
    return reg, weights
