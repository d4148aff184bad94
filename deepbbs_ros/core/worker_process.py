"""Starting a worker process of this package: a subprocess on a socket pair, and its first answer, on both sides
(no torch).

What the network's worker (core/network_process.py) and the node's registration process
(node/registration_process.py) share: ``python -m <module> FD`` in its own session, so that a Ctrl-C in the
terminal goes to the caller only and the worker ends when its socket closes; not a ``multiprocessing`` child
(spawn would run the caller's ``__main__`` again, fork would copy torch's and DDS's threads).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from deepbbs_ros.errors import ModelError

__all__ = ["handshake", "spawn_worker", "started", "stop_worker"]


def spawn_worker(module: str, what: str) -> tuple[Any, Any]:
    """Start ``python -m <module> FD`` on one end of a socket pair, in its own session (a Ctrl-C in the terminal
    goes to the caller only), importable from a source checkout too: -> (``subprocess.Popen``, the caller's
    ``multiprocessing.connection.Connection``). Raises ModelError naming ``what`` when it cannot start."""
    import socket
    import subprocess
    import sys
    from multiprocessing.connection import Connection

    import deepbbs_ros

    ours, theirs = socket.socketpair()
    env = dict(os.environ)
    root = str(Path(deepbbs_ros.__file__).resolve().parents[1])  # importable from a source checkout too
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", module, str(theirs.fileno())],
            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, env=env,
            start_new_session=True)
    except OSError as err:
        ours.close()
        raise ModelError(f"{what}: cannot start {sys.executable} ({err})") from err
    finally:
        theirs.close()
    return proc, Connection(ours.detach())


def handshake(conn: Any, proc: Any, hello: tuple, what: str, timeout_s: float) -> tuple:
    """Send a new worker its ``hello`` (weights, flat config) and wait for its first answer: -> its ("ready", ...)
    message. Raises ModelError naming ``what``: no answer in ``timeout_s``, the worker gone, or its error line
    (the caller stops it)."""
    try:
        conn.send(hello)
        if not conn.poll(timeout_s):
            raise ModelError(f"{what}: no answer within {timeout_s:.0f} s of its start")
        msg = conn.recv()
    except (EOFError, OSError) as err:
        raise ModelError(f"{what} exited while starting (exit code {proc.poll()})") from err
    if msg[0] != "ready":
        raise ModelError(f"{what}: {msg[1]}")
    return msg


def started(fd: int, build: Callable[[str, dict[str, Any]], tuple[Any, tuple]]) -> tuple[Any, Any, int]:
    """The worker's side of :func:`handshake`: on its socket ``fd``, read (weights, flat config), ``build`` what it
    serves from them (-> (that, its ``("ready", ...)`` message)) and answer that message: -> (the connection, what
    was built, 0). Where the caller is gone (EOF) -> (connection, None, 0); where ``build`` raises, its error goes
    back as one line ``("error", "Type: message")`` -> (connection, None, 1): the worker exits with that code."""
    from multiprocessing.connection import Connection

    conn = Connection(fd)
    try:
        weights, flat_config = conn.recv()
        built, ready = build(weights, flat_config)
    except (EOFError, OSError):
        return conn, None, 0
    except Exception as err:  # noqa: BLE001 - reported to the caller as one line
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return conn, None, 1
    conn.send(ready)
    return conn, built, 0


def stop_worker(conn: Any, proc: Any, grace_s: float, keep_open: bool = False) -> None:
    """Ask the worker ``proc`` on ``conn`` to stop (``("stop",)``), give it ``grace_s`` s to exit, else kill it;
    close ``conn`` before the wait (a worker blocked sending an answer nobody will read fails at once), or after it
    with ``keep_open`` (answers in flight still go out while the worker winds down: the registration process's
    lanes)."""
    try:
        conn.send(("stop",))
    except (OSError, ValueError):
        pass
    if not keep_open:
        conn.close()
    try:
        proc.wait(timeout=grace_s)
    except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired
        proc.kill()
        proc.wait(timeout=2.0)
    if keep_open:
        conn.close()
