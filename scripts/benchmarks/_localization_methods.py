"""The localization benchmark's methods as it times them (scripts/benchmarks/localization.py): MapLocalizer with its
exact twin, a baseline in a child process (_localization_baselines.py's solvers), a method's answer."""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

METHODS = ("maplocalizer", "kiss-matcher+gicp", "fpfh-ransac+gicp")
LABELS = {"maplocalizer": "MapLocalizer (DeepBBS++)", "kiss-matcher+gicp": "KISS-Matcher + GICP (scan to map)",
          "fpfh-ransac+gicp": "FPFH + RANSAC (Open3D) + GICP (scan to map)"}


@dataclass
class Answer:
    """What a method said about one query: ``T_map_scan`` (4, 4) or None, ``valid`` (it would publish it),
    ``reason`` (why not, when it says), ``time_s`` (wall clock of the call), ``timeout``."""

    T_map_scan: np.ndarray | None
    valid: bool
    reason: str = ""
    time_s: float = float("nan")
    timeout: bool = False
    exact_time_s: float = float("nan")  # MapLocalizer: the time of the twin that answered (GICP on one thread)
    cpu_s: float = float("nan")  # MapLocalizer: the timed call's CPU time (this process and its network process)
    exact_cpu_s: float = float("nan")  # the twin's CPU time
    probability: float = float("nan")  # MapLocalizer: the map verdict's probability of its answer


_REGISTRATION: dict = {}  # one DeepBBSRegistration (model loaded and warmed up once) shared by every map


def _registration(config):
    """One DeepBBSRegistration per distinct config (model loaded and warmed up once), shared by every map."""
    from deepbbs_ros.core.registration import DeepBBSRegistration

    key = config.to_yaml()
    if key not in _REGISTRATION:
        reg = DeepBBSRegistration(config)
        reg.warmup()
        _REGISTRATION[key] = reg
    return _REGISTRATION[key]


def cpu_seconds(loc) -> float:
    """CPU seconds used so far by this process and by the network process of ``loc``'s registration (when it has
    one): a search's CPU time is the difference around it, a figure the machine's load hardly changes."""
    cpu = time.process_time()
    proc = getattr(getattr(getattr(loc, "registration", None), "runner", None), "worker", None)
    if proc is not None:
        try:
            fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
            cpu += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
        except (OSError, ValueError, IndexError):
            pass
    return cpu


class MapLocalizerMethod:
    """deepbbs_ros.core.localization.MapLocalizer, built once per map (``build_s``: the map's part, places,
    descriptors and GICP cloud; the model is loaded and warmed up once per run, before any query, and shared by every
    map). Each query is timed as configured; with ``exact`` (True unless ``--inexact``) a twin with
    ``registration.exact_gicp`` (GICP's solve on one thread: the same answer on any machine) answers it, its own time
    in ``exact_time_s``."""

    name = "maplocalizer"

    def __init__(self, points: np.ndarray, trajectory: np.ndarray | None, config=None, exact: bool = True) -> None:
        from deepbbs_ros.config import Config

        config = config or Config()
        twin = config.replace(**{"registration.exact_gicp": True}) if exact and not config.registration.exact_gicp \
            else None
        for cfg in (config, twin):  # the model loaded and warmed up before any map is timed
            if cfg is not None:
                _registration(cfg)
        t0 = time.perf_counter()
        self.loc = self._localizer(points, trajectory, config)
        self.build_s = time.perf_counter() - t0
        self.exact = None if twin is None else self._localizer(points, trajectory, twin)

    @staticmethod
    def _localizer(points: np.ndarray, trajectory: np.ndarray | None, config):
        from deepbbs_ros.core.localization import MapLocalizer

        return MapLocalizer(points, config, registration=_registration(config), trajectory=trajectory)

    def __call__(self, scan: np.ndarray) -> Answer:
        t0, c0 = time.perf_counter(), cpu_seconds(self.loc)
        r = self.loc.localize(scan)
        dt, cpu = time.perf_counter() - t0, cpu_seconds(self.loc) - c0
        if self.exact is None:
            return Answer(np.asarray(r.T_map_scan, np.float64), bool(r.valid), str(r.reason), dt, cpu_s=cpu,
                          probability=float(getattr(r, "probability", np.nan)))
        t0, c0 = time.perf_counter(), cpu_seconds(self.exact)
        r = self.exact.localize(scan)
        return Answer(np.asarray(r.T_map_scan, np.float64), bool(r.valid), str(r.reason), dt, cpu_s=cpu,
                      exact_time_s=time.perf_counter() - t0, exact_cpu_s=cpu_seconds(self.exact) - c0,
                      probability=float(getattr(r, "probability", np.nan)))


class Isolated(_common.Isolated):
    """A baseline in a child process (:class:`_common.Isolated`), one query at a time, ``timeout`` s each: the child
    builds ``solver_cls(points, **kwargs)`` (the map's preparation, ``build_s``) and answers
    ``solver.solve(scan, prior)`` -> (T_map_scan, accepted, reason)."""

    def __init__(self, name: str, solver_cls, points: np.ndarray, timeout: float, one_cpu: bool = False,
                 **kwargs) -> None:
        super().__init__(solver_cls, points, timeout=timeout, one_cpu=one_cpu, **kwargs)
        self.name = name

    def __call__(self, scan: np.ndarray, prior: tuple[np.ndarray, float] | None = None) -> Answer:
        """``prior``: optional (xy (2,), radius m): register against the map within radius of xy only."""
        r = self.ask(np.ascontiguousarray(scan), prior)
        if r.error:  # a timeout, a dead child or the solver's exception: no pose, with its message
            return Answer(None, False, r.error, r.seconds, r.timeout)
        T, ok, why = r.value
        return Answer(T, bool(ok), why, r.seconds)


EXACT_GUARD = 10.0  # the one-CPU child's time per query, in time limits of the every-core child


class ExactTimed:
    """A baseline's answer from a child on one CPU (its answers the same on any machine: TBB's and OpenMP's sums
    follow the CPUs), its time from a second child on every core (as a user runs it). The query times out when the
    every-core call does alone. The one-CPU call, asked only when the every-core one has answered in time, has
    ``EXACT_GUARD`` times as long: a guard against a hung child, not a time limit (with twice the time, a query the
    every-core call answered in 9 s timed out on one CPU in one run and answered in another)."""

    def __init__(self, name: str, solver_cls, points: np.ndarray, timeout: float, **kwargs) -> None:
        self.name = name
        self.exact = Isolated(name, solver_cls, points, EXACT_GUARD * timeout, True, **kwargs)
        self.timed = Isolated(name, solver_cls, points, timeout, False, **kwargs)

    @property
    def build_s(self) -> float:
        return self.timed.build_s

    def start(self) -> None:
        self.exact.start()
        self.timed.start()

    def close(self) -> None:
        self.exact.close()
        self.timed.close()

    def __call__(self, scan: np.ndarray, prior: tuple[np.ndarray, float] | None = None) -> Answer:
        timed = self.timed(scan, prior)
        if timed.timeout:
            return timed
        a = self.exact(scan, prior)
        return Answer(a.T_map_scan, a.valid, a.reason, timed.time_s, a.timeout)


class _Sleeper:
    """A stand-in solver that takes ``seconds`` per query (tests of the time limit)."""

    def __init__(self, points: np.ndarray, seconds: float = 30.0) -> None:
        self.seconds = seconds

    def solve(self, scan, prior=None):
        time.sleep(self.seconds)
        import os

        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0
        return np.eye(4), True, f"{cpus} cpus"
