"""A scan taken the other way in a straight map (core/place_search.py): a simulated highway mapped by one drive (five
noiseless HDL-64E scans at their true poses, no trajectory given: places over the drivable space), and a scan of a
drive through the same stretch the other way, on another day, in the opposite lane. The descriptor is yaw-invariant
and the search starts from its yaw, so the scan is placed, though the map saw that stretch one way only.
Shipped weights, default configuration (network in this process)."""

from __future__ import annotations

import numpy as np
import pytest
from sim_maps import world_points

from deepbbs_ros.config import Config
from deepbbs_ros.metrics import pair_errors

WORLD_FRAMES = 120  # the world's length (frames of the map drive's route)
MAP_FRAMES = (4, 10, 16, 22, 28)  # about 70 m of a straight highway


@pytest.fixture(scope="module")
def straight():
    from deepbbs_ros.core.checkpoint import default_weights_path
    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.sim.simulator import DriveSimulator

    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    fwd = DriveSimulator("highway", 11, frames=30, motion_distortion=False, world_frames=WORLD_FRAMES)
    world = world_points(fwd, MAP_FRAMES, 50.0)
    tr = fwd.trajectory
    s_end = float(np.interp(MAP_FRAMES[-1] * fwd.period, tr.t_grid, tr.s_grid))
    back = DriveSimulator("highway", 11, frames=20, compensate=True, world_frames=WORLD_FRAMES, reverse=True,
                          s_start=s_end, day=1)
    return voxel_downsample(world, 0.25), fwd, back


def test_a_scan_taken_the_other_way_is_placed(straight):
    from deepbbs_ros.core.localization import MapLocalizer

    map_points, fwd, back = straight
    k = 12  # in the middle of the mapped stretch, driving back
    T_gt = back.pose_at(k)
    heading = np.degrees(np.arctan2(T_gt[1, 0], T_gt[0, 0]) - np.arctan2(fwd.pose_at(16)[1, 0], fwd.pose_at(16)[0, 0]))
    assert abs((heading + 180.0) % 360.0 - 180.0) > 150.0  # it is the other way
    loc = MapLocalizer(map_points, Config().replace(**{"registration.network_process": "off"}))
    try:
        res = loc.localize(back.scan_at(k).points)
    finally:
        loc.registration.close()
    rot, trans = pair_errors(res.T_map_scan, T_gt)
    assert res.valid and rot < 1.0 and trans < 0.3, (rot, trans, res.reason)
    assert res.probability >= Config().localization.min_probability
