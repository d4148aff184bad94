"""The skeleton every node command runs (``deepbbs-node``, the GICP anchor, ``deepbbs-localizer``): parse
``[--config YAML] [--ros-args ...]``, build the node, spin it until Ctrl-C / SIGTERM, destroy it cleanly."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from deepbbs_ros.config import Config
from deepbbs_ros.errors import DeepBBSError, NodeError
from deepbbs_ros.node.dds import apply_default_profile
from deepbbs_ros.node.remaps import remap_rules


def _parser(prog: str, description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        description=f"{description} ROS arguments go after --ros-args (remaps, -p name:=value, --params-file FILE).",
    )
    g = p.add_argument_group("configuration")
    g.add_argument("--config", metavar="YAML", help="config file (plain sections or a ROS parameter file); "
                   "ROS parameters given with --ros-args override it")
    g = p.add_argument_group("transport")
    g.add_argument("--no-shm-profile", action="store_true",
                   help="do not apply the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml)")
    return p


def run_node(
    argv: list[str] | None,
    prog: str,
    description: str,
    make_node: Callable[[Config], Node],
) -> int:
    """Parse ``[--config YAML] [--ros-args ...]``, build the node with ``make_node(config)`` and spin it
    until Ctrl-C / SIGTERM (the ROS 2 demos' skeleton). Shared by ``deepbbs-node`` and the GICP anchor."""
    full = list(sys.argv) if argv is None else [prog, *argv]
    args = _parser(prog, description).parse_args(_strip_ros_args(full)[1:])
    defaults = Config.from_yaml(args.config) if args.config else Config()
    if not args.no_shm_profile:
        apply_default_profile()
    # SIGINT / SIGTERM stop the spin and the node is destroyed (its last log line) while the context is still
    # valid: rclpy's own handlers shut the context down first, and every log line after that printed "Failed to
    # publish log message to rosout". A signal during start-up stops the node once it is built (a node cut
    # halfway would leave its threads and processes behind); a second signal interrupts at once.
    from rclpy.signals import SignalHandlerOptions

    stop, spinning = threading.Event(), threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()
        if not spinning.is_set():
            print(f"{prog}: stopping once started (again to interrupt now)", file=sys.stderr, flush=True)

    main_thread = threading.current_thread() is threading.main_thread()  # only there can handlers be set
    sigs = (signal.SIGINT, signal.SIGTERM) if main_thread else ()
    previous = {sig: signal.signal(sig, on_signal) for sig in sigs}
    try:
        try:
            rclpy.init(args=full, signal_handler_options=SignalHandlerOptions.NO if main_thread else None)
        except Exception as err:  # rclpy's RCLError: bad --ros-args (remap rules, parameter syntax)
            first = str(err).split(", at ")[0].replace("failed to initialize rcl: ", "")
            raise NodeError(f"invalid ROS arguments: {first}") from err
        return _spin_node(make_node, defaults, remap_rules(full), stop, spinning)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _spin_node(make_node: Callable[..., Node], defaults: Config, remaps: list, stop: threading.Event,
               spinning: threading.Event) -> int:
    node = None
    try:
        node = make_node(defaults, remaps=remaps) if remaps else make_node(defaults)
        # one thread: every callback only hands off (the inputs and the registration have their own threads), and
        # rclpy's multi-threaded executor cost ~2 ms more CPU per received 2.7 MB cloud (measured, paired runs)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spinning.set()
        # the signal handler runs between two waits (Python runs handlers in the main thread, outside rcl_wait)
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.2)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except DeepBBSError:
        raise
    except Exception:
        # the context shut down by someone else (rclpy.shutdown from a thread) can land while the executor
        # builds its wait set: RCLError ("context is not valid"). A clean stop; anything else is a real error.
        if rclpy.ok():
            raise
    finally:
        spinning.clear()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _strip_ros_args(argv: list[str]) -> list[str]:
    """argv without the ``--ros-args ... [--]`` sections (rclpy's remove_ros_args, without a context)."""
    out, in_ros = [], False
    for a in argv:
        if a == "--ros-args":
            in_ros = True
        elif in_ros and a == "--":
            in_ros = False
        elif not in_ros:
            out.append(a)
    return out
