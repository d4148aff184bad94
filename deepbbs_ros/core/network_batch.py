"""The deep passes from K starts at once, as one batch (the global search's start yaws; no ROS): a part of
:class:`~deepbbs_ros.core.network.DeepBBSNetwork`."""

from __future__ import annotations

from collections.abc import Callable

import torch

from deepbbs_ros.config import Config, RegistrationConfig
from deepbbs_ros.core.model import DeepBBSNet, TargetCache, solve_transform_inference
from deepbbs_ros.core.network_output import NetworkOutput
from deepbbs_ros.core.procrustes import apply_transform
from deepbbs_ros.core.refine import rotation_angle_deg

__all__ = ["BatchedPasses", "pass_temperature", "small_increment"]


def pass_temperature(rc: RegistrationConfig, temp: torch.Tensor, k: int, n: int, dtype: torch.dtype,
                     device: torch.device) -> torch.Tensor:
    """The soft map's T (n,) of deep pass ``k``: the predicted ``temp`` halved every pass, or
    ``registration.fixed_temperature`` where it is set (> 0)."""
    temp_k = rc.fixed_temperature if rc.fixed_temperature > 0 else temp * 0.5**k
    return torch.as_tensor(temp_k, dtype=dtype, device=device).reshape(-1).expand(n)


def small_increment(rc: RegistrationConfig, dR: torch.Tensor, dt: torch.Tensor, scale: float) -> bool:
    """A pass's increment dR (3, 3), dt (3,) (scaled) within ``registration.deep_rot_tol_deg`` and
    ``deep_trans_tol`` (m): the passes from that start stop."""
    return rotation_angle_deg(dR) < rc.deep_rot_tol_deg and float(dt.norm()) / scale < rc.deep_trans_tol


def expand_state(cache: TargetCache, k: int) -> TargetCache:
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


class BatchedPasses:
    """Part of :class:`~deepbbs_ros.core.network.DeepBBSNetwork`: :meth:`starts`."""

    # what it reads of the DeepBBSNetwork it is part of
    config: Config
    device: torch.device
    model: DeepBBSNet
    n_deep: int
    target_state: Callable[[torch.Tensor], TargetCache]  # DeepBBSNetwork.target_state

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
            phi_src, phi_tgt = self.model.cross_cached(f_src, expand_state(tgt_cache, b))
            temp = self.model.predict_temperature(phi_src, phi_tgt)
            lap("embed")
            sb = self.model.match_inference(phi_src, phi_tgt)
            lap("match")
            temp_k = pass_temperature(rc, temp, k, b, src.dtype, self.device)
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
                converged[i] = small_increment(rc, dR[j], dt[j], scale)
                if not converged[i]:
                    keep.append(j)
            lap("solve")
            if not keep:
                break
            active = [active[j] for j in keep]
            knn = knn[torch.as_tensor(keep, device=knn.device)]
        return [NetworkOutput(R[i].cpu().numpy(), t[i].cpu().numpy(), gamma[i].float().cpu().numpy(), temperature[i],
                              iterations[i], bool(converged[i])) for i in range(n_starts)]
