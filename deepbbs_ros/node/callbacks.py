"""The boundary of every callback the nodes give the executor (subscriptions, timers, services): an exception ends
there, as one rate-limited error line naming the callback and the problem, counted on ``/diagnostics``
(``errors.callback <name>``); the node keeps running.

rclpy's executors re-raise a callback's exception in the spinning thread, which ends ``rclpy.spin``: the node, and
every other node on that executor, would stop. :class:`GuardedCallbacks` (a mixin before ``rclpy.node.Node``)
wraps each callback given to ``create_subscription`` / ``create_timer`` / ``create_service`` with :func:`guard`, so
that no callback of the node, nor of its parts (REP-105 outputs, the bond heartbeat), can end the executor. A
:class:`~deepbbs_ros.errors.DeepBBSError` (a user's mistake, bad input) is logged as its message; any other
exception is a bug and is logged with its type and where it was raised (the traceback at debug level). A service
whose callback fails answers ``success: false`` with the reason (std_srvs/Trigger), instead of never answering.
"""

from __future__ import annotations

import functools
import inspect
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.node.diagnostics import RateLimitedErrors

KIND = "callback"  # the /diagnostics key of a failed callback: errors.callback <name>


def describe(exc: BaseException) -> str:
    """One line for ``exc``: a DeepBBSError's message; any other exception ``unexpected Type: text (in file:line,
    function)``."""
    text = str(exc).replace("\n", " ")
    if isinstance(exc, DeepBBSError):
        return text
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (in {Path(frames[-1].filename).name}:{frames[-1].lineno}, {frames[-1].name})" if frames else ""
    return f"unexpected {type(exc).__name__}: {text}{where}"


def guard(fn: Callable[..., Any], name: str, report: Callable[[str, str, BaseException], None],
          service: bool = False) -> Callable[..., Any]:
    """``fn`` wrapped so that an ``Exception`` it raises goes to ``report(kind, message, exc)`` and the wrapper
    returns None (``service``: the response, the call's second argument, with ``success`` false and ``message``
    the reason where it has those fields). Coroutine functions are returned as they are (rclpy awaits them)."""
    if inspect.iscoroutinefunction(fn) or getattr(fn, "__guarded__", False):
        return fn

    @functools.wraps(fn)
    def guarded(*args: Any) -> Any:
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - the executor's boundary: reported, never re-raised
            message = f"{name}: {describe(exc)}; ignored, the node continues"
            report(f"{KIND} {name}", message, exc)
            if service and len(args) >= 2:
                response = args[1]
                if hasattr(response, "success"):
                    response.success = False
                if hasattr(response, "message"):
                    response.message = message
                return response
            return None

    guarded.__guarded__ = True
    return guarded


def _callback_arg(args: tuple, kwargs: dict, index: int) -> tuple[tuple, dict, Any]:
    if "callback" in kwargs:
        return args, kwargs, kwargs["callback"]
    return args, kwargs, args[index] if len(args) > index else None


def _replace(args: tuple, kwargs: dict, index: int, fn: Any) -> tuple[tuple, dict]:
    if "callback" in kwargs:
        return args, {**kwargs, "callback": fn}
    return args[:index] + (fn,) + args[index + 1:], kwargs


class GuardedCallbacks:
    """A mixin before ``rclpy.node.Node``: every subscription, timer and service callback guarded (:func:`guard`),
    reported to the node's rate-limited errors (``_errors``, on /diagnostics) once the node has them, else to its
    own."""

    def _report_callback_error(self, kind: str, message: str, exc: BaseException) -> None:
        errors = getattr(self, "_errors", None)
        if errors is None:  # before the counters exist (the managed node while unconfigured)
            errors = self.__dict__.get("_callback_errors")
            if errors is None:
                errors = self._callback_errors = RateLimitedErrors(lambda text: self.get_logger().error(text), 5.0)
        if errors.log(kind, message) and not isinstance(exc, DeepBBSError):
            self.get_logger().debug("".join(traceback.format_exception(exc)))

    def create_subscription(self, *args: Any, **kwargs: Any):
        args, kwargs, fn = _callback_arg(args, kwargs, 2)
        topic = kwargs.get("topic", args[1] if len(args) > 1 else "?")
        if fn is not None:
            args, kwargs = _replace(args, kwargs, 2, guard(fn, str(topic), self._report_callback_error))
        return super().create_subscription(*args, **kwargs)

    def create_timer(self, *args: Any, **kwargs: Any):
        args, kwargs, fn = _callback_arg(args, kwargs, 1)
        if fn is not None:
            name = "timer " + getattr(fn, "__qualname__", type(fn).__name__)
            args, kwargs = _replace(args, kwargs, 1, guard(fn, name, self._report_callback_error))
        return super().create_timer(*args, **kwargs)

    def create_service(self, *args: Any, **kwargs: Any):
        args, kwargs, fn = _callback_arg(args, kwargs, 2)
        srv_name = kwargs.get("srv_name", args[1] if len(args) > 1 else "?")
        if fn is not None:
            args, kwargs = _replace(args, kwargs, 2, guard(fn, str(srv_name), self._report_callback_error,
                                                           service=True))
        return super().create_service(*args, **kwargs)
