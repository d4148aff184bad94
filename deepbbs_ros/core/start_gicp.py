"""GICP from a start the caller vouches for (no ROS): the good start's first try (core/good_start.py) and its coarse
try's fine GICP (core/coarse_rescue.py), on the precision-stage clouds (``core.polish.PolishCloud``), each result's
rotation orthonormalised when applied."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from deepbbs_ros.core.network import orthonormalize
from deepbbs_ros.core.polish import PolishCloud, polish

__all__ = ["from_start", "good_start_gicp", "orthonormal"]


def good_start_gicp(src_pc: PolishCloud, tgt_pc: PolishCloud, T_init: np.ndarray, rc: Any) -> Any:
    """GICP from a vouched start ``T_init`` (4, 4) within the good start's limits (``registration.good_start_max_*``
    in place of ``polish_max_*``) -> the :func:`core.polish.polish` result, its rotation orthonormalised when applied
    (the coarse try's fine GICP, core/coarse_rescue.py)."""
    cfg = dataclasses.replace(rc, polish_max_iters=rc.good_start_max_iters, polish_max_trans=rc.good_start_max_trans,
                              polish_max_rot_deg=rc.good_start_max_rot_deg)
    return orthonormal(polish(src_pc, tgt_pc, T_init, cfg))


def from_start(src_pc: PolishCloud, tgt_pc: PolishCloud, T_init: np.ndarray, rc: Any) -> Any:
    """GICP from the vouched start ``T_init`` (4, 4) with GICP's own settings (``registration.polish_*``: its
    iterations, the GICP baseline's; no limit on how far it moves, as GICP alone) -> the :func:`core.polish.polish`
    result, its rotation orthonormalised when applied."""
    if rc.polish_max_trans or rc.polish_max_rot_deg:  # the full pipeline's limits on the precision stage's move
        rc = dataclasses.replace(rc, polish_max_trans=0.0, polish_max_rot_deg=0.0)
    return orthonormal(polish(src_pc, tgt_pc, T_init, rc))


def orthonormal(pol: Any) -> Any:
    """The :func:`core.polish.polish` result ``pol``, its rotation orthonormalised when applied."""
    if pol.applied:
        pol.T_target_source[:3, :3] = orthonormalize(pol.T_target_source[:3, :3])
    return pol
