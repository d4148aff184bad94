"""The odometry's model error per axis of the scan: what the motion model is observed to miss, where the residuals
cannot show it (no ROS import). :class:`MotionFloor` gives the floor that core/covariance.py ``odometry_covariance``
adds to a step's cluster-robust covariance; :func:`quantisation_floor` the first motion's, which has no prediction;
:func:`floor_term` turns a floor into a covariance. docs/node.md#covariances has the figures."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MOTION_WINDOW", "SWEEP_SPREAD", "MotionFloor", "floor_term", "quantisation_floor"]

#: the sweep's model error (odometry): deskewed with the constant velocity, a sweep keeps the motion the prediction
#: missed (about the step's deviation from it), and a scan deskewed with a velocity off by ``e`` lands ``e T / 2``
#: off (core/odometry.py ``_deskew_delta``): half the missed motion; a step is the difference of two scans' poses,
#: each off by its own sweep's half, so its standard deviation per axis is ``sqrt(2) / 2`` of the deviation's root
#: mean square (derived, not fitted)
SWEEP_SPREAD = 0.5 ** 0.5
#: steps whose deviations from the constant-velocity prediction make the floor's root mean square
MOTION_WINDOW = 10


def floor_term(floor: np.ndarray, T_map_scan: np.ndarray) -> np.ndarray:
    """(6, 6) the model error ``floor`` (6,) (standard deviations along the scan's axes x, y, z, roll, pitch, yaw, m
    and rad) as a covariance in the module's convention: rotated into the map frame by ``T_map_scan``'s rotation."""
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = np.asarray(T_map_scan, dtype=np.float64)[:3, :3]
    return B @ np.diag(np.square(np.asarray(floor, dtype=np.float64))) @ B.T


def quantisation_floor(cloud: Any, voxel_size: float, motion: float = 0.0) -> np.ndarray:
    """(6,) the first motion's model error, m and rad per axis: its start has no prediction to deviate from, so no
    :class:`MotionFloor`; what it registers to is the first scan's voxel map, and a turn of the scan by less than a
    voxel's uniform error (``voxel_size / sqrt(12)``) at the scan's mean range is not told apart by it: that angle
    per rotation axis (a car's first sweeps are off mostly in roll and pitch, the body's sway within the sweep);
    the motion's direction is known to the same angle, so its ``motion`` m (the first motion's length) to that angle
    times its length per position axis."""
    pts = np.asarray(cloud.points(), dtype=np.float64)[::16, :3]
    rng = float(np.mean(np.linalg.norm(pts, axis=1))) if len(pts) else 0.0
    angle = voxel_size * 12.0 ** -0.5 / max(rng, voxel_size)
    return np.array([angle * motion] * 3 + [angle] * 3)

class MotionFloor:
    """The odometry's model error per axis of the scan (x, y, z, roll, pitch, yaw), from what the motion model is
    observed to miss, as KISS-ICP's adaptive threshold measures it; per axis because a car's body vibrates in roll
    and pitch while its yaw follows the road smoothly, and an isotropic floor would spread the one over the other.

    * prediction: :data:`SWEEP_SPREAD` times the root mean square of the last :data:`MOTION_WINDOW` deviations of
      the pose from the constant-velocity prediction (m, rad), less the registration noise they carry: a deviation
      is the difference of two steps' motions, so it holds twice a step's GICP variance (:meth:`add_noise`, the
      mean over the window), which the step's GICP part counts already (on the simulated drives that noise was
      most of the position's deviations, and counting it twice made every set cautious);
    * sweep (rotation axes): the deskew turns each point with the mean velocity of the last motions, and a body that
      sways faster within the sweep (roll and pitch at 0.5-3 Hz) keeps the rotation the deskew missed, which no
      residual shows (the scan is self-consistent, only bent). A single scan after an exact one lands halfway: its
      pose takes half of the missed rotation as error and shows the other half as the motion's deviation from the
      deskew's, so the missed rotation is twice that deviation, and a step's standard deviation :data:`SWEEP_SPREAD`
      of it. On a drive the previous pose is off by its own sweep's half and the deviation is about the whole missed
      rotation (11 of 12 simulated drives: root mean square 0.063-0.088 deg against 0.077-0.081 missed in roll), so
      the factor 2 counts it about twice there; it stays because where a scan takes more of the bend it shows less
      (the simulated VLP-16 suburban street: 0.044 deg against 0.076, roll step error 0.57 of the missed roll), and
      without it, or with the deviation's registration noise taken out as well, VLP-16 sets go over their band.
      Only the rotation: the position's deviation from the deskew's motion is mostly GICP's own noise, which the
      pairs already count;
    * weak directions (:meth:`weak_sigma`): where the odometry held the prediction's position (core/degeneracy.py),
      the step along the direction is the prediction's, whose error is one whole deviation per held step, summed
      over the steps held in a row (the velocity along it is not measured again meanwhile); the held steps share that
      velocity error, and :meth:`held_cross` is what the accumulated pose gains from it beyond the steps' own."""

    def __init__(self, mode: str = "fixed") -> None:
        """``mode`` (``odometry.sweep_floor``): "fixed", the floor above; "adaptive" or "adaptive_bound", its rotation
        part's variance scaled by core/floor_scale.py's ``InnovationScale`` (a model tried, not the default)."""
        from collections import deque

        from deepbbs_ros.core.floor_scale import InnovationScale

        # ``odometry.sweep_floor``: the rotation floor's variance scaled to the innovations (core/floor_scale.py)
        self._scale = None if mode == "fixed" else InnovationScale(MOTION_WINDOW, bound=mode == "adaptive_bound")
        self.last_scale = 1.0  # the scale the last floor took (1: fixed, or no innovation known yet)
        self._devs: Any = deque(maxlen=MOTION_WINDOW)
        self._swept: Any = deque(maxlen=MOTION_WINDOW)
        self._free: Any = deque(maxlen=MOTION_WINDOW)  # position deviations of the steps not held
        self._noise: Any = deque(maxlen=MOTION_WINDOW)  # the GICP part's variance per step (add_noise)
        self._held = 0

    def add_noise(self, variance: np.ndarray) -> None:
        """The variance (6,) of a step's GICP part along the scan's axes (m^2, rad^2; :func:`odometry_covariance`):
        the registration's own noise, which the deviations of the next steps carry (:meth:`update`)."""
        self._noise.append(np.asarray(variance, dtype=np.float64))
        if self._scale is not None:
            self._scale.add_noise(self._noise[-1][3:])

    def update(self, pose: np.ndarray, prediction: np.ndarray | None, motion: np.ndarray | None = None,
               swept: np.ndarray | None = None, held: bool = False) -> np.ndarray | None:
        """Add the deviation of ``pose`` from ``prediction`` (None: no prediction, the first motion) and of the
        registered ``motion`` per period (4, 4) from ``swept``, the motion per period the sweep was deskewed with
        (None: not deskewed, no per-point times); ``held``: the odometry held the prediction along a weak direction
        -> the floor (6,), standard deviations along the scan's axes (m, rad); None while no deviation was
        measured."""
        if prediction is not None:
            self._devs.append(_log(np.linalg.solve(np.asarray(prediction, dtype=np.float64), pose)))
            if not held:
                self._free.append(self._devs[-1][:3])
            if motion is not None and swept is not None:
                self._swept.append(_log(np.linalg.solve(np.asarray(swept, dtype=np.float64), motion))[3:])
        self._held = self._held + 1 if held and self._devs else 0
        if not self._devs or prediction is None:
            if self._scale is not None:
                self._scale.add_step(None, None)
            if not self._devs:
                return None
        # a deviation from the prediction is the motion the model missed plus the registration noise of the step and
        # of the one before it (the prediction repeats that step's motion): twice a step's GICP variance, which the
        # step's own GICP part counts already
        noise = np.mean(np.asarray(self._noise), axis=0) if self._noise else np.zeros(6)
        missed = self._missed(np.mean(np.square(np.asarray(self._devs)), axis=0), 2.0 * noise)
        floor = SWEEP_SPREAD * np.sqrt(missed)
        if self._swept:  # kept whole: see the class docstring
            floor[3:] = np.maximum(floor[3:], self._sweep_floor())
        if self._scale is not None and prediction is not None:  # the scale from the innovations before this one
            lam = self.last_scale = self._scale.scale()
            self._scale.add_step(self._devs[-1][3:], np.square(floor[3:]))
            floor[3:] *= lam ** 0.5
        return floor

    def _missed(self, mean_square: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """(6,) the variance per axis of the motion the model missed: the window's mean square deviation
        ``mean_square`` less the registration ``noise`` it carries, not below 0 (scripts/benchmarks/covariance.py
        ``--position-floor`` scores estimates that never reach 0)."""
        return np.maximum(mean_square - noise, 0.0)

    def _sweep_floor(self) -> np.ndarray:
        """(3,) rad: the sweep's floor per rotation axis of the scan, from the last deviations of the registered
        motion from the deskew's (the class docstring; scripts/benchmarks/covariance.py ``--sweep-floor`` scores other
        estimates from the same deviations)."""
        return SWEEP_SPREAD * 2.0 * np.sqrt(np.mean(np.square(np.asarray(self._swept)), axis=0))

    def last_deviation(self, direction: np.ndarray) -> float:
        """m: the last step's deviation from its prediction along the unit ``direction`` (3,), the scan's axes (the
        constant velocity carries it into the next prediction); NaN before any."""
        if not self._devs:
            return float("nan")
        return float(abs(np.asarray(self._devs[-1][:3]) @ np.asarray(direction, dtype=np.float64)))

    def weak_sigma(self, direction: np.ndarray) -> float:
        """m: the prediction's standard deviation along the unit ``direction`` (3,), the scan's axes: the root mean
        square along it of the deviations of the steps not held (a held step's is the prediction's own, zero), times
        the square root of the steps held in a row (at least one); NaN before any step that was not held (the
        motion model never measured the direction: :func:`odometry_covariance` keeps its default)."""
        if not self._free:
            return float("nan")
        return float(np.sqrt(max(1, self._held) * self._free_var(direction)))

    def held_cross(self, direction: np.ndarray) -> float:
        """m^2: what the accumulated pose's variance along the unit ``direction`` (3,), the scan's axes, gains at this
        step beyond the step's own (:meth:`weak_sigma`) while the odometry holds it: the held steps' errors are not
        independent. Along a held direction the velocity is not measured; each held step adds the motion model's
        miss ``a_i`` (variance ``s^2``, the deviations' root mean square along it squared) to the velocity's error,
        which persists, so the ``j``-th held step is off by ``a_1 + ... + a_j`` (variance ``j s^2``: the step's own,
        :meth:`weak_sigma`) and shares ``min(i, j) s^2`` with the ``i``-th. Composed as independent steps (the node's
        chain) the ``k``-th adds ``k s^2``; its covariance with the ``k - 1`` held steps before it adds ``k (k - 1)
        s^2`` more (a stretch of ``k`` held steps is off by ``s^2 k (k + 1) (2 k + 1) / 6`` in all, not ``s^2 k (k +
        1) / 2``): that is this. 0 before the second held step in a row, or before any step that was not held."""
        if not self._free or self._held < 2:
            return 0.0
        return float(self._held * (self._held - 1) * self._free_var(direction))

    def _free_var(self, direction: np.ndarray) -> float:
        """m^2: the mean square along the unit ``direction`` (3,) of the deviations of the steps not held."""
        return float(np.mean(np.square(np.asarray(self._free) @ np.asarray(direction, dtype=np.float64))))


def _log(D: np.ndarray) -> np.ndarray:
    """(6,) ``[t, rotvec]`` of a (4, 4) motion."""
    from scipy.spatial.transform import Rotation

    return np.concatenate([D[:3, 3], Rotation.from_matrix(D[:3, :3]).as_rotvec()])
