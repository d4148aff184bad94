"""Shared CLI plumbing: known errors become one line and exit code 1; DDS stays on loopback."""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable

from deepbbs_ros.errors import DeepBBSError


def cli_entry(prog: str) -> Callable[[Callable[..., int]], Callable[..., int]]:
    """Decorate ``main(argv=None) -> int``.

    A :class:`DeepBBSError` prints ``<prog>: error: <message>`` on stderr and returns 1; Ctrl-C
    returns 130 (the command itself is responsible for saving partial results before that).
    Unknown exceptions keep their traceback: they are bugs.
    """

    def wrap(func: Callable[..., int]) -> Callable[..., int]:
        @functools.wraps(func)
        def inner(*args, **kwargs) -> int:
            try:
                return int(func(*args, **kwargs) or 0)
            except DeepBBSError as err:
                print(f"{prog}: error: {err}", file=sys.stderr)
                return 1
            except KeyboardInterrupt:
                print(f"{prog}: interrupted", file=sys.stderr)
                return 130

        return inner

    return wrap


def local_ros_env(domain_id: int | None = None) -> None:
    """Keep DDS discovery on loopback and in a run-specific domain, unless the user chose one.

    Used by everything that starts DDS on its own (tests, demo, benchmarks); not by the live node,
    which follows the robot's environment.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else 1 + os.getpid() % 100)
