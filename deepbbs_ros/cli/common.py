"""Shared CLI plumbing: known errors become one line and exit code 1 (:func:`cli_entry`, defined in
:mod:`deepbbs_ros.entry` so that the node shares it without importing the CLI layer); every option's
default shown once in ``--help`` (:class:`HelpFormatter`, :func:`config_default`); DDS stays on loopback
(:func:`local_ros_env`)."""

from __future__ import annotations

import argparse
import os

from deepbbs_ros.entry import cli_entry

__all__ = ["HelpFormatter", "RawHelpFormatter", "cli_entry", "config_default", "local_ros_env"]


class HelpFormatter(argparse.HelpFormatter):
    """``--help`` that shows each option's default once: ``(default: X)`` is added when the option has a
    value of its own (not None, False or empty) and its help does not already say its default. An option
    whose default is None writes its real default in its help (``config_default`` for config keys)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (not action.option_strings or "default" in text.lower() or default is None or default is False
                or default is argparse.SUPPRESS or default == [] or default == ""):
            return text
        return text + " (default: %(default)s)"


class RawHelpFormatter(argparse.RawDescriptionHelpFormatter, HelpFormatter):
    """:class:`HelpFormatter` whose description and epilog keep their line breaks (examples)."""


def config_default(key: str, unit: str = "") -> str:
    """``"eval.stride = 100"``: a dotted config key and its built-in value, for help texts of options that
    default to the config (a ``--config`` file may change the value)."""
    from deepbbs_ros.config import Config

    value = Config().to_flat()[key]
    if isinstance(value, float):
        value = f"{value:g}"
    elif value == "":
        value = "''"
    return f"{key} = {value}{' ' + unit if unit else ''}"


def local_ros_env(domain_id: int | None = None) -> None:
    """Keep DDS discovery on loopback and in a run-specific domain, unless the user chose one.

    Used by everything that starts DDS on its own (tests, demo, benchmarks); not by the live node,
    which follows the robot's environment.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else 1 + os.getpid() % 100)
