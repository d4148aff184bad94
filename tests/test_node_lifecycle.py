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
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
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
        return test_node.wait_for(cond, timeout)

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(10.0)
        self.node.destroy_node()
        self.client.destroy_node()


def _cli(*args: str):
    import os
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.ros", "--timeout", "20", *args],
                          capture_output=True, text=True, timeout=120, env=dict(os.environ))


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
        assert m.wait_for(lambda: m.client.count_publishers("/lc_node/pose") == 1, 10.0)  # made by configure
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
        # again from deepbbs-ros (ros2 lifecycle's pip-install stand-in), its own process: refused, exit code 1
        res = _cli("lifecycle", "set", "/lc_fail", "configure")
        assert res.returncode == 1 and "/lc_fail: configure failed" in res.stdout and "now unconfigured" in res.stdout
        assert _cli("lifecycle", "get", "/lc_fail").stdout.strip() == "/lc_fail: unconfigured [1]"
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
        # shutdown from active by its label (the manager's shutdown ends with it): finalized, everything released
        res = _cli("lifecycle", "set", "/lc_fail", "shutdown")
        assert res.returncode == 0 and res.stdout.strip() == "/lc_fail: shutdown ok; now finalized", res
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


def test_the_localizer_process_with_the_shipped_params_file(ros, drive, tmp_path):
    """``deepbbs-localizer`` in its own process with config/nav2_localization.yaml (keyed by its default name, as the
    launch file gives it), driven from this process as the lifecycle manager drives it: unconfigured until told,
    configure (the model and the map loaded there) and activate over lifecycle_msgs, a scan answered, SIGINT: exit 0
    with the counts logged and no traceback."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    _shipped_weights()
    params = Path(__file__).resolve().parents[1] / "config" / "nav2_localization.yaml"
    cmd = [sys.executable, "-m", "deepbbs_ros.node.managed", "--ros-args", "--params-file", str(params),
           "-p", f"localization.map_path:={_map(tmp_path, drive)}", "-p", "node.warmup:=false",
           "-p", "registration.network_process:=off"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    c = rclpy.create_node("lc_proc_manager")
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(c)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    try:
        poses: list[PoseStamped] = []
        c.create_subscription(PoseStamped, "/deepbbs_localizer/pose", poses.append, 10)
        scans = c.create_publisher(PointCloud2, "source_cloud", 5)
        change = c.create_client(ChangeState, "/deepbbs_localizer/change_state")
        get = c.create_client(GetState, "/deepbbs_localizer/get_state")
        assert change.wait_for_service(60.0) and get.wait_for_service(10.0), "".join(lines)

        def call(client, request):
            future = client.call_async(request)
            deadline = time.monotonic() + 120.0
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.02)
            assert future.done(), "".join(lines)
            return future.result()

        # the first request can meet DDS discovery half done ("failed to send response (timeout)": the server's reply
        # writer had not matched this client's reader yet); get_state is idempotent: asked again until answered
        first = None
        for _ in range(12):
            future = get.call_async(GetState.Request())
            deadline = time.monotonic() + 10.0
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.02)
            if future.done():
                first = future.result()
                break
        assert first is not None, "".join(lines)
        assert first.current_state.id == State.PRIMARY_STATE_UNCONFIGURED
        for t in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            assert call(change, ChangeState.Request(transition=Transition(id=t))).success, "".join(lines)
        assert call(get, GetState.Request()).current_state.id == State.PRIMARY_STATE_ACTIVE
        deadline = time.monotonic() + 10.0
        while scans.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        sim = drive[0]
        scans.publish(arrays_to_pointcloud2(sim.scan_at(32).points.astype(np.float32), stamp_ns=sim.stamp_ns(32),
                                            frame_id="lidar"))
        deadline = time.monotonic() + 90.0
        while not poses and time.monotonic() < deadline:
            time.sleep(0.05)
        assert poses, "".join(lines)
        _check_pose(pose_stamped_to_matrix(poses[0])[0], sim.pose_at(32))
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 0, "".join(lines)
        reader.join(10.0)
        log = "".join(lines)
        assert "stopping: 1 clouds received" in log and "1 poses published" in log, log
        assert "Traceback" not in log and "Failed to publish" not in log, log
    finally:
        proc.kill() if proc.poll() is None else None
        executor.shutdown()
        spin.join(10.0)
        c.destroy_node()


def test_a_bad_model_or_map_fails_configure_in_one_line(ros, drive, tmp_path, capfd):
    """A missing checkpoint, a damaged map: configure fails with one error line naming the parameter (no trace), the
    node stays unconfigured with nothing of the attempt left (no publisher, no thread of the node's)."""
    bad = tmp_path / "bad.pcd"
    bad.write_bytes(b"# .PCD v0.7\nFIELDS x y z\nnonsense")
    good = _map(tmp_path, drive)
    node = LocalizerNode(_config(**{"localization.map_path": good, "registration.weights": str(tmp_path / "no.pt")}),
                         node_name="lc_bad")
    before = set(threading.enumerate())  # another test's leftover thread is not this node's
    try:
        publishers = len(list(node.publishers))
        for param, value, named in [(None, None, "registration.weights: file not found"),
                                    ("localization.map_path", str(bad), "localization.map_path: ")]:
            if param:
                node.set_parameters([rclpy.parameter.Parameter(param, value=value)])
            capfd.readouterr()
            assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
            assert node._state_machine.current_state[1] == "unconfigured"
            errors = [line for line in capfd.readouterr().err.splitlines() if "ERROR" in line]
            assert len(errors) == 1 and f"configure failed: {named}" in errors[0], errors
            assert len(list(node.publishers)) == publishers and node.reg is None
            assert not [t for t in threading.enumerate() if t.name.startswith("deepbbs") and t not in before], (
                threading.enumerate())
    finally:
        node.destroy_node()


BOND_CHECK = """
import sys, time, threading, uuid
sys.path.insert(0, sys.argv[2])
import bond
assert bond.__file__.startswith(sys.argv[1]), bond.__file__
import rclpy
from bond.msg import Status
from rclpy.executors import MultiThreadedExecutor
from rclpy.lifecycle import TransitionCallbackReturn
from test_node import tiny_registration
SUCCESS = TransitionCallbackReturn.SUCCESS
from deepbbs_ros.config import Config
from deepbbs_ros.node.managed import LocalizerNode

rclpy.init()
cfg = Config().replace(**{"node.target_mode": "latched", "node.warmup": False, "registration.network_process": "off"})
node = LocalizerNode(cfg, registration=tiny_registration(cfg), node_name="lc_bond")
manager = rclpy.create_node("lc_bond_manager")  # the lifecycle manager's side of the bond
heard = []
mine = str(uuid.uuid4())
manager.create_subscription(Status, "bond", lambda m: heard.append(m) if m.instance_id != mine else None, 100)
pub = manager.create_publisher(Status, "bond", 5)
ex = MultiThreadedExecutor(num_threads=2)
ex.add_node(node); ex.add_node(manager)
threading.Thread(target=ex.spin, daemon=True).start()
assert node.trigger_configure() == SUCCESS
time.sleep(0.5)
assert not heard, "a heartbeat while inactive"
assert node.trigger_activate() == SUCCESS
deadline = time.monotonic() + 10
while (len(heard) < 5 or node.bond.sister is None) and time.monotonic() < deadline:
    pub.publish(Status(id="lc_bond", instance_id=mine, active=True, heartbeat_timeout=4.0, heartbeat_period=0.1))
    time.sleep(0.1)
n_active = len(heard)
assert n_active >= 5 and all(m.active for m in heard), heard
assert {(m.id, m.instance_id) for m in heard} == {("lc_bond", node.bond.instance_id)}, heard
assert abs(heard[0].heartbeat_period - 0.1) < 1e-6 and heard[0].heartbeat_timeout == 4.0  # float32
assert node.bond.sister == mine and node.bond.sister_active
t = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in heard]
span = t[-1] - t[0]
assert node.trigger_deactivate() == SUCCESS
deadline = time.monotonic() + 10  # the broken bond's last status, on a loaded machine too
while heard[-1].active and time.monotonic() < deadline:
    time.sleep(0.05)
assert heard[-1].active is False and all(m.active for m in heard[:-1]), [m.active for m in heard]
count = len(heard)
time.sleep(0.5)
assert len(heard) == count, "heartbeats after deactivate"
print(f"ok {n_active} heartbeats over {span:.2f} s, then active=false")
ex.shutdown(); node.destroy_node(); manager.destroy_node(); rclpy.shutdown()
"""


def test_bond_heartbeat_while_active(tmp_path):
    """With the bond messages built (as `make venv` / deepbbs-ros build-interfaces does; here into a temporary
    folder), the active node publishes bondcpp's heartbeat on bond (its name as id, 0.1 s period, 4 s timeout, active)
    and hears the manager's side; nothing while inactive; deactivate breaks it (active false, then silence)."""
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    pytest.importorskip("rosidl_generator_c")
    if shutil.which("gcc") is None or shutil.which("g++") is None:
        pytest.skip("needs gcc and g++")
    from deepbbs_ros import interfaces

    stage = interfaces.build_package("bond", tmp_path, install=False)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(stage), env.get("PYTHONPATH", "")])
    env["LD_LIBRARY_PATH"] = os.pathsep.join([str(stage / "lib"), env.get("LD_LIBRARY_PATH", "")])
    tests = str(Path(__file__).resolve().parent)
    res = subprocess.run([sys.executable, "-c", BOND_CHECK, str(stage), tests], capture_output=True, text=True,
                         env=env, timeout=180)
    assert res.returncode == 0 and res.stdout.startswith("ok"), res.stdout + res.stderr
    print(res.stdout)
