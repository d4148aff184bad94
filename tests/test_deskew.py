"""Deskewing with per-point times (Velodyne ``time``, Ouster ``t``): the core function, the sweep's
azimuth-to-time model, the preprocessing with a known motion and the registration's deskew stage,
checked against the toy world's ground truth (deepbbs_ros.replay.synthetic) and the LiDAR simulator."""

from __future__ import annotations

import re

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core.preprocess import SweepTimes, deskew
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.replay.synthetic import synthetic_drive
from deepbbs_ros.sim import DriveSimulator, LidarConfig


def _err(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_gt) @ T_est
    return float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))), float(np.linalg.norm(E[:3, 3]))


@pytest.fixture(scope="module")
def drives():
    """The toy drive at 15 m/s, motion-distorted (time field) and measured at the stamps."""
    return synthetic_drive(frames=10, seed=4, speed=15.0, motion_distortion=True), synthetic_drive(
        frames=10, seed=4, speed=15.0)


@pytest.fixture(scope="module")
def reg():
    return DeepBBSRegistration(Config().replace(**{"registration.device": "cpu", "registration.threads": 1}))


def test_sweep_times_follow_the_azimuth():
    """Velodyne-like clockwise sweep (the simulator) and the toy world's counter-clockwise one."""
    lid = LidarConfig.hdl64(azimuth_step_deg=1.0)
    scan = DriveSimulator("suburban", 3, lid, frames=3).scan_at(2)
    sweep = SweepTimes.fit(scan.points, scan.fields["time"])
    assert sweep is not None and sweep.direction == 1
    assert np.percentile(np.abs(sweep(scan.points) - scan.fields["time"]), 95) < 0.001  # < 1 % of the sweep
    toy = synthetic_drive(frames=2, seed=1, motion_distortion=True)[1]
    sweep = SweepTimes.fit(toy.points, toy.fields["time"])
    assert sweep is not None and sweep.direction == -1
    assert np.percentile(np.abs(sweep(toy.points) - toy.fields["time"]), 95) < 0.002
    shuffled = np.random.default_rng(0).permutation(toy.fields["time"])
    assert SweepTimes.fit(toy.points, shuffled) is None  # times unrelated to the azimuth: no model


def test_preprocess_with_a_known_motion_deskews_first(drives, reg):
    dist, flat = drives
    k = 5
    delta = np.linalg.inv(dist[k].T_world_lidar) @ dist[k + 1].T_world_lidar
    times = dist[k].point_times()
    pre = reg.preprocess(dist[k].points, times, dist[k].stamp_ns, motion=(delta, 0.1))
    ref = reg.preprocess(deskew(dist[k].points, times, delta, 0.1).astype(np.float32))
    np.testing.assert_array_equal(pre.points, ref.points)
    assert "deskew" in pre.timings_ms and pre.raw_points is None  # already deskewed: nothing kept
    # the precision-stage cloud is the undistorted scan's (same points, measured at the stamp)
    a, b = pre.polish_cloud.points(), reg.preprocess(flat[k].points).polish_cloud.points()
    assert abs(len(a) - len(b)) < 0.02 * len(b)
    raw = reg.preprocess(dist[k].points).polish_cloud.points()
    from scipy.spatial import cKDTree

    assert np.median(cKDTree(b).query(a)[0]) < 0.5 * np.median(cKDTree(b).query(raw)[0])


def test_stream_velocity_and_the_registration_deskew(drives, reg):
    """A raw pair 0.3 s apart at 15 m/s: each scan deskewed with its stream's velocity (the scan before it),
    the precision stage runs on both deskewed clouds and lands on the ground truth; the raw clouds are
    kept (with the reason) when only one scan has a velocity or a velocity disagrees with the pair."""
    import dataclasses

    from deepbbs_ros.core.deskew import StreamDeskew

    dist, _ = drives
    s, t = 7, 4
    T_gt = np.linalg.inv(dist[t].T_world_lidar) @ dist[s].T_world_lidar

    def prep(k, times=True):
        scan = dist[k]
        return reg.preprocess(scan.points, scan.point_times() if times else None, scan.stamp_ns)

    def streamed(k):
        stream = StreamDeskew(reg)
        first = stream.apply(prep(k - 1))
        assert first.deskew.startswith("no velocity yet") and first.deskewed_cloud is None
        out = stream.apply(prep(k))
        step = np.linalg.inv(dist[k - 1].T_world_lidar) @ dist[k].T_world_lidar
        rot, trans = _err(out.velocity[0], step)
        assert out.deskew == "deskewed" and out.velocity[1] == pytest.approx(0.1) and trans < 0.02 and rot < 0.05
        return out

    src, tgt = streamed(s), streamed(t)
    assert src.polish_cloud is not src.deskewed_cloud  # the raw cloud is kept beside the deskewed one
    res = reg.register(src, tgt)
    assert res.deskew == "deskewed"
    rot, trans = _err(res.T_target_source, T_gt)
    assert rot < 0.05 and trans < 0.02, (rot, trans)
    good = reg.register(src, tgt, T_init=res.T_target_source, good_start=True)  # the good-start path deskews too
    assert good.path == "gicp" and good.deskew == "deskewed"
    rot, trans = _err(good.T_target_source, T_gt)
    assert rot < 0.05 and trans < 0.02, (rot, trans)
    assert reg.register(prep(s, False), prep(t, False)).deskew == ""
    assert reg.register(src, prep(t)).deskew == "one scan has no velocity yet: raw clouds"
    still = dataclasses.replace(tgt, velocity=(np.eye(4), 0.1))  # a velocity of 0 m/s at 15 m/s
    assert re.match(r"target velocity off the pair's by 1[45]\.\d m/s", reg.register(src, still).deskew)
    with pytest.raises(Exception, match="per-point times for"):
        reg.preprocess(dist[s].points, dist[s].point_times()[:10], dist[s].stamp_ns)
    off = DeepBBSRegistration(reg.config.replace(**{"preprocess.deskew": False}), model=reg.model)
    assert off.preprocess(dist[s].points, dist[s].point_times(), dist[s].stamp_ns).times is None


def test_replay_pairs_follow_the_recordings_velocity(drives):
    """deepbbs-replay's pairs mode on raw sweeps: the DeepBBS++ method sees every scan in order
    (``observe``), knows the recording's velocity at each one after the first, and its pairs land on the
    ground truth."""
    from deepbbs_ros.replay.methods import build_methods
    from deepbbs_ros.replay.runner import run_pairs

    dist, _ = drives
    cfg = Config().replace(**{"registration.device": "cpu", "registration.threads": 1, "eval.stride": 3,
                              "eval.max_dist": 5.0})
    methods = build_methods(["deepbbs++"], cfg)
    res = run_pairs(iter(dist), methods, cfg)
    motions = methods["deepbbs++"]._motions
    assert len(motions) == len(dist) and sum(m is not None for m, _ in motions.values()) == len(dist) - 1
    step = np.linalg.inv(dist[0].T_world_lidar) @ dist[1].T_world_lidar
    for k, (motion, ms) in enumerate(motions.values()):
        if k:
            assert _err(motion[0], step)[1] < 0.02 and ms > 0  # 1.5 m per scan, straight
    assert res.pairs >= 3 and all(r.success and r.trans_err_m < 0.02 for r in res.records), res.records
