"""The DeepBBS++ network as one object: the model, its kept target states and the deep passes (no ROS).

:class:`DeepBBSNetwork` is what both the in-process path of ``DeepBBSRegistration.register`` and the
network's worker process (``core/network_process.py``) run::

    load        the checkpoint (weights, config's model section, metadata), or a model object handed in
    passes      embed / match / solve repeated on the moved source until the increment is small (DeepBBS)
    starts      the same from K start poses at once, as a batch of K (the global search's start yaws)
    targets     the target-only network state (DGCNN features, transformer memory) kept for the three most
                recent clouds: a fixed map target, or the last source that becomes the next target

Everything here runs in scaled coordinates (``model.scale`` times metres); the numpy entry points
(:meth:`DeepBBSNetwork.network_np`, :meth:`DeepBBSNetwork.starts_np`) take metres. The small helpers the
registration stages share with it (:func:`matrix`, :func:`orthonormalize`, :class:`Clock`) live here too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
import warnings
import zlib
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.checkpoint import default_weights_path, load_checkpoint
from deepbbs_ros.core.model import DeepBBSNet, TargetCache, solve_transform_inference
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.procrustes import apply_transform
from deepbbs_ros.core.refine import rotation_angle_deg
from deepbbs_ros.device import resolve_device
from deepbbs_ros.errors import ModelError

__all__ = ["Clock", "DeepBBSNetwork", "NetworkOutput", "matrix", "orthonormalize"]


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


def _expand(cache: TargetCache, k: int) -> TargetCache:
    """A target state of batch 1 broadcast to batch ``k`` (views; the memory's keys/values are (2, B, ...))."""
    if k == 1:
        return cache
    f = cache.f_tgt.expand(k, *cache.f_tgt.shape[1:])
    if cache.memory_kv is None:
        return TargetCache(f)
    kv = [m.expand(m.shape[0], k, *m.shape[2:]) for m in cache.memory_kv]
    tgt_self = None if cache.tgt_self is None else cache.tgt_self.expand(k, *cache.tgt_self.shape[1:])
    tgt_q = None if cache.tgt_q is None else cache.tgt_q.expand(k, *cache.tgt_q.shape[1:])
    return TargetCache(f, kv, tgt_self, tgt_q)


def cloud_key(cloud: torch.Tensor) -> tuple:
    """(shape, CRC-32 of the bytes) of a (1, N, 3) tensor: the target memo's key (then compared exactly)."""
    return tuple(cloud.shape), zlib.crc32(cloud.detach().cpu().numpy().tobytes())


class _Stopped(Exception):
    """The caller of :meth:`DeepBBSNetwork.speculate_np` no longer wants the passes."""


class DeepBBSNetwork:
    """The network of one checkpoint (or of a model object) with the registration config's deep-pass settings.

    Args:
        config: the whole configuration (defaults if None; copied). When weights are loaded, the model section
            is taken from the checkpoint (it describes the weights).
        weights: checkpoint path; None -> ``config.registration.weights``; "" -> the shipped model.
        device: "auto", "cpu", "cuda", "cuda:N"; None -> ``config.registration.device``.
        model: an already built :class:`DeepBBSNet` (used as is, its train/eval mode the caller's; moved to
            ``device``). Its target states are never kept: its weights may change.
        stacklevel: of the warning about a ``preprocess.num_points`` far from the trained one (2: the caller).

    Raises:
        ModelError: the checkpoint is missing, corrupt or does not match.
    """

    def __init__(
        self,
        config: Config | None = None,
        *,
        weights: str | Path | None = None,
        device: str | None = None,
        model: DeepBBSNet | None = None,
        stacklevel: int = 2,
    ) -> None:
        config = dataclasses.replace(config or Config())
        self.device = resolve_device(device or config.registration.device)
        self.metadata: dict[str, Any] = {}
        self.weights_path: Path | None = None
        if model is None:
            path = weights if weights is not None else config.registration.weights
            self.weights_path = Path(path).expanduser() if path else default_weights_path()
            if not self.weights_path.is_file():
                raise ModelError(f"model file not found: {self.weights_path} (train one with deepbbs-train)")
            model, ckpt_config, self.metadata = load_checkpoint(self.weights_path, self.device)
            config.model = ckpt_config.model
            trained, used = ckpt_config.preprocess.num_points, config.preprocess.num_points
            if not 0.5 * trained <= used <= 2 * trained:  # the network is size-agnostic, within reason
                warnings.warn(
                    f"{self.weights_path} was trained on {trained} points per cloud, "
                    f"preprocess.num_points is {used} (more than 2x apart)",
                    RuntimeWarning,
                    stacklevel=stacklevel,
                )
        else:
            config.model = model.cfg
        self.model = model.to(self.device)
        self.config = config
        # the last targets' network state (target_state); the model must not change while it is kept (training
        # hands in a model whose weights do: no memo then)
        self._target_lock = threading.Lock()
        self._target_memo: OrderedDict[tuple, tuple[torch.Tensor, TargetCache]] = OrderedDict()
        self._memo_targets = self.weights_path is not None

    @property
    def n_deep(self) -> int:
        """The configured number of deep passes (0: the deep stage is off)."""
        rc = self.config.registration
        return (rc.max_deep_iters if rc.deep_iterations else 1) if rc.deep else 0

    @contextlib.contextmanager
    def torch_threads(self) -> Iterator[None]:
        """torch's CPU thread count set to ``registration.threads`` for the network stages and restored
        after (process-wide in torch: a training run or a script keeps its own setting around the call)."""
        n = self.config.registration.threads
        before = torch.get_num_threads()
        if n <= 0 or self.device.type != "cpu" or n == before:
            yield
            return
        torch.set_num_threads(n)
        try:
            yield
        finally:
            torch.set_num_threads(before)

    def scaled(self, points: np.ndarray) -> torch.Tensor:
        """Checked (N, 3) float32 metres -> (1, N, 3) on the device in the network's scaled units."""
        return torch.from_numpy(points).to(self.device)[None] * self.model.scale

    def start_tensors(self, T: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """(4, 4) metres -> R (3, 3), t (3,) scaled float32 tensors on the device."""
        T = np.asarray(T, dtype=np.float64).reshape(4, 4)
        R = torch.as_tensor(T[:3, :3], dtype=torch.float32, device=self.device)
        t = torch.as_tensor(T[:3, 3] * self.model.scale, dtype=torch.float32, device=self.device)
        return R, t

    @staticmethod
    def _check(points: np.ndarray, name: str) -> np.ndarray:
        """A preprocessed cloud: (N >= 3, 3), finite (core/points.py)."""
        return as_xyz(points, name, finite=True, min_points=3)

    # -- the deep passes ---------------------------------------------------------------------------
    def passes(self, src: torch.Tensor, tgt: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
               lap: Callable[[str], None], n_passes: int | None = None) -> NetworkOutput:
        """The deep passes on src (1, N, 3), tgt (1, M, 3) (scaled, on the device) from R (3, 3), t (3,)
        (scaled); ``lap(stage)`` is called after each stage ("embed", "match", "solve"); ``n_passes``
        overrides the configured number (the global search ranks its starts after one)."""
        rc, scale = self.config.registration, self.model.scale
        n_deep = self.n_deep if n_passes is None else n_passes
        # the target does not move: its DGCNN features and the target-only parts of the transformer
        # (encoder output, self-attention) are computed once, and kept for the next registration against the
        # same target (a fixed map cloud); the source's kNN graph is rigid-invariant
        tgt_cache = self.target_state(tgt)
        src_knn, temperature, gamma, converged, k = None, 0.0, src.new_ones(src.shape[1]), False, -1
        lap("embed")
        # from identity, the first pass sees the source as it is: its state as a target comes almost for free
        # (consecutive pairs, scan-to-scan odometry: this source is the next pair's target)
        unmoved = self._memo_targets and bool((R == torch.eye(3, device=R.device)).all() and (t == 0).all())
        for k in range(n_deep):
            moved = apply_transform(src, R[None], t[None])
            # embed: DGCNN + transformer on the moved source and the target, temperature head
            f_src, src_knn = self.model.point_features(moved, src_knn)
            own = [] if k == 0 and unmoved else None
            phi_src, phi_tgt = self.model.cross_cached(f_src, tgt_cache, source_cache=own)
            if own:
                self.keep_state(src, own[0])
            temp = self.model.predict_temperature(phi_src, phi_tgt)
            lap("embed")
            # match: SoftBBS on the feature distances (B~ directly, no log domain at inference)
            sb = self.model.match_inference(phi_src, phi_tgt)
            lap("match")
            # solve: soft map, gamma (T halved every deep iteration), weighted Procrustes
            temperature = float(temp[0]) if k == 0 else temperature
            temp_k = rc.fixed_temperature if rc.fixed_temperature > 0 else temp * 0.5**k
            temp_k = torch.as_tensor(temp_k, dtype=src.dtype, device=self.device).reshape(1)
            dR, dt, _, g = solve_transform_inference(
                moved, tgt, sb, temp_k, use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma
            )
            R, t, gamma = dR[0] @ R, dR[0] @ t + dt[0], g[0]
            small_rot = rotation_angle_deg(dR[0]) < rc.deep_rot_tol_deg
            converged = small_rot and float(dt.norm()) / scale < rc.deep_trans_tol
            lap("solve")
            if converged:
                break
        return NetworkOutput(R.cpu().numpy(), t.cpu().numpy(), gamma.float().cpu().numpy(), temperature, k + 1,
                             bool(converged))

    def starts(self, src: torch.Tensor, tgt: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
               n_passes: int | None = None, lap: Callable[[str], None] | None = None) -> list[NetworkOutput]:
        """:meth:`passes` from K starts at once: src (1, N, 3), tgt (1, M, 3) scaled, R (K, 3, 3), t (K, 3) scaled.

        The source moved K ways goes through the network as one batch of K against the target's state computed
        once (broadcast to the batch); a start whose increment is small leaves the batch (as :meth:`passes`
        stops), so every output equals the one of :meth:`passes` from that start (to float round-off).
        -> K :class:`NetworkOutput` s in the order of the starts."""
        rc, scale = self.config.registration, self.model.scale
        lap = lap or (lambda _stage: None)
        n_deep = self.n_deep if n_passes is None else n_passes
        n_starts = int(R.shape[0])
        tgt_cache = self.target_state(tgt)
        R, t = R.clone(), t.clone()
        gamma = src.new_ones(n_starts, src.shape[1])
        temperature = [0.0] * n_starts
        iterations, converged = [0] * n_starts, [False] * n_starts
        active = list(range(n_starts))  # the starts still in the batch
        knn = None
        lap("embed")
        for k in range(n_deep):
            b = len(active)
            idx = torch.as_tensor(active, device=self.device)
            Ra, ta = R[idx], t[idx]
            moved = apply_transform(src.expand(b, *src.shape[1:]), Ra, ta)
            f_src, knn = self.model.point_features(moved, knn)
            phi_src, phi_tgt = self.model.cross_cached(f_src, _expand(tgt_cache, b))
            temp = self.model.predict_temperature(phi_src, phi_tgt)
            lap("embed")
            sb = self.model.match_inference(phi_src, phi_tgt)
            lap("match")
            temp_k = rc.fixed_temperature if rc.fixed_temperature > 0 else temp * 0.5**k
            temp_k = torch.as_tensor(temp_k, dtype=src.dtype, device=self.device).reshape(-1).expand(b)
            dR, dt, _, g = solve_transform_inference(
                moved, tgt.expand(b, *tgt.shape[1:]), sb, temp_k, use_gamma=rc.use_gamma,
                spatial_gamma=rc.spatial_gamma,
            )
            R[idx] = dR @ Ra
            t[idx] = (dR @ ta[:, :, None])[:, :, 0] + dt
            gamma[idx] = g
            keep = []
            for j, i in enumerate(active):
                if k == 0:
                    temperature[i] = float(temp[j])
                iterations[i] = k + 1
                converged[i] = (rotation_angle_deg(dR[j]) < rc.deep_rot_tol_deg
                                and float(dt[j].norm()) / scale < rc.deep_trans_tol)
                if not converged[i]:
                    keep.append(j)
            lap("solve")
            if not keep:
                break
            active = [active[j] for j in keep]
            knn = knn[torch.as_tensor(keep, device=knn.device)]
        return [NetworkOutput(R[i].cpu().numpy(), t[i].cpu().numpy(), gamma[i].float().cpu().numpy(), temperature[i],
                              iterations[i], bool(converged[i])) for i in range(n_starts)]

    # -- the kept target states --------------------------------------------------------------------
    def target_state(self, tgt: torch.Tensor) -> TargetCache:
        """The network's target-only state for tgt (1, M, 3) (scaled), reused when the same points (byte for
        byte) come back as a target: a fixed map cloud, or the last source (:meth:`keep_state`)."""
        key = cloud_key(tgt)
        with self._target_lock:
            hit = self._target_memo.get(key)
            if hit is not None:
                self._target_memo.move_to_end(key)
        if hit is not None and torch.equal(hit[0], tgt):
            return hit[1]
        f_tgt, _ = self.model.point_features(tgt)
        state = self.model.target_cache(f_tgt)
        self.keep_state(tgt, state, key)
        return state

    def keep_state(self, cloud: torch.Tensor, state: TargetCache, key: tuple | None = None) -> None:
        """Keep a cloud's network state for when it is a target (the three most recent clouds: a fixed target,
        the last source and the global search's ranking prefix of a target all stay; not for a model object handed
        in, whose weights may change).
        ``key``: the cloud's :func:`cloud_key`, when the caller has it."""
        if not self._memo_targets:
            return
        key = cloud_key(cloud) if key is None else key
        with self._target_lock:
            self._target_memo[key] = (cloud.clone(), state)
            while len(self._target_memo) > 3:
                self._target_memo.popitem(last=False)

    # -- numpy entry points (the network process) ----------------------------------------------------
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
