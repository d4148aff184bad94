"""Shared helpers of the benchmark scripts: the --out folder, the JSON figures file, plots without a display, solvers
in child processes (a time limit, one CPU) and calls timed as configured but answered by an exact twin."""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # run from a checkout without installing

# importing deepbbs_ros sets what the libraries read when they load: OMP_WAIT_POLICY=PASSIVE (before torch and
# small_gicp) and the CPU kernels of numpy, OpenBLAS and torch (deepbbs_ros.cpu_kernels), as the CLIs do
from deepbbs_ros import cpu_kernels  # noqa: E402

HERE = Path(__file__).resolve().parent
if (cpu_kernels.state().startswith("avx2 except") and Path(sys.argv[0]).resolve().parent == HERE
        and not os.environ.get("DEEPBBS_BENCH_REEXEC")):
    # a benchmark script imported numpy before this module: start it again with the pins in its environment
    os.environ["DEEPBBS_BENCH_REEXEC"] = "1"
    os.execv(sys.executable, [sys.executable, *sys.argv])


def clean(v):
    """JSON-safe: NaN/inf -> None, numpy scalars -> Python numbers, tuples -> lists."""
    if isinstance(v, dict):
        return {str(k): clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [clean(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):
        try:
            v = v.item()
        except (ValueError, AttributeError):
            return str(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def split_passthrough(argv: list[str]) -> tuple[list[str], list[str]]:
    """``argv`` split at ``--``: (the script's own arguments, those passed on to deepbbs-replay)."""
    if "--" not in argv:
        return list(argv), []
    k = argv.index("--")
    return argv[:k], argv[k + 1:]


def read_reference_pair(folder: str | Path) -> tuple:
    """A real reference pair (``--pair``): two ``.pcd`` files (target, source in name order) and ``relative.txt``
    (their reference ``T_target_source``, 4x4) -> (target (N, 3) float32, source (M, 3) float32, T (4, 4))."""
    import numpy as np

    from deepbbs_ros.datasets.pcd import read_pcd_points

    folder = Path(folder)
    pcds = sorted(folder.glob("*.pcd"))
    if len(pcds) != 2 or not (folder / "relative.txt").is_file():
        raise SystemExit(f"--pair {folder}: expected two .pcd files (target, source in name order) and "
                         "relative.txt (T_target_source)")
    T = np.loadtxt(folder / "relative.txt").reshape(4, 4)
    return (read_pcd_points(pcds[0])[0].astype(np.float32), read_pcd_points(pcds[1])[0].astype(np.float32), T)


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux, else platform.processor()); "" when unknown."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def machine() -> dict:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return {"cpus": os.cpu_count(), "cpu_model": cpu_model(), "platform": platform.platform(),
            "python": platform.python_version(), "cpu_kernels": cpu_kernels.state(), "load_avg_1min": load,
            "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def write_json(out: Path, name: str, figures: dict, command: list[str] | None = None) -> Path:
    """``out/name``: {"command", "machine", "figures"}; returns the path."""
    out.mkdir(parents=True, exist_ok=True)
    doc = {"command": " ".join(command if command is not None else sys.argv), "machine": machine(),
           "figures": figures}
    path = out / name
    path.write_text(json.dumps(clean(doc), indent=2) + "\n")
    print(f"figures: {path}")
    return path


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, out: Path, name: str) -> Path:
    path = out / name
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"plot: {path}")
    return path


@dataclass
class Reply:
    """What a solver in a child process said: ``value`` (what its ``solve`` returned; None with ``error``),
    ``seconds`` (the call's time in the child; up to the limit on a timeout, NaN when the child died), ``error``
    (a timeout, a dead child or the solver's exception, in words; "" when it answered) and ``timeout``."""

    value: Any
    seconds: float
    error: str = ""
    timeout: bool = False


class Isolated:
    """A solver in a child process, one request at a time. The child (spawned: a forked child of a process that
    already ran TBB code can deadlock in KISS-Matcher) builds ``solver_cls(*args, **kwargs)`` (its time:
    ``build_s``) and answers ``solver.solve(*request)``. A request that takes over ``timeout`` s (None: no limit)
    kills the child (a C++ solver cannot be stopped from Python otherwise); the next request starts another. With
    ``one_cpu`` the child runs on one CPU from its start, so that every thread pool it starts has one thread and
    its answers are the same on any machine (a pool started in this process on every core keeps its threads)."""

    def __init__(self, solver_cls, *args, timeout: float | None = None, one_cpu: bool = False, **kwargs) -> None:
        self.solver_cls, self.args, self.kwargs = solver_cls, args, kwargs
        self.timeout = None if timeout is None else float(timeout)
        self.one_cpu = one_cpu
        self.build_s = 0.0
        self.proc = None
        self.conn = None

    def start(self) -> None:
        """Start the child and build the solver; OSError with the child's message when it cannot (e.g. a missing
        optional package)."""
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_serve, args=(self.solver_cls, self.args, self.kwargs, child, self.one_cpu),
                                daemon=True)
        self.proc.start()
        child.close()
        msg = self.conn.recv()  # ("ready", build_s) or ("error", text)
        if msg[0] != "ready":
            self.close()
            raise OSError(msg[1])
        self.build_s = max(self.build_s, msg[1])

    def ask(self, *request) -> Reply:
        if self.proc is None:
            self.start()
        t0 = time.perf_counter()
        self.conn.send(request)
        if not self.conn.poll(self.timeout):
            self.close()
            return Reply(None, time.perf_counter() - t0, f"timeout after {self.timeout:g} s", timeout=True)
        try:
            status, value, seconds = self.conn.recv()
        except EOFError:
            self.close()
            return Reply(None, float("nan"), "the child process died")
        return Reply(value, seconds) if status == "ok" else Reply(None, seconds, value)

    def close(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.join()
        self.proc = self.conn = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001  (interpreter shutdown)
            pass


def _serve(solver_cls, args, kwargs, conn, one_cpu: bool) -> None:
    """The child of :class:`Isolated`: build the solver, then answer requests until the pipe closes; on one CPU
    when ``one_cpu`` (before any library starts its threads; the threads it starts inherit it)."""
    from deepbbs_ros.baselines import one_cpu as on_one_cpu

    with on_one_cpu(one_cpu):
        try:
            t0 = time.perf_counter()
            solver = solver_cls(*args, **kwargs)
            conn.send(("ready", time.perf_counter() - t0))
        except Exception as err:  # noqa: BLE001  (reported in the parent)
            conn.send(("error", f"{type(err).__name__}: {err}"))
            return
        while True:
            try:
                request = conn.recv()
            except (EOFError, OSError):
                return
            t0 = time.perf_counter()
            try:
                conn.send(("ok", solver.solve(*request), time.perf_counter() - t0))
            except Exception as err:  # noqa: BLE001  (a solver's failure is an answer, with its message)
                conn.send(("error", f"{type(err).__name__}: {err}", time.perf_counter() - t0))


def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and every process below it (Linux /proc; elsewhere this
    process only)."""
    if not Path("/proc/self/task").is_dir():
        return time.process_time()
    return _tree_cpu_seconds([os.getpid()])


def children_cpu_seconds() -> float:
    """CPU seconds (user + system, to the clock tick) of every process below this one (a network process), without
    this process's own (Linux /proc; elsewhere 0)."""
    kids = []
    for task in Path("/proc/self/task").glob("*"):
        try:
            kids += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
    return _tree_cpu_seconds(kids)


def _tree_cpu_seconds(pids: list[int]) -> float:
    """CPU seconds (user + system, to the clock tick) of the processes ``pids`` and every process below them."""
    tick = os.sysconf("SC_CLK_TCK")
    total, todo, seen = 0.0, list(pids), set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                f = (task / "stat").read_text().rsplit(")", 1)[1].split()
                total += (int(f[11]) + int(f[12])) / tick
                todo += [int(c) for c in (task / "children").read_text().split()]
            except (OSError, ValueError):
                continue
    return total


def timed_then_answered(call: Callable[[Any], Any], timed: Any, answering: Any = None) -> tuple[Any, float, float]:
    """``call(timed)`` timed as a user runs it (wall ms, CPU ms of this process), then, when ``answering`` is
    given, ``call(answering)`` (a twin whose answer is the same on any machine: small_gicp's solve on one thread, a
    child on one CPU) gives the answer: -> (the answer, wall ms, CPU ms)."""
    c0, t0 = cpu_seconds(), time.perf_counter()
    out = call(timed)
    wall, cpu = (time.perf_counter() - t0) * 1e3, (cpu_seconds() - c0) * 1e3
    return (call(answering) if answering is not None else out), wall, cpu
