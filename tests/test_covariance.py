"""The pose covariance of a GICP solution (deepbbs_ros/core/covariance.py) against known truth: its convention (the
cost's curvature along perturbations of the pose), Monte-Carlo NEES of the cluster-robust covariance on a synthetic
structured scene with independent and with correlated errors (no fitted constant), the Student widening on a linear
problem with few cells, a degenerate corridor, the odometry's sweep floor, composition along a chain, and the
localizer's covariance on every valid pose."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from deepbbs_ros.core.covariance import (
    SWEEP_SPREAD,
    MotionFloor,
    compose,
    effective_cells,
    gicp_covariance,
    gicp_hessian,
    is_covariance,
    jackknife_meat,
    matched_pairs,
    pose_error,
    sandwich_covariance,
    student_widened,
)
from deepbbs_ros.core.polish import prepare_polish_cloud

small_gicp = pytest.importorskip("small_gicp")


def _plane(rng, c, u, v, a, b, m):
    s = rng.uniform(-1, 1, (m, 2))
    return c + s[:, :1] * a * u + s[:, 1:] * b * v


def _scene(rng, n: int, corridor: bool = False) -> np.ndarray:
    """Floor, two walls (4 m apart for a corridor, 20 m for a room), and for the room an end wall and six boxes."""
    X, Y, Z = np.eye(3)
    half = 2.0 if corridor else 10.0
    pts = [_plane(rng, np.zeros(3), X, Y, 20, half, n),
           _plane(rng, np.array([0, half, 1.5]), X, Z, 20, 1.5, n // 2),
           _plane(rng, np.array([0, -half, 1.5]), X, Z, 20, 1.5, n // 2)]
    if not corridor:
        pts.append(_plane(rng, np.array([12, 0, 1.5]), Y, Z, 10, 1.5, n // 3))
        for c in rng.uniform(-8, 8, (6, 2)):
            for d in (X, Y):
                pts.append(_plane(rng, np.array([c[0], c[1], 1.0]) + 0.5 * d, np.cross(d, Z), Z, 0.5, 1.0, n // 20))
    return np.concatenate(pts)


def _pose(rng, rot_sigma=0.2, trans_sigma=3.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, rot_sigma, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, trans_sigma, 3)
    return T


def _patches(rng, pts: np.ndarray, size: float, sigma: float) -> np.ndarray:
    """``pts`` with every ``size``-m cube of them moved by one offset (normal, ``sigma`` m per axis): errors that
    neighbouring points share (a surface sampled or mapped a little off)."""
    _, cell = np.unique(np.floor(pts / size).astype(np.int64), axis=0, return_inverse=True)
    cell = cell.ravel()
    return pts + rng.normal(0, sigma, (int(cell.max()) + 1, 3))[cell]


def _trial(rng, base, start_offset, voxel=0.5, noise=0.02, shared=0.0):
    """Two noisy samplings of ``base`` (the source's with 2 m patches moved by ``shared`` m as well), the source
    moved by a random T_target_source; GICP from the truth moved by ``start_offset`` (3,) -> (true T, estimate,
    cluster-robust covariance (inflation 1, no weak prior), raw ``s^2 H^-1``, the pairs)."""
    m = len(base) // 2
    tgt = base[rng.choice(len(base), m, replace=False)] + rng.normal(0, noise, (m, 3))
    src_w = base[rng.choice(len(base), m, replace=False)] + rng.normal(0, noise, (m, 3))
    if shared:
        src_w = _patches(rng, src_w, 2.0, shared)
    T = _pose(rng)
    src = (src_w - T[:3, 3]) @ T[:3, :3]  # p_target = R p_source + t
    tc, sc = prepare_polish_cloud(tgt, voxel, 20, threads=1), prepare_polish_cloud(src, voxel, 20, threads=1)
    init = T.copy()
    init[:3, 3] += start_offset
    res = small_gicp.align(tc.cloud, sc.cloud, tc.tree, init_T_target_source=init, max_correspondence_distance=2.0,
                           max_iterations=50)
    Te = np.asarray(res.T_target_source)
    pairs = matched_pairs(sc, tc, Te, 2.0)
    raw = gicp_covariance(*gicp_hessian(sc, tc, Te, max_corr_dist=2.0), Te)
    return T, Te, sandwich_covariance(pairs, Te, 1.0), raw, pairs


def _nees(T, Te, cov) -> float:
    d = pose_error(T, Te)
    return float(d @ np.linalg.solve(cov, d))


def test_convention_moves_with_the_target_frame():
    """The covariance is of the position and the rotation in the target frame (module convention): the same problem
    with its target frame moved by G (60 m away, turned) gives ``diag(R_G, R_G) Sigma diag(R_G, R_G)^T``, not the
    SE(3) adjoint's (a rotation read about the far origin) nor the unchanged matrix (a right perturbation)."""
    rng = np.random.default_rng(3)
    base = _scene(rng, 6000)
    T = _pose(rng)
    tgt = base + rng.normal(0, 0.02, base.shape)
    src = ((base + rng.normal(0, 0.02, base.shape)) - T[:3, 3]) @ T[:3, :3]
    G = _pose(rng, 1.0, 0.0)
    G[:3, 3] = [60.0, -20.0, 3.0]
    covs = []
    for Tg in (np.eye(4), G):
        tc = prepare_polish_cloud(tgt @ Tg[:3, :3].T + Tg[:3, 3], 0.0, 20, threads=1)
        sc = prepare_polish_cloud(src, 0.0, 20, threads=1)
        res = small_gicp.align(tc.cloud, sc.cloud, tc.tree, init_T_target_source=Tg @ T,
                               max_correspondence_distance=2.0, max_iterations=50)
        Te = np.asarray(res.T_target_source)
        covs.append(gicp_covariance(*gicp_hessian(sc, tc, Te, max_corr_dist=2.0), Te))
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = G[:3, :3]
    np.testing.assert_allclose(covs[1], B @ covs[0] @ B.T, rtol=0.05, atol=0.02 * np.abs(covs[0]).max())


def _band(n: int, p: float = 0.999) -> tuple[float, float]:
    """The ``p`` band of the mean of ``n`` chi2(6)."""
    return chi2.ppf((1 - p) / 2, 6 * n) / n, chi2.ppf((1 + p) / 2, 6 * n) / n


def test_sandwich_nees_is_chi2_with_independent_errors():
    """Seeded transforms and independent noise on a synthetic structured scene, GICP from 10 cm off: the cluster-robust
    covariance with a cell per voxel (independent residuals: the true model here) gives a mean NEES over 30 trials in
    the 99.9 % band of the mean of 30 chi2(6), with no fitted constant; with the node's cells it is not
    overconfident (the scene's fixed geometry adds cell sums that cancel over the scene: cautious); the residuals'
    Hessian alone (``s^2 H^-1``) is far too confident even here (small_gicp's normalised point covariances weigh the
    residuals by a shape, not by their variance)."""
    rng = np.random.default_rng(11)
    base = _scene(rng, 8000)
    trials = [_trial(rng, base, rng.normal(0, 0.1, 3)) for _ in range(30)]
    own = np.array([_nees(T, Te, sandwich_covariance(p, Te, 1.0, cell=0.5)) for T, Te, _, _, p in trials])
    node = np.array([_nees(T, Te, cov) for T, Te, cov, *_ in trials])
    raw = np.array([_nees(T, Te, r) for T, Te, _, r, _ in trials])
    lo, hi = _band(len(own))
    assert lo <= own.mean() <= hi, (own.mean(), (lo, hi))
    assert node.mean() <= hi, node.mean()
    assert raw.mean() > 1.5 * hi, raw.mean()


def test_sandwich_follows_errors_that_neighbours_share():
    """The same with every 2 m patch of the source moved by a shared 3 cm offset (most of the pose error now comes
    from a few dozen patches, not from thousands of independent points): the node's cells give a mean NEES in the
    99.9 % band of the mean of 30 chi2(6) (the node's leave-one-cell-out covariance, and the plain cluster sums
    ``H^-1 B H^-1 G / (G - 6)`` alike), while a cell per voxel (what treating the residuals as independent means) and
    the raw ``s^2 H^-1`` are overconfident."""
    rng = np.random.default_rng(12)
    base = _scene(rng, 8000)
    trials = [_trial(rng, base, rng.normal(0, 0.1, 3), shared=0.03) for _ in range(30)]
    node = np.array([_nees(T, Te, cov) for T, Te, cov, *_ in trials])
    own = np.array([_nees(T, Te, sandwich_covariance(p, Te, 1.0, cell=0.5)) for T, Te, _, _, p in trials])
    raw = np.array([_nees(T, Te, r) for T, Te, _, r, _ in trials])
    cr1 = np.array([_nees(T, Te, sandwich_covariance(p, Te, 1.0, jackknife=False)) for T, Te, _, _, p in trials])
    lo, hi = _band(len(node))
    assert lo <= node.mean() <= hi, (node.mean(), (lo, hi))
    assert lo <= cr1.mean() <= hi, (cr1.mean(), (lo, hi))
    assert own.mean() > hi and raw.mean() > hi, (own.mean(), raw.mean())


def test_degenerate_corridor_is_uncertain_along_its_axis():
    """A 4 m wide corridor along x and GICP started 30 cm off along it: along its weak direction the covariance
    adds the start's uncertainty (here GICP's reach, 2 m, over sqrt(3), as the localizer does): the standard
    deviation along x is above 10 cm and 100 x the across one's variance, and the NEES covers the error."""
    rng = np.random.default_rng(5)
    T, Te, _, _, pairs = _trial(rng, _scene(rng, 20000, corridor=True), np.array([0.3, 0.0, 0.0]))
    cov = sandwich_covariance(pairs, Te, 1.0, weak_sigma=2.0 / np.sqrt(3))
    along = float(np.array([1.0, 0, 0]) @ cov[:3, :3] @ np.array([1.0, 0, 0]))
    across = float(np.array([0, 1.0, 0]) @ cov[:3, :3] @ np.array([0, 1.0, 0]))
    assert np.sqrt(along) > 0.1 and along > 100 * across, (np.sqrt(along), np.sqrt(across))
    assert _nees(T, Te, cov) < chi2.ppf(0.999, 6)
    well = sandwich_covariance(pairs, Te, 1.0)  # without the prior: the corridor's data alone
    assert along > 10 * float(well[0, 0])


def test_motion_floor_is_the_deviation_per_axis_over_sqrt2():
    """The odometry's sweep floor: per axis of the scan, the root mean square of the recent deviations from the
    prediction times sqrt(2) / 2 (a scan lands half its sweep's missed motion off, a step is the difference of two
    scans); nothing before the first prediction, a roll deviation only in roll, the window forgetting old ones."""
    f = MotionFloor()
    assert SWEEP_SPREAD == pytest.approx(np.sqrt(0.5))
    assert f.update(np.eye(4), None) is None
    for dx, angle in ((0.03, 0.001), (0.04, 0.002)):
        P = np.eye(4)
        P[:3, :3] = Rotation.from_rotvec([angle, 0.0, 0.0]).as_matrix()
        P[:3, 3] = [dx, 0.0, 0.0]
        floor = f.update(P, np.eye(4))
    want = np.zeros(6)
    want[0] = SWEEP_SPREAD * np.sqrt((0.03 ** 2 + 0.04 ** 2) / 2)
    want[3] = SWEEP_SPREAD * np.sqrt((0.001 ** 2 + 0.002 ** 2) / 2)
    np.testing.assert_allclose(floor, want, atol=1e-12)
    for _ in range(20):
        floor = f.update(np.eye(4), np.eye(4))
    np.testing.assert_array_equal(floor, np.zeros(6))


def test_motion_floor_leaves_out_the_registration_noise_of_its_deviations():
    """A drive at constant velocity (nothing for the model to miss) registered with independent step errors of 2 cm
    and 0.05 deg per axis: the deviations from the constant-velocity prediction are the difference of two steps'
    errors (variance twice a step's), all of it the registration noise that the step's GICP part counts; with that
    part's variance given (``add_noise``) the floor keeps about half of it (the ten-step window's scatter: 1 cm
    against 2 cm without), and a missed motion of 5 cm a step on top of the same noise comes back as sqrt(2) / 2 of
    it."""
    rng = np.random.default_rng(5)
    sigma = np.array([0.02] * 3 + [np.radians(0.05)] * 3)
    v = np.eye(4)
    v[:3, 3] = [1.0, 0.0, 0.0]

    def drive(missed: float) -> tuple[np.ndarray, np.ndarray]:
        """-> the root mean square over the drive of the floor (6,) without and with the noise given."""
        plain, told = MotionFloor(), MotionFloor()
        est, a, b = [np.eye(4)], [], []
        for k in range(1, 400):
            step = v.copy()
            step[0, 3] += missed * (1 if k % 2 else -1)  # the motion changes by 2 * missed a step, back and forth
            e = rng.normal(0.0, sigma)  # this step's own registration error
            E = np.eye(4)
            E[:3, :3] = Rotation.from_rotvec(e[3:]).as_matrix()
            E[:3, 3] = e[:3]
            est.append(est[-1] @ step @ E)
            if k >= 2:
                pred = est[-2] @ np.linalg.solve(est[-3], est[-2])
                told.add_noise(sigma ** 2)
                a.append(plain.update(est[-1], pred))
                b.append(told.update(est[-1], pred))
        return (np.sqrt(np.mean(np.square(x[20:]), axis=0)) for x in (a, b))

    without, with_noise = drive(0.0)
    np.testing.assert_allclose(without, SWEEP_SPREAD * np.sqrt(2.0) * sigma, rtol=0.15)  # the noise, counted again
    # what is left: the window's ten deviations scatter about their mean square, and a floor is never below zero
    assert np.all(with_noise < 0.65 * without), (with_noise, without)
    _, floor = drive(0.025)  # deviations of +-5 cm along x (the motion's change), plus the noise
    assert floor[0] == pytest.approx(SWEEP_SPREAD * 0.05, rel=0.1), floor[0]


def test_compose_matches_monte_carlo():
    """The covariance of ``T_a @ T_b`` from :func:`compose` against sampled errors of both (first order)."""
    rng = np.random.default_rng(2)
    Ta, Tb = _pose(rng, 0.5, 20.0), _pose(rng, 0.3, 2.0)
    A = rng.normal(size=(6, 6)) * 1e-3
    B = rng.normal(size=(6, 6)) * 1e-3
    ca, cb = A @ A.T, B @ B.T
    m = 4000
    da, db = rng.multivariate_normal(np.zeros(6), ca, m), rng.multivariate_normal(np.zeros(6), cb, m)
    Ra = Rotation.from_rotvec(da[:, 3:]).as_matrix() @ Ta[:3, :3]  # (m, 3, 3) perturbed T_a, T_b
    Rb = Rotation.from_rotvec(db[:, 3:]).as_matrix() @ Tb[:3, :3]
    ta, tb = Ta[:3, 3] + da[:, :3], Tb[:3, 3] + db[:, :3]
    T = Ta @ Tb
    t = ta + np.einsum("mij,mj->mi", Ra, tb)
    rot = Rotation.from_matrix(np.einsum("mij,mjk->mik", Ra, Rb) @ T[:3, :3].T).as_rotvec()
    errs = np.concatenate([t - T[:3, 3], rot], axis=1)
    emp = np.cov(errs.T)
    np.testing.assert_allclose(compose(Ta, ca, Tb, cb), emp, atol=0.1 * np.abs(emp).max())


def test_is_covariance_rejects_placeholders():
    assert not is_covariance(np.eye(6) * 1e6, max_diagonal=1.0)
    assert not is_covariance(np.zeros((6, 6)))
    assert not is_covariance(np.full((6, 6), np.nan))
    assert is_covariance(np.eye(6) * 1e-4, max_diagonal=1.0)


def test_jackknife_is_the_leave_one_cell_out_spread():
    """On a linear least-squares problem (6 parameters, 12 cells of uneven size) the jackknife covariance from the
    cells' gradients and Hessians at the solution is exactly ``(G - 1) / G`` times the sum of the outer products of
    the solution's moves when each cell is left out and the problem solved again."""
    rng = np.random.default_rng(4)
    sizes = rng.integers(3, 40, 12)
    cell = np.repeat(np.arange(12), sizes)
    X = rng.normal(size=(len(cell), 6)) * rng.uniform(0.2, 3.0, (12, 6))[cell]  # cells pin directions unevenly
    y = X @ rng.normal(size=6) + rng.normal(0, 0.1, len(cell)) + rng.normal(0, 0.1, 12)[cell]
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    g = X * (y - X @ beta)[:, None]
    grads = np.stack([g[cell == c].sum(0) for c in range(12)])
    hessians = np.stack([X[cell == c].T @ X[cell == c] for c in range(12)])
    moves = np.stack([np.linalg.lstsq(X[cell != c], y[cell != c], rcond=None)[0] - beta for c in range(12)])
    np.testing.assert_allclose(jackknife_meat(X.T @ X, grads, hessians), 11 / 12 * moves.T @ moves, rtol=1e-9)


def test_effective_cells_count_the_cells_a_direction_rests_on():
    """G cells of equal information are G effective cells along every direction; where one cell holds nearly all
    the information along a direction (the others a thousandth), about one."""
    eq = np.stack([np.eye(6)] * 10)
    np.testing.assert_allclose(effective_cells(eq.sum(0), eq, np.eye(6)), 10.0, rtol=1e-9)
    uneven = eq.copy()
    uneven[1:, 0, 0] = 1e-3
    uneven[0, 0, 0] = 1.0
    nu = effective_cells(uneven.sum(0), uneven, np.eye(6), left_out=False)
    assert nu[0] < 1.1 and np.allclose(nu[1:], 10.0), nu


def _student_trials(seed: int, G: int = 12, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A linear least-squares problem with ``G`` cells of uneven size that pin the directions unevenly (true
    parameters 0, independent normal errors), ``n`` draws: per draw and parameter the squared error over the variance
    the jackknife covariance gives and over the widened one's."""
    rng = np.random.default_rng(seed)
    cell = np.repeat(np.arange(G), rng.integers(5, 40, G))
    X = rng.normal(size=(len(cell), 6)) * rng.uniform(0.2, 3.0, (G, 6))[cell]
    H = X.T @ X
    hessians = np.stack([X[cell == c].T @ X[cell == c] for c in range(G)])
    jk, st = [], []
    for _ in range(n):
        y = rng.normal(0, 0.1, len(cell))
        beta = np.linalg.lstsq(X, y, rcond=None)[0]
        g = X * (y - X @ beta)[:, None]
        grads = np.stack([g[cell == c].sum(0) for c in range(G)])
        V = jackknife_meat(H, grads, hessians)
        jk.append(beta ** 2 / np.diag(V))
        st.append(beta ** 2 / np.diag(student_widened(V, H, hessians)))
    return np.array(jk), np.array(st)


def test_student_widening_makes_each_direction_honest_with_few_cells():
    """With a dozen cells the jackknife variance is itself an estimate with a few degrees of freedom, so a
    parameter's squared error over it is on average above 1 (a t, not a normal); widened as Student's t with the
    direction's effective cells, the average is 1 (known truth: 400 draws of a linear problem, pooled over the six
    parameters)."""
    jk, st = _student_trials(6)
    assert jk.mean() > 1.2, jk.mean()
    assert 0.8 < st.mean() < 1.1, st.mean()


def test_no_covariance_from_too_little():
    assert sandwich_covariance(None, np.eye(4), 1.0) is None
    assert gicp_covariance(np.eye(6), 1.0, 3, np.eye(4)) is None
    assert gicp_covariance(np.zeros((6, 6)), 1.0, 100, np.eye(4)) is None
    assert gicp_covariance(np.full((6, 6), np.nan), 1.0, 100, np.eye(4)) is None


# ---- the localizer: a covariance on every valid pose -----------------------------------------------------------
import test_localization as _tl  # noqa: E402

world = _tl.world
localizer = _tl.localizer


def test_localizer_gives_every_valid_pose_a_covariance(localizer, world):
    """A held-out scan tracked from a guess and found by a search: each valid result has a covariance (finite,
    symmetric, positive definite, well below 1 m^2 / rad^2) whose NEES of the true error is plausible; a rejected
    scan has none."""
    from deepbbs_ros.replay.synthetic import pose

    _, _, drive, other = world
    T_gt = drive.pose_at(61)
    for guess in (T_gt @ pose(0.3, -0.2, 0.0, np.radians(1.0)), None):
        res = localizer.localize(drive.scan_at(61).points, guess)
        assert res.valid, res.reason
        assert is_covariance(res.covariance, 1.0), res.covariance
        assert _nees(T_gt, res.T_map_scan, res.covariance) < chi2.ppf(0.999, 6)
        assert "covariance" in res.timings_ms
    res = localizer.localize(other.scan_at(5).points)
    assert not res.valid and res.covariance is None


def test_conjugated_matches_monte_carlo():
    """The base's odometry ``T_bs T_os T_bs^-1`` (the mounting exact): its covariance from :func:`conjugated`
    against sampled errors of ``T_os`` (first order); a sensor at the base gives the sensor's covariance."""
    from deepbbs_ros.core.covariance import conjugated

    rng = np.random.default_rng(4)
    T_bs, T_os = _pose(rng, 0.3, 1.5), _pose(rng, 0.4, 30.0)
    A = rng.normal(size=(6, 6)) * 1e-3
    cov = A @ A.T
    d = rng.multivariate_normal(np.zeros(6), cov, 4000)
    R = Rotation.from_rotvec(d[:, 3:]).as_matrix() @ T_os[:3, :3]
    Ts = np.tile(np.eye(4), (len(d), 1, 1))
    Ts[:, :3, :3], Ts[:, :3, 3] = R, T_os[:3, 3] + d[:, :3]
    T_sb = np.linalg.inv(T_bs)
    want = T_bs @ T_os @ T_sb
    got = T_bs @ Ts @ T_sb
    errs = np.concatenate([got[:, :3, 3] - want[:3, 3],
                           Rotation.from_matrix(got[:, :3, :3] @ want[:3, :3].T).as_rotvec()], axis=1)
    emp = np.cov(errs.T)
    np.testing.assert_allclose(conjugated(T_bs, T_os, cov), emp, atol=0.1 * np.abs(emp).max())
    np.testing.assert_allclose(conjugated(np.eye(4), T_os, cov), cov, atol=1e-15)
