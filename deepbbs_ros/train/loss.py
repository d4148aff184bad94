"""The DeepBBS training loss (paper, eq. 9), in the network's scaled units.

    L = ||R_gt^T R - I||_F^2 + w_t ||s (t_gt - t)||^2
        + beta^epoch * sum_i gamma_gt_i ||s (q^_i - (R_gt p_i + t_gt))||^2 / max(sum_i gamma_gt_i, 1)

averaged over the batch, where ``s = model.scale``. Units: the network returns ``t`` and ``q^`` in
metres; the translation and correspondence terms are computed after multiplying by ``s`` (1/40 by
default), i.e. in the unit-sized coordinates the paper's loss (and its weighting against the
dimensionless rotation term) was designed for. With s = 0.025, a 1 degree rotation error
(Frobenius term 6.1e-4) weighs as much as a 1 m translation error (6.3e-4): the same balance LiDAR
alignment needs, where 1 degree moves points 40 m away by 0.7 m. In metres the translation would
swamp the rotation by three orders of magnitude. ``w_t`` (``train.trans_weight``, 1 in the paper)
shifts that balance: the success criterion (1 degree, 0.3 m) weighs 0.3 m like 1 degree, i.e.
w_t ~ 5.

**Bounded per pair** (``train.pose_loss: bounded``). The pose term ``p = rot + w_t trans`` of each pair
is replaced by ``2 c (sqrt(1 + p / c) - 1)`` (pseudo-Huber, Charbonnier), ``c`` the pose term of a pair at
the success tolerance (``eval.success_rot_deg``, ``eval.success_trans``: 1 degree and 0.3 m give
c = 6.1e-4 + w_t 5.6e-5). Below the tolerance it is the squared loss (p for p << c); beyond it grows like
the error instead of its square, so a pair's pull on the network (the gradient with respect to its pose
error) is at most 2 sqrt(c), about 1.4 times that of a pair at the tolerance. A pair many degrees off
(one the network cannot solve in one pass: the search's starts are there for it) still says which way to
go, but can no longer outweigh the batch's pairs near the tolerance, which the success criterion
measures. Rotation and translation are bounded together: a pair whose rotation is far off has a
translation error that follows from it.

**Hard pairs left out** (``train.hard_pair_deg`` > 0). A pair the network's own pass (this step's forward
pass, detached) leaves more than ``hard_pair_deg`` off in rotation adds nothing to the step: the batch's loss is
the mean over the other pairs (0 when none is left). In the sensor mix, halls and garages bring pairs the shipped
network leaves over 10 deg off (55-62 % of them); those carried 94-95 % of the rotation term and steered the steps
away from the translation precision the success criterion measures. Left out, a pair comes back once the network
gets it within the bound: a curriculum the network sets itself.

``gamma_gt_i = 1`` when source point p_i, moved by the ground truth, has a target point within
``theta`` metres (a true partner), else 0. The mean over partners is guarded: a pair with no
partner at all contributes 0 to the correspondence term instead of NaN.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class LossTerms(NamedTuple):
    """Batch means (0-d tensors); ``total`` carries the gradient, the rest are for logging."""

    total: object
    rot: object
    trans: object
    corr: object
    partner_ratio: object  # mean fraction of source points with a true partner
    kept: object = 1.0  # share of the batch's pairs in the loss (below 1 only with hard_pair_deg > 0)


def partner_mask(src, tgt, R_gt, t_gt, theta: float):
    """gamma_gt: (B, N) float32, 1 where ``R_gt p_i + t_gt`` has a target point within ``theta`` m.

    Args:
        src: (B, N, 3) source points, metres. tgt: (B, M, 3) target points, metres.
        R_gt: (B, 3, 3), t_gt: (B, 3): ground truth T_target_source.
    """
    import torch

    with torch.no_grad():
        moved = src @ R_gt.transpose(1, 2) + t_gt[:, None, :]
        nearest = torch.cdist(moved, tgt).min(dim=2).values
        return (nearest <= theta).to(src.dtype)


def tolerance_pose_term(rot_deg: float, trans_m: float, *, scale: float, trans_weight: float) -> float:
    """The pose term ``rot + w_t trans`` of a pair off by exactly ``rot_deg`` degrees and ``trans_m`` metres."""
    return 4.0 * (1.0 - math.cos(math.radians(rot_deg))) + trans_weight * (scale * trans_m) ** 2


def bounded_pose(pose, c: float):
    """``2 c (sqrt(1 + pose / c) - 1)`` of the per-pair tensor ``pose`` (>= 0): ~pose below c, ~sqrt above."""
    return 2.0 * c * ((1.0 + pose / c).sqrt() - 1.0)


def loss_options(config, epoch: int) -> dict:
    """``deepbbs_loss``'s keyword arguments from a ``Config`` (train, model and eval sections) at ``epoch``."""
    tc = config.train
    bound = 0.0
    if tc.pose_loss == "bounded":
        bound = tolerance_pose_term(config.eval.success_rot_deg, config.eval.success_trans,
                                    scale=config.model.scale, trans_weight=tc.trans_weight)
    return {"scale": config.model.scale, "theta": tc.theta, "corr_weight": tc.beta ** epoch,
            "trans_weight": tc.trans_weight, "pose_bound": bound, "hard_pair_deg": tc.hard_pair_deg}


def deepbbs_loss(out, src, tgt, R_gt, t_gt, *, scale: float, theta: float, corr_weight: float,
                 trans_weight: float = 1.0, pose_bound: float = 0.0, hard_pair_deg: float = 0.0) -> LossTerms:
    """The loss above.

    Args:
        out: the network's ``NetOutput`` (R (B,3,3), t (B,3) m, q_hat (B,N,3) m, ...).
        src: (B, N, 3) float32 source (network input, metres). tgt: (B, M, 3) float32 target.
        R_gt: (B, 3, 3), t_gt: (B, 3) metres: ground-truth T_target_source.
        scale: model.scale (metres -> network units). theta: partner radius in metres.
        corr_weight: beta ** epoch.
        trans_weight: w_t, the weight of the translation term (1 = the paper).
        pose_bound: c of the bounded per-pair pose term (``tolerance_pose_term``); 0 = the squared loss.
        hard_pair_deg: pairs whose rotation error is above this many degrees are left out; 0 = none is.
    """
    import torch

    B = src.shape[0]
    eye = torch.eye(3, dtype=src.dtype, device=src.device).expand(B, 3, 3)
    rot = ((R_gt.transpose(1, 2) @ out.R - eye) ** 2).sum(dim=(1, 2))
    trans = ((scale * (t_gt - out.t)) ** 2).sum(dim=1)
    gamma_gt = partner_mask(src, tgt, R_gt, t_gt, theta)
    q_gt = src @ R_gt.transpose(1, 2) + t_gt[:, None, :]
    err = ((scale * (out.q_hat - q_gt)) ** 2).sum(dim=2)
    corr = (gamma_gt * err).sum(dim=1) / gamma_gt.sum(dim=1).clamp_min(1.0)
    pose = rot + trans_weight * trans
    if pose_bound > 0:
        pose = bounded_pose(pose, pose_bound)
    total = pose + corr_weight * corr
    if hard_pair_deg > 0:  # 4 (1 - cos angle) is the rotation term of a pair off by angle
        keep = (rot.detach() <= 4.0 * (1.0 - math.cos(math.radians(hard_pair_deg)))).to(total.dtype)
        loss, kept = (keep * total).sum() / keep.sum().clamp_min(1.0), keep.mean()
    else:
        loss, kept = total.mean(), torch.ones((), dtype=total.dtype)
    return LossTerms(loss, rot.mean().detach(), trans.mean().detach(), corr.mean().detach(),
                     gamma_gt.mean().detach(), kept.detach())
