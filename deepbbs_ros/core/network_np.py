"""The numpy entry points of :class:`~deepbbs_ros.core.network.DeepBBSNetwork` (what the network process runs;
preprocessed clouds in metres; no ROS) and its warm-up: a part of it."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.model import DeepBBSNet, TargetCache
from deepbbs_ros.core.network_output import Clock, NetworkOutput

__all__ = ["NumpyEntryPoints"]


class _Stopped(Exception):
    """The caller of :meth:`DeepBBSNetwork.speculate_np` no longer wants the passes."""


class NumpyEntryPoints:
    """Part of :class:`~deepbbs_ros.core.network.DeepBBSNetwork`: its numpy entry points."""

    # what it reads of the DeepBBSNetwork it is part of
    config: Config
    device: torch.device
    model: DeepBBSNet
    # and its methods (core/network.py, core/network_batch.py)
    scaled: Callable[[np.ndarray], torch.Tensor]
    start_tensors: Callable[[np.ndarray], tuple[torch.Tensor, torch.Tensor]]
    _check: Callable[[np.ndarray, str], np.ndarray]
    torch_threads: Callable[[], contextlib.AbstractContextManager[None]]
    target_state: Callable[[torch.Tensor], TargetCache]
    passes: Callable[..., NetworkOutput]
    starts: Callable[..., list[NetworkOutput]]

    def prepare_target_np(self, target: np.ndarray) -> None:
        """Compute and keep the network state of a preprocessed target (M, 3) float32 metres (what the
        network process does with a target sent ahead of its registration)."""
        tgt = self.scaled(self._check(target, "target"))
        with torch.inference_mode(), self.torch_threads():
            self.target_state(tgt)

    def network_np(self, source: np.ndarray, target: np.ndarray, T_init: np.ndarray) -> NetworkOutput:
        """The deep passes alone on preprocessed clouds (N, 3), (M, 3) float32 metres from T_init (4, 4):
        what the network process runs (``core/network_process.py``); ``ms`` holds the stage times."""
        clock = Clock(self.device)
        src, tgt = self.scaled(self._check(source, "source")), self.scaled(self._check(target, "target"))
        R, t = self.start_tensors(T_init)
        with torch.inference_mode(), self.torch_threads():
            out = self.passes(src, tgt, R, t, clock.lap)
        out.ms = dict(clock.ms)
        return out

    def starts_np(self, source: np.ndarray, target: np.ndarray, T_starts: np.ndarray,
                  n_passes: int | None = None) -> list[NetworkOutput]:
        """:meth:`starts` on preprocessed clouds (N, 3), (M, 3) float32 metres from K starts (K, 4, 4): what the
        network process runs for the global search; the first output's ``ms`` holds the stage times."""
        clock = Clock(self.device)
        src, tgt = self.scaled(self._check(source, "source")), self.scaled(self._check(target, "target"))
        T = np.asarray(T_starts, dtype=np.float64).reshape(-1, 4, 4)
        R = torch.as_tensor(T[:, :3, :3], dtype=torch.float32, device=self.device)
        t = torch.as_tensor(T[:, :3, 3] * self.model.scale, dtype=torch.float32, device=self.device)
        with torch.inference_mode(), self.torch_threads():
            outs = self.starts(src, tgt, R, t, n_passes, clock.lap)
        if outs:
            outs[0].ms = dict(clock.ms)
        return outs

    def speculate_np(self, source: np.ndarray, target: np.ndarray, T_starts: np.ndarray,
                     stop: Callable[[], bool]) -> list[NetworkOutput]:
        """One deep pass from each of the starts (K, 4, 4) in turn (preprocessed clouds, metres) until ``stop()``
        (checked after every network stage) says the caller does not want them: -> the outputs done, in order."""
        src, tgt = self.scaled(self._check(source, "source")), self.scaled(self._check(target, "target"))
        outs: list[NetworkOutput] = []

        def lap(_stage: str) -> None:
            if stop():
                raise _Stopped

        with torch.inference_mode(), self.torch_threads():
            try:
                for T in np.asarray(T_starts, dtype=np.float64).reshape(-1, 4, 4):
                    if stop():
                        break
                    outs.append(self.passes(src, tgt, *self.start_tensors(T), lap, n_passes=1))
            except _Stopped:
                pass
        return outs

    def warmup(self, rounds: int = 2, batches: Sequence[int] = (), rank_points: int = 0) -> None:
        """The deep passes on two random clouds of ``preprocess.num_points`` points ``rounds`` times, and from
        as many starts at once as each of ``batches`` says (also on the first ``rank_points`` of them, the global
        search's ranking passes, with one start and with each batch, when that is fewer): torch's CPU kernels
        pick and cache their primitives on the first calls with a new shape."""
        rng = np.random.default_rng(0)
        pts = rng.uniform(-30.0, 30.0, (self.config.preprocess.num_points, 3)).astype(np.float32)
        for _ in range(rounds):
            self.network_np(pts, pts[::-1].copy(), np.eye(4))
        for k in sorted(set(batches)):
            if k > 1:
                self.starts_np(pts, pts[::-1].copy(), np.repeat(np.eye(4)[None], k, axis=0), 1)
        if 0 < rank_points < len(pts):  # the ranking prefix: one start (the speculative passes) and each batch
            for k in sorted({1, *batches}):
                self.starts_np(pts[:rank_points], pts[::-1][:rank_points].copy(),
                               np.repeat(np.eye(4)[None], k, axis=0), 1)
