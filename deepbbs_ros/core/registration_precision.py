"""The precision stage of one ``DeepBBSRegistration.register`` call (no ROS): small_gicp GICP on the dense scans
from the estimate (core/polish.py), then again on both scans deskewed with their own velocities when they agree
(core/pair_deskew.py); an answer the verdict does not take, finished on the scans' scene-sized grids."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core import finish_verdict, pair_deskew
from deepbbs_ros.core.good_start import good_start_points
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network_output import Clock, matrix, orthonormalize
from deepbbs_ros.core.polish import finish, polish
from deepbbs_ros.core.registration_state import State

__all__ = ["PrecisionStages"]


class PrecisionStages:
    """Part of :class:`~deepbbs_ros.core.registration.DeepBBSRegistration`: the precision stage."""

    # what it reads of the DeepBBSRegistration it is part of
    config: Config
    model: DeepBBSNet
    device: torch.device
    _inlier_ratio: Callable[..., float]  # RefineStages._inlier_ratio
    _verdict: Callable[[State], None]  # VerdictStages._verdict
    _skew: Callable[[State], None]  # VerdictStages._skew

    def _deskew(self, st: State, clock: Clock) -> None:
        """Both scans deskewed with their own stream velocities (``core.deskew.StreamDeskew``): the precision
        stage again, from its result, on their ``deskewed_cloud`` s when each velocity agrees with the pair's mean
        motion (core/pair_deskew.py); ``st.deskew`` says what happened."""
        if st.src_pre is None or st.tgt_pre is None:
            return
        st.T, st.deskew, n = pair_deskew.again(st.src_pre, st.tgt_pre, st.T, self.config.registration,
                                               st.polish_reason == "ok")
        st.iters["polish"] += n
        if st.deskew == "deskewed":
            clock.lap("deskew")

    def _polish(self, st: State, clock: Clock) -> None:
        """The precision stage: small_gicp GICP on the dense scans from the estimate (both clouds need
        their ``polish_cloud``; rejected results keep the estimate)."""
        rc = self.config.registration
        st.T = matrix(st.R, st.t, self.model.scale)
        if rc.polish == "none" or st.src_pc is None or st.tgt_pc is None:
            return
        pol = polish(st.src_pc, st.tgt_pc, st.T, rc, check=st.polish_check)
        st.iters["polish"], st.polish_reason = pol.iterations, pol.reason
        if pol.applied:
            self._take(st, pol.T_target_source)
            st.converged = pol.converged
        clock.lap("polish")

    def _take(self, st: State, T: np.ndarray) -> None:
        """GICP's pose ``T`` (4, 4) becomes the answer: its rotation orthonormalised, the inlier ratio at it."""
        st.T = T
        st.T[:3, :3] = orthonormalize(st.T[:3, :3])
        with torch.inference_mode():
            Rp = torch.as_tensor(st.T[:3, :3], dtype=st.src.dtype, device=self.device)
            tp = torch.as_tensor(st.T[:3, 3] * self.model.scale, dtype=st.src.dtype, device=self.device)
            st.inlier_ratio = self._inlier_ratio(st, Rp, tp)

    def _finish(self, st: State, clock: Clock) -> None:
        """An answer the verdict does not take, GICP's (the precision stage applied): finished on the scans'
        scene-sized grids (``registration.polish_voxel_angle``, :func:`core.polish.finish`: a narrow place's walls,
        floor and ceiling, which GICP's grid blends) and judged again (``registration.finish_grid`` "both": where
        GICP's grid does not hold it, on both grids, core/finish_verdict.py). Not on scans deskewed with their own
        velocities (the finer grids are the scans as measured), nor on one another candidate of the search made
        ambiguous (core/search_ambiguity.py); an answer the verdict takes stays GICP's."""
        rc = self.config.registration
        if (st.valid or st.rival or rc.polish == "none" or st.polish_reason != "ok" or st.deskew == "deskewed"
                or st.skew.startswith("rejected")  # a bent sweep: a finer grid does not unbend it
                or st.src_pc is None or st.tgt_pc is None):
            return
        fine = finish(st.src_pc, st.tgt_pc, st.T, rc)
        if fine is None or not fine.applied:
            return
        self._take(st, fine.T_target_source)
        st.iters["polish"] += fine.iterations
        clock.lap("polish")
        self._verdict(st)
        if not st.valid and rc.finish_grid == "both" and not st.skew.startswith("rejected"):  # on both grids
            prob, why = finish_verdict.judge(good_start_points(st.src_pc, rc), st.T, st.src_pc, st.tgt_pc, rc,
                                             rc.verdict_probability)
            if not why:
                st.probability, st.valid = prob, True
                if rc.skew_check:  # not run on a pose the probability did not take
                    self._skew(st)
