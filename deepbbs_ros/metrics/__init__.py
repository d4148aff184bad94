"""Registration and odometry metrics (CONVENTIONS.md), plus TUM/KITTI trajectory files.

Pure numpy maths with no ROS import; the only I/O is the small trajectory readers/writers at the
end (plain text that ``evo`` reads). Every transform is a (4, 4) float64 homogeneous matrix acting
on column vectors, ``p_target = R @ p_source + t``.

Rotations
    A rotation read from a file is made one once, by its reader (:func:`nearest_rotation`: the SVD
    projection onto SO(3), det +1; quaternions are normalised), so the same poses give the same figures
    whatever the file format. The angle of a rotation ``R`` is :func:`rotation_angle`,
    ``atan2(||vee(R - R^T)|| / 2, (trace(R) - 1) / 2)``: exact to about 1e-16 rad at every angle, where
    ``arccos((trace - 1) / 2)`` loses all digits below about 1e-8 rad (and about 0.05 deg when ``R`` is
    1e-6 off orthonormal). It is the angle evo computes (``Rotation.from_matrix(R).magnitude()``).
Per pair
    ``rot_err_deg`` = the angle of ``R_gt^T R`` in degrees, ``trans_err_m = ||t - t_gt||``; a pair
    succeeds when both are within the thresholds.
Per sequence (each the quantity evo computes on the trajectory files written by :func:`write_tum`)
    KITTI drift (the devkit's ``calcSequenceErrors``); ATE: position error after SE(3) Umeyama alignment
    (no scale; ``evo_ape tum gt est -a``); APE rotation: the angle of ``gt_k^-1 est_k``, no alignment
    (``evo_ape tum gt est --pose_relation angle_deg``); RPE between frames ``k - 1`` and ``k``
    (``evo_rpe tum gt est [--pose_relation angle_deg]``, evo's defaults ``--delta 1 --delta_unit f``).

Modules: :mod:`~deepbbs_ros.metrics.pairs` (rotations, per-pair errors, summaries),
:mod:`~deepbbs_ros.metrics.sequence` (KITTI drift, ATE, APE, RPE), :mod:`~deepbbs_ros.metrics.files` (TUM/KITTI
trajectory files); every public name is imported from here too.
"""

from deepbbs_ros.metrics.files import read_kitti, read_tum, write_kitti, write_tum
from deepbbs_ros.metrics.pairs import (
    nearest_rotation,
    pair_errors,
    project_pose,
    rotation_angle,
    rotation_error_deg,
    runtime_summary,
    success_mask,
    success_rate,
    summarize,
    translation_error_m,
)
from deepbbs_ros.metrics.sequence import (
    KITTI_LENGTHS,
    KITTI_STEP,
    ape_rotation_deg,
    ate_errors,
    ate_rmse,
    kitti_drift,
    kitti_segment_errors,
    rpe,
    trajectory_distances,
    umeyama_alignment,
)

__all__ = [
    "KITTI_LENGTHS", "KITTI_STEP", "ape_rotation_deg", "ate_errors", "ate_rmse", "kitti_drift", "kitti_segment_errors",
    "nearest_rotation", "pair_errors", "project_pose", "read_kitti", "read_tum", "rotation_angle", "rotation_error_deg",
    "rpe", "runtime_summary", "success_mask", "success_rate", "summarize", "trajectory_distances",
    "translation_error_m", "umeyama_alignment", "write_kitti", "write_tum",
]
