"""What the network's deep passes give back, and the small helpers the registration stages share with it (no ROS):
:class:`NetworkOutput`, :class:`Clock` (wall time per stage), :func:`orthonormalize`, :func:`matrix` (scaled R, t
-> metres (4, 4)), :func:`worker_share` (the network process's share of a batch of starts)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

__all__ = ["Clock", "NetworkOutput", "matrix", "orthonormalize", "worker_share"]


@dataclass
class NetworkOutput:
    """What the network passes give back (scaled units, see ModelConfig.scale).

    R: (3, 3) float32, t: (3,) float32 (scaled) with p_target = R p_source + t; gamma: (N,) float32;
    temperature: T of the first pass; iterations: passes run; converged: the last increment was below the
    tolerances; ms: {"embed", "match", "solve"} wall time of the passes where they ran."""

    R: np.ndarray
    t: np.ndarray
    gamma: np.ndarray
    temperature: float
    iterations: int
    converged: bool
    ms: dict[str, float] = field(default_factory=dict)


class Clock:
    """Accumulates wall time per stage; synchronises CUDA so GPU stages are timed, not queued."""

    def __init__(self, device: torch.device) -> None:
        self.cuda = device.type == "cuda"
        self.ms: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, stage: str) -> None:
        if self.cuda:
            torch.cuda.synchronize()
        now = time.perf_counter()
        self.ms[stage] = self.ms.get(stage, 0.0) + (now - self._t) * 1e3
        self._t = now


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation (float64) to a float32-accumulated one."""
    u, _, vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def matrix(R: Any, t: Any, scale: float) -> np.ndarray:
    """(4, 4) float64 metres from R (3, 3) and t (3,) in scaled units (tensors or arrays; rotation
    re-orthonormalised)."""
    T = np.eye(4)
    T[:3, :3] = orthonormalize(torch.as_tensor(R).double().cpu().numpy())
    T[:3, 3] = torch.as_tensor(t).double().cpu().numpy() / scale
    return T


def worker_share(n: int) -> int:
    """How many of ``n`` starts the network process runs while the caller runs the others (it has the given
    start's target state already; a batch of k costs a little less than k single passes)."""
    return (n + 1) // 2
