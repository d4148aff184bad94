"""The optional SoftBBS refinements of one ``DeepBBSRegistration.register`` call (no ROS): on the sampled points
(``registration.refine``), on the voxelised non-ground clouds (``registration.dense_refine``), within the overlap of
the two sensors' crops; and the inlier ratio of an estimate."""

from __future__ import annotations

import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.procrustes import apply_transform
from deepbbs_ros.core.refine import refine
from deepbbs_ros.core.registration_state import State

__all__ = ["RefineStages"]


class RefineStages:
    """Part of :class:`~deepbbs_ros.core.registration.DeepBBSRegistration`: the refinements."""

    # what it reads of the DeepBBSRegistration it is part of
    config: Config
    model: DeepBBSNet
    device: torch.device

    def _refine(self, st: State) -> None:
        """DeepBBS++: SoftBBS on xyz over the k nearest targets, until the increment is tiny."""
        rc, scale = self.config.registration, self.model.scale
        if not rc.refine:
            return
        s_in, t_in, keep = st.src[0], st.tgt[0], None
        if rc.refine_overlap_crop:
            keep, t_keep = _overlap(s_in, t_in, st.R, st.t, self.config.preprocess.max_range * scale)
            if int(keep.sum()) >= 3 and int(t_keep.sum()) >= 3:
                s_in, t_in = s_in[keep], t_in[t_keep]
            else:
                keep = None
        t_ref = rc.refine_temperature * scale if rc.refine_temperature > 0 else 1.0
        ref = refine(
            s_in, t_in, st.R, st.t,
            k=rc.refine_k, max_iters=rc.refine_max_iters, rot_tol_deg=rc.refine_rot_tol_deg,
            trans_tol=rc.refine_trans_tol * scale, xi=self.model.cfg.xi, temperature=t_ref,
            use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma, search=st.search if keep is None else None,
            alpha_start=rc.refine_alpha_start,
        )  # fmt: skip
        st.R, st.t, st.gamma, st.converged, st.iters["refine"] = ref.R, ref.t, ref.gamma, ref.converged, ref.iterations
        if keep is not None:  # points outside the overlap get gamma 0
            st.gamma = st.src.new_zeros(st.src.shape[1]).masked_scatter_(keep, ref.gamma)

    def _dense_refine(self, st: State) -> None:
        """The refinement on the voxelised non-ground clouds: a sharper alpha (their spacing is the voxel
        size, not the ~2 m of the sampled points) and a spatial T in metres."""
        rc, scale = self.config.registration, self.model.scale
        if not (rc.refine and rc.dense_refine and st.src_dense is not None and st.tgt_dense is not None):
            return
        d_src = torch.from_numpy(st.src_dense).to(self.device) * scale
        d_tgt = torch.from_numpy(st.tgt_dense).to(self.device) * scale
        if rc.refine_overlap_crop:
            ks, kt = _overlap(d_src, d_tgt, st.R, st.t, self.config.preprocess.max_range * scale)
            if int(ks.sum()) >= 3 and int(kt.sum()) >= 3:
                d_src, d_tgt = d_src[ks], d_tgt[kt]
        ref = refine(
            d_src, d_tgt, st.R, st.t,
            k=rc.dense_refine_k, max_iters=rc.dense_refine_max_iters, rot_tol_deg=rc.refine_rot_tol_deg,
            trans_tol=rc.refine_trans_tol * scale, xi=rc.dense_refine_xi,
            temperature=rc.dense_refine_temperature * scale,
            use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma,
        )  # fmt: skip
        st.R, st.t, st.converged, st.iters["dense"] = ref.R, ref.t, ref.converged, ref.iterations

    def _inlier_ratio(self, st: State, R: torch.Tensor, t: torch.Tensor) -> float:
        """Share of the sampled source points within ``registration.inlier_dist`` of a target point."""
        moved = apply_transform(st.src, R[None], t[None])[0]
        return float((st.search.nearest_distance(moved) / self.model.scale <= self.config.registration.inlier_dist)
                     .float().mean())


def _overlap(
    src: torch.Tensor, tgt: torch.Tensor, R: torch.Tensor, t: torch.Tensor, radius: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Masks of the points that both sensors could see: src (N, 3) and tgt (M, 3) (scaled) within
    ``radius`` of the other sensor under the estimate p_target = R p_source + t.

    Each scan was cropped at ``radius`` around its own sensor: a source point beyond ``radius`` of the
    target sensor has no partner in the target (and vice versa), and such unpaired ends of roads and
    walls pull a point-to-point refinement along the road. -> (src_mask (N,) bool, tgt_mask (M,) bool).
    """
    src_in_tgt = src @ R.T + t
    tgt_in_src = (tgt - t) @ R
    return src_in_tgt.norm(dim=1) <= radius, tgt_in_src.norm(dim=1) <= radius
