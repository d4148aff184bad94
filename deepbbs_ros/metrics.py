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
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from deepbbs_ros.errors import DatasetError

KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)  # m, devkit segment lengths
KITTI_STEP = 10  # frames between segment starts (devkit ``step_size``)


# --------------------------------------------------------------------------------------------------
# rotations
# --------------------------------------------------------------------------------------------------
def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``R`` in the Frobenius norm: ``U diag(1, 1, det(U V^T)) V^T`` of the SVD
    ``R = U S V^T`` (det +1, so a reflection is never returned).

    A pose file keeps 6-7 significant digits (KITTI) or so, leaving ``R^T R`` about 1e-6 off the
    identity; readers pass every matrix they read through this once, so that every metric downstream
    scores a rotation.

    Args:
        R: (3, 3) or (..., 3, 3) float64 matrices, finite (non-finite ones are returned unchanged).
    Returns:
        (..., 3, 3) float64 rotation matrices (``R^T R = I`` to about 1e-16).
    """
    R = np.array(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"nearest_rotation: expected (...,3,3) matrices, got shape {R.shape}")
    finite = np.isfinite(R).all(axis=(-2, -1))
    if not finite.all():
        out = R.copy()
        out[finite] = nearest_rotation(R[finite])
        return out
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= np.where(d == 0, 1.0, d)[..., None]
    return U @ Vt


def project_pose(T: np.ndarray) -> np.ndarray:
    """(4, 4) or (..., 4, 4) poses with the rotation block made a rotation (:func:`nearest_rotation`)
    and the last row ``[0, 0, 0, 1]``; a copy, float64."""
    T = np.array(T, dtype=np.float64)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"project_pose: expected (...,4,4) poses, got shape {T.shape}")
    T[..., :3, :3] = nearest_rotation(T[..., :3, :3])
    T[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return T


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle in radians, in [0, pi]: ``atan2(||vee(R - R^T)|| / 2, (trace(R) - 1) / 2)``.

    Both arguments are exact to about 1e-16 for a rotation (``sin`` and ``cos`` of the angle), so the
    angle is too, near 0 and near pi alike (``arccos`` of the cosine alone loses everything below about
    1e-8 rad). The same value as scipy's ``Rotation.from_matrix(R).magnitude()``, which evo uses.

    Args:
        R: (3, 3) or (..., 3, 3) rotations (also accepts (..., 4, 4) transforms). NaN in, NaN out.
    Returns:
        float64 scalar array or (...,) radians.
    """
    R = np.asarray(R, dtype=np.float64)[..., :3, :3]
    s = 0.5 * np.sqrt((R[..., 2, 1] - R[..., 1, 2]) ** 2 + (R[..., 0, 2] - R[..., 2, 0]) ** 2
                      + (R[..., 1, 0] - R[..., 0, 1]) ** 2)
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    return np.arctan2(s, c)


# --------------------------------------------------------------------------------------------------
# per-pair errors
# --------------------------------------------------------------------------------------------------
def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations, degrees: the angle of ``R_gt^T R_est`` (:func:`rotation_angle`).

    Args:
        R_est, R_gt: (3, 3) or (B, 3, 3) rotation matrices (also accepts (…, 4, 4) transforms).
    Returns:
        float64 scalar array (or (B,)) in degrees, in [0, 180].
    """
    R_est = np.asarray(R_est, dtype=np.float64)[..., :3, :3]
    R_gt = np.asarray(R_gt, dtype=np.float64)[..., :3, :3]
    return np.degrees(rotation_angle(np.swapaxes(R_gt, -1, -2) @ R_est))


def translation_error_m(t_est: np.ndarray, t_gt: np.ndarray) -> np.ndarray:
    """``||t_est - t_gt||`` in metres; t: (3,) or (B, 3)."""
    return np.linalg.norm(np.asarray(t_est, np.float64) - np.asarray(t_gt, np.float64), axis=-1)


def pair_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (deg) and translation (m) error of estimated ``T_target_source`` against ground truth.

    Args:
        T_est, T_gt: (4, 4) or (B, 4, 4) float64.
    Returns:
        (rot_err_deg, trans_err_m), scalars or (B,) float64.
    """
    T_est = np.asarray(T_est, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    if T_est.shape[-2:] != (4, 4) or T_gt.shape[-2:] != (4, 4):
        raise ValueError(f"pair_errors: expected (...,4,4) transforms, got {T_est.shape} and {T_gt.shape}")
    return rotation_error_deg(T_est, T_gt), translation_error_m(T_est[..., :3, 3], T_gt[..., :3, 3])


def success_mask(
    rot_err_deg: np.ndarray, trans_err_m: np.ndarray, rot_thresh_deg: float = 1.0, trans_thresh_m: float = 0.3
) -> np.ndarray:
    """(B,) bool: ``rot_err_deg <= rot_thresh_deg`` and ``trans_err_m <= trans_thresh_m`` (NaN fails)."""
    rot = np.asarray(rot_err_deg, dtype=np.float64)
    tr = np.asarray(trans_err_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return (rot <= rot_thresh_deg) & (tr <= trans_thresh_m)


def success_rate(
    rot_err_deg: np.ndarray, trans_err_m: np.ndarray, rot_thresh_deg: float = 1.0, trans_thresh_m: float = 0.3
) -> float:
    """Fraction of pairs within both thresholds (NaN when there are no pairs)."""
    ok = success_mask(rot_err_deg, trans_err_m, rot_thresh_deg, trans_thresh_m)
    return float(ok.mean()) if ok.size else float("nan")


def summarize(errors: Sequence[float] | np.ndarray) -> dict[str, float]:
    """``{"mean", "rmse", "median", "p95", "max"}`` of finite values (NaN entries when none)."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {k: float("nan") for k in ("mean", "rmse", "median", "p95", "max")}
    return {
        "mean": float(e.mean()),
        "rmse": float(np.sqrt(np.mean(e**2))),
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
    }


def runtime_summary(runtimes_ms: Sequence[float] | np.ndarray) -> dict[str, float]:
    """``{"mean", "p50", "p95"}`` of runtimes in milliseconds (NaN when empty)."""
    r = np.asarray(runtimes_ms, dtype=np.float64).ravel()
    r = r[np.isfinite(r)]
    if r.size == 0:
        return {"mean": float("nan"), "p50": float("nan"), "p95": float("nan")}
    return {"mean": float(r.mean()), "p50": float(np.median(r)), "p95": float(np.percentile(r, 95))}


# --------------------------------------------------------------------------------------------------
# sequence metrics
# --------------------------------------------------------------------------------------------------
def _stack(poses: Sequence[np.ndarray] | np.ndarray, name: str) -> np.ndarray:
    P = np.asarray(poses, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"{name}: expected (N,4,4) poses, got shape {P.shape}")
    return P


def _inv(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (…, 4, 4)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def trajectory_distances(T_world: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """(N,) cumulative path length in metres along the positions of ``T_world`` (first entry 0)."""
    P = _stack(T_world, "trajectory_distances")
    steps = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def kitti_segment_errors(
    T_world_est: Sequence[np.ndarray] | np.ndarray,
    T_world_gt: Sequence[np.ndarray] | np.ndarray,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = KITTI_STEP,
) -> np.ndarray:
    """Per-segment errors of the KITTI odometry devkit (``calcSequenceErrors``).

    For every first frame ``f = 0, step, 2 step, …`` and every length ``L``, the last frame ``l`` is the
    first frame whose ground-truth path distance exceeds ``dist[f] + L`` (segments that run past the
    end are skipped). With ``E = (est_f^-1 est_l)^-1 (gt_f^-1 gt_l)``, the segment errors are
    ``t_err = ||t(E)|| / L`` (m/m) and ``r_err = angle(E) / L`` (rad/m).

    Returns:
        (S, 4) float64 rows ``[first_frame, length_m, t_err (m/m), r_err (rad/m)]``.
    """
    est = _stack(T_world_est, "kitti_drift(est)")
    gt = _stack(T_world_gt, "kitti_drift(gt)")
    if est.shape != gt.shape:
        raise ValueError(f"kitti_drift: {len(est)} estimated poses but {len(gt)} ground-truth poses")
    dist = trajectory_distances(gt)
    rows = []
    for first in range(0, len(gt), step):
        for length in lengths:
            later = np.nonzero(dist[first:] > dist[first] + length)[0]
            if later.size == 0:
                continue
            last = first + int(later[0])
            d_gt = _inv(gt[first]) @ gt[last]
            d_est = _inv(est[first]) @ est[last]
            E = _inv(d_est) @ d_gt
            r = float(rotation_angle(E))
            t = float(np.linalg.norm(E[:3, 3]))
            rows.append((first, length, t / length, r / length))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4)


def kitti_drift(
    T_world_est: Sequence[np.ndarray] | np.ndarray,
    T_world_gt: Sequence[np.ndarray] | np.ndarray,
    lengths: Sequence[float] = KITTI_LENGTHS,
    step: int = KITTI_STEP,
) -> dict[str, float]:
    """KITTI drift averaged over all segments (devkit definition).

    Returns:
        ``{"t_err_pct": mean t_err * 100, "r_err_deg_per_100m": mean r_err * 180/pi * 100,
        "segments": S}``; the errors are NaN when the ground-truth path is shorter than every length.
    """
    seg = kitti_segment_errors(T_world_est, T_world_gt, lengths, step)
    if seg.shape[0] == 0:
        return {"t_err_pct": float("nan"), "r_err_deg_per_100m": float("nan"), "segments": 0}
    return {
        "t_err_pct": float(seg[:, 2].mean() * 100.0),
        "r_err_deg_per_100m": float(np.degrees(seg[:, 3].mean()) * 100.0),
        "segments": int(seg.shape[0]),
    }


def umeyama_alignment(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, float]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) float64 corresponding positions, N >= 3 (N = 1, 2 fall back to a translation /
            the best rotation about the line, as the SVD allows).
    Returns:
        (T (4, 4) float64 with ``[R t]``, scale s; s = 1 unless ``with_scale``).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] == 0:
        raise ValueError(f"umeyama_alignment: expected matching (N,3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var_s = (xs**2).sum() / src.shape[0]
        s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T, s


def _pair_of(T_world_est, T_world_gt, name: str) -> tuple[np.ndarray, np.ndarray]:
    est = _stack(T_world_est, f"{name}(est)")
    gt = _stack(T_world_gt, f"{name}(gt)")
    if est.shape != gt.shape:
        raise ValueError(f"{name}: {len(est)} estimated poses but {len(gt)} ground-truth poses")
    return est, gt


def ate_errors(
    T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray
) -> np.ndarray:
    """Absolute trajectory error per frame: (N,) metres between the estimated positions, moved by the SE(3)
    Umeyama alignment onto the ground-truth positions (no scale), and the ground-truth positions.

    evo's APE translation part with ``-a`` (``evo_ape tum gt.tum est.tum -a``): the same per-frame errors.
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "ate")
    p_est, p_gt = est[:, :3, 3], gt[:, :3, 3]
    T, _ = umeyama_alignment(p_est, p_gt)
    aligned = p_est @ T[:3, :3].T + T[:3, 3]
    return np.linalg.norm(aligned - p_gt, axis=1)


def ate_rmse(T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray) -> float:
    """Absolute trajectory error: RMSE (m) of :func:`ate_errors` (SE(3) Umeyama alignment, no scale);
    evo's ``evo_ape tum gt.tum est.tum -a`` rmse."""
    e = ate_errors(T_world_est, T_world_gt)
    return float(np.sqrt(np.mean(e**2)))


def ape_rotation_deg(T_world_est: Sequence[np.ndarray] | np.ndarray,
                     T_world_gt: Sequence[np.ndarray] | np.ndarray) -> np.ndarray:
    """Absolute rotation error per frame without alignment: (N,) degrees, the angle of ``gt_k^-1 est_k``.

    The replay's trajectories start at the first ground-truth pose, so no alignment is needed (an SE(3)
    alignment fitted to positions alone leaves the rotation about a straight drive's direction free).
    evo's ``evo_ape tum gt.tum est.tum --pose_relation angle_deg`` (no ``-a``).
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "ape_rotation")
    return rotation_error_deg(est, gt)


def rpe(
    T_world_est: Sequence[np.ndarray] | np.ndarray, T_world_gt: Sequence[np.ndarray] | np.ndarray, delta: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose error between frames ``k - delta`` and ``k`` (``delta`` in frames).

    ``E_k = (gt_{k-d}^-1 gt_k)^-1 (est_{k-d}^-1 est_k)``; returns ((N-d,) ``||t(E_k)||`` m, (N-d,) angle of
    ``R(E_k)`` deg). evo's ``evo_rpe tum gt.tum est.tum --delta d --delta_unit f`` (translation_part, and
    ``--pose_relation angle_deg``), consecutive pairs, no alignment.
    """
    est, gt = _pair_of(T_world_est, T_world_gt, "rpe")
    if len(est) <= delta:
        return np.zeros(0), np.zeros(0)
    d_est = _inv(est[:-delta]) @ est[delta:]
    d_gt = _inv(gt[:-delta]) @ gt[delta:]
    E = _inv(d_gt) @ d_est
    trans = np.linalg.norm(E[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angle(E))
    return trans, rot


# --------------------------------------------------------------------------------------------------
# trajectory files (evo-compatible)
# --------------------------------------------------------------------------------------------------
def _matrix_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()  # (..., 4) x y z w
    q = np.where(q[..., 3:4] < 0, -q, q)
    return q


def _quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def _num(v: float) -> str:
    """A float64 as the shortest text that reads back as the same float (``repr``: up to 17 digits)."""
    return repr(float(v))


def write_tum(
    path: str | Path, stamps_s: Sequence[float] | np.ndarray, T_world: Sequence[np.ndarray] | np.ndarray
) -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` per line (seconds, metres; unit quaternion, w >= 0).

    Every number is written in full (the shortest text that reads back as the same float64), so evo reads
    back the poses that were scored. ``stamps_s``: (N,) float seconds, or an integer array of nanoseconds
    (written exactly).
    """
    P = _stack(T_world, "write_tum") if len(T_world) else np.zeros((0, 4, 4))
    raw = np.asarray(stamps_s).ravel()
    if np.issubdtype(raw.dtype, np.integer):
        stamps = [f"{int(v) // 1_000_000_000}.{int(v) % 1_000_000_000:09d}" for v in raw]
    else:
        stamps = [_num(v) for v in raw.astype(np.float64)]
    if len(stamps) != P.shape[0]:
        raise ValueError(f"write_tum: {len(stamps)} stamps for {P.shape[0]} poses")
    with open(path, "w") as fh:
        if P.shape[0]:
            q = _matrix_to_quat_xyzw(P[:, :3, :3])
            for s, T, qq in zip(stamps, P, q):
                x, y, z = T[:3, 3]
                fh.write(" ".join([s, *(_num(v) for v in (x, y, z, *qq))]) + "\n")


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory; returns ((N,) stamps s, (N, 4, 4) float64). ``#`` lines are comments.

    Quaternions are normalised on reading (the rotation of a quaternion of any norm).
    """
    stamps, poses = [], []
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DatasetError(f"cannot read TUM trajectory {path}: {err.strerror or err}") from err
    for lineno, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: TUM line must hold 8 numbers: {line!r}") from err
        if len(vals) != 8:
            raise DatasetError(f"{path}:{lineno}: TUM line must hold 8 numbers, got {len(vals)}")
        T = np.eye(4)
        q = np.asarray(vals[4:8])
        if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
            raise DatasetError(f"{path}:{lineno}: invalid quaternion {vals[4:8]}")
        T[:3, :3] = _quat_xyzw_to_matrix(q / np.linalg.norm(q))
        T[:3, 3] = vals[1:4]
        stamps.append(vals[0])
        poses.append(T)
    return np.asarray(stamps, dtype=np.float64), np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)


def write_kitti(path: str | Path, T_world: Sequence[np.ndarray] | np.ndarray) -> None:
    """Write the first three rows of every pose, 12 numbers row-major per line, each in full (the shortest
    text that reads back as the same float64)."""
    P = _stack(T_world, "write_kitti") if len(T_world) else np.zeros((0, 4, 4))
    with open(path, "w") as fh:
        for T in P:
            fh.write(" ".join(_num(v) for v in T[:3, :].ravel()) + "\n")


def read_kitti(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file; returns (N, 4, 4) float64, each rotation block made a rotation
    (:func:`nearest_rotation`: a file with 6-7 digits per entry leaves it about 1e-6 off orthonormal)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as err:
        raise DatasetError(f"cannot read KITTI trajectory {path}: {err.strerror or err}") from err
    poses = []
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            vals = [float(v) for v in line.split()]
        except ValueError as err:
            raise DatasetError(f"{path}:{lineno}: KITTI pose line must hold 12 numbers: {line.strip()!r}") from err
        if len(vals) != 12:
            raise DatasetError(f"{path}:{lineno}: KITTI pose line must hold 12 numbers, got {len(vals)}")
        if not np.isfinite(vals).all():
            raise DatasetError(f"{path}:{lineno}: KITTI pose line holds a non-finite number: {line.strip()!r}")
        T = np.eye(4)
        T[:3, :] = np.asarray(vals).reshape(3, 4)
        poses.append(T)
    return project_pose(np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4))
