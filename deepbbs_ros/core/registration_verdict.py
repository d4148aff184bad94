"""The verdict of one ``DeepBBSRegistration.register`` call (no ROS): the score of a pose and whether it can be
trusted (core/verdict.py), on the clouds the call has."""

from __future__ import annotations

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import second_minimum, sweep_skew, verdict
from deepbbs_ros.core.good_start import good_start_points
from deepbbs_ros.core.registration_state import State

__all__ = ["VerdictStages"]


class VerdictStages:
    """Part of :class:`~deepbbs_ros.core.registration.DeepBBSRegistration`: the verdict."""

    # what it reads of the DeepBBSRegistration it is part of
    config: Config

    def _score(self, st: State, T: np.ndarray, dist: float | None = None) -> float:
        """The verdict's score of the pose T (4, 4) (core/verdict.py) at ``dist`` m (``verdict_dist``): against
        the target's precision-stage cloud when it has one (calibrated), else against its voxelised non-ground
        points, else against its sampled points within ``max(dist, inlier_dist)``."""
        rc = self.config.registration
        d = rc.verdict_dist if dist is None else dist
        if st.tgt_pc is not None and st.tgt_pc.tree is not None and st.tgt_pc.pending is None:
            return verdict.fitness(st.src_np, st.tgt_pc.tree, T, d)
        if st.tgt_dense is not None and len(st.tgt_dense) >= len(st.tgt_np):  # no precision stage: voxelised
            return verdict.fitness_to_points(st.src_np, st.tgt_dense, T, d)
        return verdict.fitness_to_points(st.src_np, st.tgt_np, T, max(d, rc.inlier_dist))  # sparse: a wider gate

    def _verdict(self, st: State) -> None:
        """The pose's score (fitness) and calibrated probability (core/verdict.py); valid from
        ``registration.verdict_probability``, unless it can slide to another minimum as good along its weakest
        direction (core/second_minimum.py, ``registration.second_minimum``)."""
        rc = self.config.registration
        st.score = self._score(st, st.T)
        if (st.tgt_pc is not None and st.tgt_pc.tree is not None and st.tgt_pc.pending is None
                and st.src_pc is not None):  # the good start's points and coefficients: they carry to real scans
            pts = good_start_points(st.src_pc, rc)
            st.probability = verdict.probability(pts, st.T, st.tgt_pc, rc.verdict_dist, "good_start")
            st.probability = verdict.times_within(st.probability, st.src_pc, st.tgt_pc, st.T, rc,
                                                  rc.verdict_probability)
            st.valid = verdict.is_valid(st.probability, rc.verdict_probability)
            if st.valid and rc.skew_check and st.deskew != "deskewed":  # per-point times: does a sweep bend the pose?
                self._skew(st)
            if st.valid and rc.second_minimum:  # a second minimum as good along the weakest direction: not sure
                st.ambiguity = second_minimum.check(pts, st.T, st.src_pc, st.tgt_pc, rc,
                                                      reach=rc.second_minimum_reach)
                st.valid = not st.ambiguity.ambiguous
            return
        # no precision stage: the voxelised non-ground points, else the sampled ones, for which the probability is
        # not calibrated: reported, and the fitness decides (registration.verdict_threshold)
        dense = st.tgt_dense is not None and len(st.tgt_dense) >= len(st.tgt_np)
        st.probability = verdict.probability(st.src_np, st.T, st.tgt_dense if dense else st.tgt_np, rc.verdict_dist)
        st.valid = verdict.is_valid(st.score, rc.verdict_threshold)

    def _skew(self, st: State) -> None:
        """The skew check (core/sweep_skew.py) of the pose of a pair whose scans kept their per-point times: not valid
        where the motion within either sweep says the pose cannot be within the tolerance; ``st.skew`` says what it
        found ("" where neither scan has times: nothing runs)."""
        bends, st.skew = sweep_skew.judge(st.src_pre, st.tgt_pre, st.T, self.config.registration,
                                          self.config.preprocess.min_range)
        st.valid = not bends
