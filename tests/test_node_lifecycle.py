"""The managed localization node (``deepbbs-localizer``) driven as nav2_lifecycle_manager drives it, over real DDS.

A client node plays the lifecycle manager with the real lifecycle_msgs services (``<node>/change_state``,
``<node>/get_state``) and the real parameter service; the node localizes held-out scans of a simulated drive in a
map file written from the drive's other scans (as tests/test_node_localization.py), with the shipped weights.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from test_node import _check_pose  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.core.checkpoint import default_weights_path  # noqa: E402
from deepbbs_ros.node.managed import LocalizerNode, localizer_defaults  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context
FRAMES = 60
MAP_EVERY = 5


@pytest.fixture(scope="module")
def drive():
    """(sim, map points (N, 3) world frame, keyframe poses (K, 4, 4)): every 5th scan of a short urban drive."""
    from deepbbs_ros.core.localization import voxel_downsample
    from deepbbs_ros.sim.lidar import LidarConfig
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("urban", 5, LidarConfig.hdl32(), frames=FRAMES, motion_distortion=False)
    keys = list(range(0, FRAMES, MAP_EVERY))
    parts = [sim.scan_at(k).points @ sim.pose_at(k)[:3, :3].T + sim.pose_at(k)[:3, 3] for k in keys]
    return sim, voxel_downsample(np.concatenate(parts), 0.2), np.stack([sim.pose_at(k) for k in keys])


def _map(tmp_path, drive) -> str:
    from deepbbs_ros.datasets.maps import write_map

    _, points, poses = drive
    write_map(tmp_path / "map.pcd", points, poses, np.arange(len(poses), dtype=np.int64) * 500_000_000)
    return str(tmp_path / "map.pcd")


def _config(**extra) -> Config:
    return localizer_defaults(Config().replace(**{"registration.network_process": "off", "node.warmup": False,
                                                  "node.diagnostics_period": 0.3, **extra}))


class Manager:
    """The node and a client playing nav2_lifecycle_manager: change_state / get_state, parameters, the scans."""

    def __init__(self, cfg: Config, name: str, registration=None) -> None:
        self.name = name
        self.node = LocalizerNode(cfg, node_name=name, registration=registration)
        c = self.client = rclpy.create_node(f"{name}_manager")
        self.poses: list[PoseStamped] = []
        c.create_subscription(PoseStamped, f"/{name}/pose", self.poses.append, 50)
        self.scans = c.create_publisher(PointCloud2, "source_cloud", 5)
        self.change = c.create_client(ChangeState, f"/{name}/change_state")
        self.get = c.create_client(GetState, f"/{name}/get_state")
        self.params = c.create_client(SetParameters, f"/{name}/set_parameters")
        self.executor = MultiThreadedExecutor(num_threads=3)
        self.executor.add_node(self.node)
        self.executor.add_node(c)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        assert self.change.wait_for_service(10.0) and self.get.wait_for_service(10.0)

    def _call(self, client, request, timeout: float = 120.0):
        future = client.call_async(request)
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert future.done(), f"{client.srv_name}: no answer in {timeout} s"
        return future.result()

    def state(self) -> str:
        return self._call(self.get, GetState.Request()).current_state.label

    def transition(self, transition_id: int) -> bool:
        return self._call(self.change, ChangeState.Request(transition=Transition(id=transition_id))).success

    def set_string(self, name: str, value: str) -> bool:
        p = Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value))
        return self._call(self.params, SetParameters.Request(parameters=[p])).results[0].successful

    def send(self, points: np.ndarray, stamp_ns: int) -> None:
        self.scans.publish(arrays_to_pointcloud2(points.astype(np.float32), stamp_ns=stamp_ns, frame_id="lidar"))

    def subscribed(self) -> int:
        return self.scans.get_subscription_count()

    def wait_for(self, cond, timeout: float = 30.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if cond():
                return True
            time.sleep(0.02)
        return False

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(10.0)
        self.node.destroy_node()
        self.client.destroy_node()


def _shipped_weights() -> None:
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")


def test_transitions_as_the_lifecycle_manager_drives_them(ros, drive, tmp_path, capfd):
    """unconfigured -> configure (map and model loaded by the node) -> inactive: no subscription, no answer ->
    activate: a held-out scan is placed -> deactivate: nothing answered, the map kept -> activate again: answered ->
    cleanup: map and model released, unconfigured, publishers gone."""
    _shipped_weights()
    sim = drive[0]
    m = Manager(_config(**{"localization.map_path": _map(tmp_path, drive)}), "lc_node")
    try:
        assert m.state() == "unconfigured"
        assert m.subscribed() == 0 and m.client.count_publishers("/lc_node/pose") == 0
        assert m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == "inactive"
        # the map is loaded by configure: its line, the localizer's places (in-process), the model the node's own
        log = capfd.readouterr().err
        assert "map from " in log and "candidate places" in log and "inactive: configured in" in log, log
        assert m.node.localization.has_map and m.node._owns_reg
        assert m.client.count_publishers("/lc_node/pose") == 1  # created by configure, silent until active
        # inactive: the scan topic is not subscribed, nothing is received or answered
        m.send(sim.scan_at(12).points, sim.stamp_ns(12))
        time.sleep(1.0)
        assert m.subscribed() == 0 and m.node.stats()["received"] == 0 and not m.poses
        # active: subscribed; a held-out scan (not one of the map's) is placed with no initial pose
        assert m.transition(Transition.TRANSITION_ACTIVATE) and m.state() == "active"
        assert m.wait_for(lambda: m.subscribed() == 1, 10.0)
        m.send(sim.scan_at(12).points, sim.stamp_ns(12))
        assert m.wait_for(lambda: m.poses, 90.0), m.node.stats()
        T, stamp, frame = pose_stamped_to_matrix(m.poses[0])
        assert (stamp, frame) == (sim.stamp_ns(12), "map")
        _check_pose(T, sim.pose_at(12))
        # deactivate: unsubscribed, nothing answered; the map and the tracker stay
        assert m.transition(Transition.TRANSITION_DEACTIVATE) and m.state() == "inactive"
        assert m.wait_for(lambda: m.subscribed() == 0, 10.0)
        received = m.node.stats()["received"]
        m.send(sim.scan_at(13).points, sim.stamp_ns(13))
        time.sleep(1.0)
        assert m.node.stats()["received"] == received and len(m.poses) == 1
        assert m.node.localization.has_map
        # activate again: answered (tracked from the kept pose)
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        assert m.wait_for(lambda: m.subscribed() == 1, 10.0)
        m.send(sim.scan_at(14).points, sim.stamp_ns(14))
        assert m.wait_for(lambda: len(m.poses) == 2, 90.0), m.node.stats()
        _check_pose(pose_stamped_to_matrix(m.poses[1])[0], sim.pose_at(14))
        # deactivate + cleanup: back to unconfigured with the map, the model and the publishers released
        assert m.transition(Transition.TRANSITION_DEACTIVATE)
        assert m.transition(Transition.TRANSITION_CLEANUP) and m.state() == "unconfigured"
        assert m.node.localization is None and m.node.reg is None
        assert m.wait_for(lambda: m.client.count_publishers("/lc_node/pose") == 0, 10.0)
        log = capfd.readouterr().err
        assert "2 poses published" in log and "unconfigured: map and model released" in log, log
        assert "error" not in log.lower(), log
    finally:
        m.close()


def test_a_missing_map_fails_configure_in_one_line_and_the_node_stays(ros, drive, tmp_path, capfd):
    """configure with a missing map: FAILURE, one error line naming the parameter, the node still unconfigured and
    serving get_state; the parameter set through the parameter service, configure succeeds and the node answers."""
    _shipped_weights()
    from deepbbs_ros.core.registration import DeepBBSRegistration

    cfg = _config(**{"localization.map_path": str(tmp_path / "nowhere.pcd")})
    m = Manager(cfg, "lc_fail", registration=DeepBBSRegistration(cfg))
    try:
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == "unconfigured"
        errors = [line for line in capfd.readouterr().err.splitlines() if "ERROR" in line]
        assert len(errors) == 1 and "configure failed: localization.map_path" in errors[0], errors
        assert "nowhere.pcd" in errors[0] and "Traceback" not in errors[0]
        assert m.transition(Transition.TRANSITION_CONFIGURE) is False and m.state() == "unconfigured"  # again
        assert m.set_string("localization.map_path", _map(tmp_path, drive))
        assert m.transition(Transition.TRANSITION_CONFIGURE) and m.state() == "inactive"
        # configured: the node's parameters are fixed until cleanup, said in the refusal
        assert not m.set_string("localization.map_path", "/elsewhere.pcd")
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        assert m.wait_for(lambda: m.subscribed() == 1, 10.0)
        sim = drive[0]
        m.send(sim.scan_at(22).points, sim.stamp_ns(22))
        assert m.wait_for(lambda: m.poses, 90.0), m.node.stats()
        _check_pose(pose_stamped_to_matrix(m.poses[0])[0], sim.pose_at(22))
        # shutdown from active (as the manager's shutdown ends): finalized, everything released
        assert m.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert m.state() == "finalized" and m.node.localization is None
        assert m.get.wait_for_service(1.0)  # still serving its lifecycle services
    finally:
        m.close()


def test_localizer_defaults_and_states():
    """The managed node localizes by default (pair mode's stamped default becomes localization); a mode given
    otherwise is kept. The lifecycle state ids are lifecycle_msgs'."""
    assert localizer_defaults().node.target_mode == "localization"
    assert localizer_defaults(Config().replace(**{"node.target_mode": "latched"})).node.target_mode == "latched"
    assert localizer_defaults(Config().replace(**{"node.mode": "odometry"})).node.mode == "odometry"
    assert (State.PRIMARY_STATE_UNCONFIGURED, State.PRIMARY_STATE_INACTIVE, State.PRIMARY_STATE_ACTIVE) == (1, 2, 3)
