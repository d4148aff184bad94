"""The registration methods replay compares, behind one small interface.

Every pairwise method has ``prepare(points, times, stamp_ns) -> (prepared, ms)`` (preprocessing of one raw scan) and
``align(src, tgt, T_init) -> (T_target_source, info, ms)``; the runtime of a pair is the sum of both
preparations and the alignment (reading excluded). KISS-ICP is an odometry (scan-to-map with its own
state), so it only has ``step(scan) -> (T_first_k, ms)``. No ROS import. The DeepBBS methods and
:func:`build_methods` are here, the baselines in replay/baseline_methods.py, the names and ``--method`` parsing in
replay/method_names.py (every name is imported from here too).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.config.registration import NETWORK_ALONE
from deepbbs_ros.replay.baseline_methods import KissMatcherMethod, KissMethod, SmallGicpMethod
from deepbbs_ros.replay.method_names import (  # noqa: F401  (re-exported)
    DEEPBBS_VARIANTS,
    GLOBAL,
    INPUTS,
    METHODS,
    ODOMETRY_ONLY,
    PAIRWISE,
    parse_methods,
    topic_name,
)

MAX_MOTIONS = 100_000  # per-scan velocities kept by a DeepBBS method (a few hundred bytes each)


class DeepBBSMethod:
    """DeepBBS++ as configured (``deepbbs++``), with the GICP precision stage forced on (``deepbbs++gicp``), or
    the network alone (``deepbbs``: the deep passes from the one start, ``config.registration.NETWORK_ALONE``) via
    ``DeepBBSRegistration``."""

    def __init__(self, name: str, config: Config, *, weights: str | None = None, device: str | None = None,
                 model: Any = None, share_from: DeepBBSMethod | None = None) -> None:
        from deepbbs_ros.core.registration import DeepBBSRegistration

        self.name = name
        if name == "deepbbs":
            cfg = config.replace(**NETWORK_ALONE)
        elif name == "deepbbs++gicp":
            cfg = config.replace(**{"registration.polish": "gicp"})
        else:
            cfg = config
        self.polish = cfg.registration.polish != "none"
        if share_from is not None:  # one network in memory for both variants
            model = share_from.reg.model
            device = str(share_from.reg.device)
        self.reg = DeepBBSRegistration(cfg, weights=weights, device=device, model=model)
        self._stream = None  # core.deskew.StreamDeskew over the recording (scans with per-point times)
        if cfg.preprocess.deskew and self.polish:
            from deepbbs_ros.core.deskew import StreamDeskew

            self._stream = StreamDeskew(self.reg)
        self._motions: OrderedDict[int, tuple[Any, float]] = OrderedDict()  # stamp -> (velocity or None, ms)
        if share_from is None:
            self.reg.warmup()  # first-call kernel set-up out of the timed frames
        self.input = INPUTS[name]

    def observe(self, points: np.ndarray, times: np.ndarray | None, stamp_ns: int) -> None:
        """Every scan of the recording, in order (the runner calls it as it reads): the recording's
        velocity at this scan (``StreamDeskew.velocity``), kept by stamp for ``prepare`` with the time of
        the estimate (a live stream preprocesses each scan once; replay preprocesses it again in
        ``prepare``, which is not counted twice)."""
        if self._stream is None or times is None or stamp_ns in self._motions:
            return
        motion = self._stream.velocity(self.reg.preprocess(points, times, stamp_ns))
        self._motions[int(stamp_ns)] = (motion, self._stream.last_ms)
        while len(self._motions) > MAX_MOTIONS:
            self._motions.popitem(last=False)

    def prepare(self, points: np.ndarray, times: np.ndarray | None = None,
                stamp_ns: int | None = None) -> tuple[Any, float]:
        """-> (the PreprocessResult: sampled points, dense points, precision-stage cloud (deskewed with the
        recording's velocity at this scan when the scan has per-point times), ms (the velocity's cost
        included)."""
        entry = None
        if self._stream is not None and times is not None and stamp_ns is not None:
            self.observe(points, times, stamp_ns)  # in order for scan-to-scan odometry; pairs mode did it
            entry = self._motions.get(int(stamp_ns))
        extra = entry[1] if entry is not None else 0.0
        t0 = time.perf_counter()
        res = self.reg.preprocess(points, times, stamp_ns)
        if entry is not None and entry[0] is not None:
            res = self.reg.deskew_scan(res, entry[0])
        return res, (time.perf_counter() - t0) * 1e3 + extra  # + the velocity's cost

    def align(self, src: np.ndarray, tgt: np.ndarray, T_init: np.ndarray | None) -> tuple[np.ndarray, dict, float]:
        t0 = time.perf_counter()
        res = self.reg.register(src, tgt, T_init=T_init, preprocessed=True)
        ms = (time.perf_counter() - t0) * 1e3
        info = {"converged": bool(res.converged), "inlier_ratio": float(res.inlier_ratio), "valid": bool(res.valid),
                "path": str(getattr(res, "path", "")),
                "score": float(res.score)}
        if self.polish:
            info["polish"] = res.polish
            info["polish_ms"] = float(res.timings_ms.get("polish", 0.0))
        return np.asarray(res.T_target_source, dtype=np.float64), info, ms


class DeepBBSOdomMethod:
    """``deepbbs++`` in odometry mode: :class:`~deepbbs_ros.core.odometry.DeepBBSOdometry`."""

    def __init__(self, name: str, config: Config, *, registration: Any = None) -> None:
        from deepbbs_ros.core.odometry import DeepBBSOdometry

        self.name = name
        self.odom = DeepBBSOdometry(config, registration=registration)
        self.input = INPUTS["deepbbs++odom"]

    def step(self, points: np.ndarray, times: np.ndarray | None,
             stamp_ns: int | None = None) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        out = self.odom.register_frame(points, times, stamp_ns)
        return out.T_first_k, (time.perf_counter() - t0) * 1e3

    def corrupt_prior(self, T: np.ndarray) -> None:
        """Robustness benchmark: the next constant-velocity prediction is off by ``T`` (4, 4)."""
        self.odom.delta = self.odom.delta @ T


def build_methods(names: list[str], config: Config, *, weights: str | None = None, device: str | None = None,
                  model: Any = None, mode: str = "pairs") -> dict[str, Any]:
    """Instantiate the methods in ``names`` (DeepBBS variants share one network). In odometry ``mode``,
    ``deepbbs++`` is the local-map odometry pipeline and ``deepbbs++s2s`` the chained scan-to-scan one."""
    out: dict[str, Any] = {}
    deep: DeepBBSMethod | None = None
    for name in names:
        if name == "deepbbs++" and mode == "odometry":
            share = DeepBBSMethod("deepbbs++", config, weights=weights, device=device, model=model, share_from=deep)
            deep = deep or share
            out[name] = DeepBBSOdomMethod(name, config, registration=share.reg)
        elif name in DEEPBBS_VARIANTS:
            out[name] = DeepBBSMethod(name, config, weights=weights, device=device, model=model, share_from=deep)
            deep = deep or out[name]
        elif name in ("icp", "plane-icp", "gicp"):
            out[name] = SmallGicpMethod(name, config)
        elif name in GLOBAL:
            out[name] = KissMatcherMethod(name, config)
        else:
            out[name] = KissMethod(name, config)
    return out
