"""Every deepbbs-* command's --help (and each subcommand's): real defaults, each said once."""

from __future__ import annotations

import argparse
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _console_scripts() -> dict[str, str]:
    text = (ROOT / "setup.py").read_text()
    return dict(re.findall(r'"(deepbbs-[\w-]+) = ([\w.]+):main"', text))


def _parsers(name: str, module: str) -> list[tuple[str, argparse.ArgumentParser]]:
    """The command's parser and every subcommand's, depth first."""
    mod = importlib.import_module(module)
    if hasattr(mod, "build_parser"):
        root = mod.build_parser()
    else:  # a node: its parser is built by run_node
        from deepbbs_ros.node.run import _parser

        root = _parser(name, "description")
    out, todo = [], [(name, root)]
    while todo:
        label, parser = todo.pop()
        out.append((label, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                todo += [(f"{label} {sub}", p) for sub, p in action.choices.items()]
    return out


def _all_parsers():
    scripts = _console_scripts()
    assert {"deepbbs-replay", "deepbbs-sim", "deepbbs-bag", "deepbbs-train", "deepbbs-node"} <= set(scripts)
    found = []
    for name, module in sorted(scripts.items()):
        if name == "deepbbs-node":
            pytest.importorskip("rclpy")
        found += _parsers(name, module)
    return found


def test_every_help_shows_real_defaults_once():
    checked = 0
    for label, parser in _all_parsers():
        text = " ".join(parser.format_help().split())  # wrapping undone
        assert "(default: None)" not in text, label
        assert "default: False" not in text, label
        formatter = parser._get_formatter()
        for action in parser._actions:
            if not action.help or action.help is argparse.SUPPRESS:
                continue
            shown = formatter._expand_help(action)
            assert shown.count("(default") <= 1, (label, action.option_strings, shown)
            assert "None" not in shown, (label, action.option_strings, shown)
            checked += 1
    assert checked > 100


def test_replay_help_states_the_config_defaults():
    from deepbbs_ros.cli.replay import build_parser
    from deepbbs_ros.config import Config

    text = " ".join(build_parser().format_help().split())
    ev = Config().eval
    assert (f"eval.stride = {ev.stride} in pairs mode, eval.odom_stride = {ev.odom_stride} in odometry and "
            "localization)") in text
    assert f"eval.max_dist = {ev.max_dist:g} m)" in text and f"eval.trials = {ev.trials})" in text
    assert "(default: registration.device = auto)" in text
    assert "(default: results/replay)" in text and "(default: 0.05)" in text
    assert "--no-plots skip the PNG plots --no-bag" in text  # a flag shows no "(default: False)"
