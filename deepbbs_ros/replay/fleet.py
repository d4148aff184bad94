"""A fleet of recordings replayed as Ray tasks: one task per recording, one results folder.

``deepbbs-replay A B C --workers 2`` (or ``--ray-address ADDR``) runs every recording through the very
function a single ``deepbbs-replay SOURCE`` run uses (handed in by the CLI as ``replay_one``), in a Ray
worker process, into a private temporary folder. The task sends back what that run wrote (metrics.json,
CSV, trajectories, plots, results bag: bytes, never point clouds) and the driver lays it out as::

    OUT/<timestamp>/
        metrics.json      the fleet summary: per-recording rows + pooled figures per method
        recordings.csv    the per-recording table
        <recording>/      exactly what ``deepbbs-replay <recording>`` writes into its own run folder

The pooled figures are computed from the per-recording metrics (see :func:`pool_metrics`), never
re-estimated. A recording that fails is a row with its one-line error; a worker process that dies is
retried by Ray (``retries``); Ctrl-C keeps every recording finished so far and marks the run incomplete.
No ROS import; Ray is imported only when a fleet runs.

Modules: this one runs the fleet (the Ray task, Ray's start, the driver); :mod:`~deepbbs_ros.replay.fleet_sources`
expands the sources, :mod:`~deepbbs_ros.replay.fleet_results` holds the rows and pools the figures,
:mod:`~deepbbs_ros.replay.fleet_summary` writes and prints the summary; their names are imported from here too.
"""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

from deepbbs_ros.errors import ConfigError, DeepBBSError
from deepbbs_ros.replay.fleet_results import FleetResult, Recording, pool_metrics
from deepbbs_ros.replay.fleet_sources import LIST_SUFFIXES, expand_sources, recording_names
from deepbbs_ros.replay.fleet_summary import print_summary, write_summary
from deepbbs_ros.replay.loop import mark_interrupted

__all__ = [
    "LIST_SUFFIXES", "FleetResult", "Recording", "expand_sources", "init_ray", "pool_metrics", "print_summary",
    "recording_names", "replay_task", "run_fleet", "write_summary",
]

# --------------------------------------------------------------------------------------------------
# the Ray task
# --------------------------------------------------------------------------------------------------
def replay_task(replay_one: Callable[[Any], int], args: Any, source: str, tag: str = "") -> dict[str, Any]:
    """One recording in a worker process: ``replay_one(args)`` with ``args.source = source`` and a private
    output folder; returns ``{"status", "rc", "error", "seconds", "metrics", "files"}`` where ``files``
    maps each written file (relative path) to its bytes. Errors become the one-line ``error``. The
    private folder is removed on return (``tag`` names it, so the driver can remove a killed worker's)."""
    import copy

    tmp = Path(tempfile.mkdtemp(prefix=f"deepbbs-fleet-{tag}-"))
    t0 = time.perf_counter()
    args = copy.copy(args)
    args.source, args.out, args.quiet = source, str(tmp), True
    error = ""
    try:
        with redirect_stdout(io.StringIO()), redirect_stderr(io.StringIO()):
            try:
                rc = int(replay_one(args) or 0)
            except DeepBBSError as err:
                rc, error = 1, str(err)
            except Exception as err:  # noqa: BLE001 - one recording's bug must not stop the fleet
                rc, error = 1, f"{type(err).__name__}: {err}"
        runs = [p for p in tmp.iterdir() if p.is_dir() and not p.is_symlink()]
        files: dict[str, bytes] = {}
        doc = None
        if runs:
            run = runs[0]
            files = {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}
            if "metrics.json" in files:
                doc = json.loads(files["metrics.json"])
        if rc != 0 and not error:
            errs = (doc or {}).get("errors") or []
            error = errs[-1] if errs else f"exit code {rc}"
        status = "ok" if rc == 0 else ("incomplete" if doc is not None else "failed")
        return {"status": status, "rc": rc, "error": error.splitlines()[0] if error else "",
                "seconds": time.perf_counter() - t0, "metrics": doc, "files": files}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------------------------------
# the driver
# --------------------------------------------------------------------------------------------------
def init_ray(workers: int | None, address: str | None) -> tuple[bool, int]:
    """Join ``address``, or start Ray in this process with ``workers`` CPUs; reuse a Ray already started
    by the caller. Quiet: no dashboard, worker output not forwarded. Returns (we started it, CPUs)."""
    try:
        import ray
    except ImportError as err:  # pragma: no cover - ray is an install requirement
        raise ConfigError("fleet runs need Ray: pip install ray") from err
    started = False
    if address:
        _check_reachable(address)
    if not ray.is_initialized():
        kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                              "logging_level": logging.ERROR, "configure_logging": True}
        try:
            if address:
                ray.init(address=address, **kw)
            else:
                ray.init(num_cpus=workers, **kw)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = f"the Ray cluster at {address}" if address else "a local Ray"
            raise ConfigError(f"--ray-address: cannot start or join {where} ({str(err).splitlines()[0]})") from err
        started = True
    cpus = int(ray.cluster_resources().get("CPU", 1))
    return started, cpus


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A quick TCP connect to ``HOST:PORT`` (Ray itself retries an unreachable address for minutes)."""
    import socket

    if address == "auto":
        return
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep or not port.isdigit():
        raise ConfigError(f"--ray-address: expected HOST:PORT or 'auto', got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise ConfigError(f"--ray-address: cannot reach the Ray cluster at {address} ({err.strerror or err})") from err


def run_fleet(replay_one: Callable[[Any], int], args: Any, sources: list[str], run_dir: Path, *,
              workers: int | None = None, address: str | None = None, retries: int = 3, cpus_per_task: int = 1,
              gpus_per_task: float = 0.0,
              progress: bool = True, on_result: Callable[[Recording], None] | None = None) -> FleetResult:
    """Replay every source as a Ray task (``cpus_per_task`` CPUs, ``gpus_per_task`` GPUs each) and write each
    recording's files into ``run_dir/<name>/`` as they arrive. ``on_result`` is called after each recording."""
    import ray
    from tqdm import tqdm

    names = recording_names(sources)
    recs = [Recording(n, s) for n, s in zip(names, sources)]
    started, cpus = init_ray(workers, address)
    t0 = time.perf_counter()
    res = FleetResult(getattr(args, "mode", "pairs"), recs, cpus, address or "local")
    bar = tqdm(total=len(recs), unit="recordings", desc=f"fleet {res.mode}", disable=not progress,
               dynamic_ncols=True)
    pending: dict[Any, int] = {}
    frames = failed = 0
    tag = "none"
    try:
        task = ray.remote(num_cpus=cpus_per_task, num_gpus=gpus_per_task, max_retries=retries)(replay_task)
        fn_ref, args_ref = ray.put(replay_one), ray.put(args)
        tag = f"{os.getpid()}-{int(time.time() * 1000) % 10**8}"  # the driver's pid first: one run's folders
        pending = {task.remote(fn_ref, args_ref, r.source, tag): i for i, r in enumerate(recs)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)  # Ctrl-C is seen between waits
            for ref in ready:
                rec = recs[pending.pop(ref)]
                try:
                    out = ray.get(ref)
                except ray.exceptions.RayError as err:  # the worker died more than ``retries`` times, ...
                    lines = [ln for ln in str(err).splitlines() if ln.strip()]
                    out = {"status": "failed", "error": f"{type(err).__name__}: {lines[-1] if lines else err}",
                           "seconds": None, "metrics": None, "files": {}}
                _store(run_dir / rec.name, rec, out)
                del out
                frames += rec.frames_read or 0
                failed += rec.status != "ok"
                bar.set_postfix(frames=frames, failed=failed, refresh=False)
                bar.update(1)
                if on_result:
                    on_result(rec)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        mark_interrupted(res)
    finally:
        bar.close()
        if started:
            ray.shutdown()
        for d in Path(tempfile.gettempdir()).glob(f"deepbbs-fleet-{tag}-*"):  # of workers killed on this machine
            shutil.rmtree(d, ignore_errors=True)
    res.wall_s = time.perf_counter() - t0
    for r in recs:
        if r.status != "ok":
            res.complete = False
            if r.status != "not run":
                res.errors.append(f"{r.name}: {r.error}")
    return res


def _store(folder: Path, rec: Recording, out: dict[str, Any]) -> None:
    """Write a task's files, then fill its row (a Ctrl-C while writing leaves the row 'not run')."""
    for rel, data in (out.get("files") or {}).items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    doc = out.get("metrics")
    if doc is not None:
        rec.frames_read = doc.get("frames_read")
        rec.methods = doc.get("methods") or {}
    rec.status, rec.error, rec.seconds = out["status"], out.get("error", ""), out.get("seconds")


