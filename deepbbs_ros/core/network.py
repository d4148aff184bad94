"""The DeepBBS++ network as one object: the model, its kept target states and the deep passes (no ROS).

:class:`DeepBBSNetwork` is what both the in-process path of ``DeepBBSRegistration.register`` and the
network's worker process (``core/network_process.py``) run::

    load        the checkpoint (weights, config's model section, metadata), or a model object handed in
    passes      embed / match / solve repeated on the moved source until the increment is small (DeepBBS)
    starts      the same from K start poses at once, as a batch of K (the global search's start yaws)
    targets     the target-only network state (DGCNN features, transformer memory) kept for the three most
                recent clouds: a fixed map target, or the last source that becomes the next target

Everything here runs in scaled coordinates (``model.scale`` times metres); the numpy entry points
(:meth:`DeepBBSNetwork.network_np`, :meth:`DeepBBSNetwork.starts_np`) take metres. Its parts: the passes from
K starts as one batch (core/network_batch.py), the numpy entry points (core/network_np.py); what it gives back and
the helpers the registration stages share (:func:`matrix`, :func:`orthonormalize`, :class:`Clock`):
core/network_output.py.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import warnings
import zlib
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.checkpoint import default_weights_path, load_checkpoint
from deepbbs_ros.core.model import DeepBBSNet, TargetCache, solve_transform_inference
from deepbbs_ros.core.network_batch import BatchedPasses, pass_temperature, small_increment
from deepbbs_ros.core.network_np import NumpyEntryPoints
from deepbbs_ros.core.network_output import Clock, NetworkOutput, matrix, orthonormalize, worker_share
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.procrustes import apply_transform
from deepbbs_ros.device import resolve_device
from deepbbs_ros.errors import ModelError

__all__ = ["Clock", "DeepBBSNetwork", "NetworkOutput", "matrix", "orthonormalize", "worker_share"]


def cloud_key(cloud: torch.Tensor) -> tuple:
    """(shape, CRC-32 of the bytes) of a (1, N, 3) tensor: the target memo's key (then compared exactly)."""
    return tuple(cloud.shape), zlib.crc32(cloud.detach().cpu().numpy().tobytes())


class DeepBBSNetwork(BatchedPasses, NumpyEntryPoints):
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
            temp_k = pass_temperature(rc, temp, k, 1, src.dtype, self.device)
            dR, dt, _, g = solve_transform_inference(
                moved, tgt, sb, temp_k, use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma
            )
            R, t, gamma = dR[0] @ R, dR[0] @ t + dt[0], g[0]
            converged = small_increment(rc, dR[0], dt[0], scale)
            lap("solve")
            if converged:
                break
        return NetworkOutput(R.cpu().numpy(), t.cpu().numpy(), gamma.float().cpu().numpy(), temperature, k + 1,
                             bool(converged))

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
