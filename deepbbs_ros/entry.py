"""Entry-point plumbing shared by every command (the CLIs and the live node): known errors become one
line and exit code 1. No ROS import, no CLI import: both layers reach it without an upward import."""

from __future__ import annotations

import functools
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
