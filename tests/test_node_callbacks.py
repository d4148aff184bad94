"""No exception ends the executor: every callback the node gives rclpy (subscriptions, timers, services) is guarded
(deepbbs_ros/node/callbacks.py). Bad input and a failing callback are one error line, counted on /diagnostics, and
the node answers the next valid scan; the executor's spin thread stays up (``Harness.spin_error`` empty)."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
import test_node_localization  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from test_node import SEC, Harness, at, scan, tiny_config  # noqa: E402

from deepbbs_ros.errors import NodeError  # noqa: E402
from deepbbs_ros.node.callbacks import GuardedCallbacks, guard  # noqa: E402
from deepbbs_ros.node.tf_buffer import TransformBuffer  # noqa: E402
from msg_adapters.transforms import matrix_to_transform_stamped, odometry_to_matrix  # noqa: E402

world = test_node.world  # the structured street
drive = test_node_localization.drive  # the simulated drive and its map


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_guard_reports_and_returns():
    seen = []

    def report(kind, message, exc):
        seen.append((kind, message, type(exc)))

    def bug(msg):
        raise KeyError("x")

    def refused(msg):
        raise NodeError("a user's mistake")

    assert guard(bug, "/topic", report)(object()) is None
    assert guard(refused, "/topic", report)(object()) is None
    kind, message, exc = seen[0]
    assert kind == "callback /topic" and exc is KeyError
    assert message.startswith("/topic: unexpected KeyError: 'x' (in test_node_callbacks.py:") and "bug" in message
    assert seen[1][1] == "/topic: a user's mistake; ignored, the node continues"
    # a service answers, saying why
    response = Trigger.Response(success=True)
    out = guard(lambda req, res: 1 / 0, "~/reset", report, service=True)(Trigger.Request(), response)
    assert out is response and not out.success and "ZeroDivisionError" in out.message
    # a guarded callback's value passes through; guarding twice wraps once
    ok = guard(lambda a: a + 1, "t", report)
    assert ok(1) == 2 and guard(ok, "t", report) is ok
    assert len(seen) == 3


def _tf(T: np.ndarray, parent: str, child: str, quat=None, stamp_ns: int = 0):
    ts = matrix_to_transform_stamped(T, stamp_ns, parent, child)
    if quat is not None:
        ts.transform.rotation.x, ts.transform.rotation.y, ts.transform.rotation.z, ts.transform.rotation.w = quat
    return ts


def test_bad_input_and_failing_callbacks_leave_the_executor_spinning(ros, world, monkeypatch):
    """Odometry mode with a base frame (/tf_static subscribed), its /diagnostics timer and ~/reset: bad /tf_static
    transforms are skipped, each a warning; a callback that raises (a fault injected in the /tf_static, input, timer
    and service callbacks: each used to end the spin thread) is logged, counted, and the next scans are answered."""
    from tf2_msgs.msg import TFMessage

    from deepbbs_ros.node.qos import reliable_qos

    real_add = TransformBuffer.add_message

    def add_message(self, msg, *rest):  # a bug in the /tf_static callback, on the message naming "boom"
        if any(ts.child_frame_id == "boom" for ts in msg.transforms):
            raise RuntimeError("injected /tf_static fault")
        return real_add(self, msg, *rest)

    monkeypatch.setattr(TransformBuffer, "add_message", add_message)
    cfg = tiny_config(**{"node.mode": "odometry", "node.odom_frame": "odom", "node.base_frame": "base_link",
                         "node.tf_timeout": 5.0, "node.diagnostics_period": 0.2, "node.error_log_period": 60.0})
    h = Harness(cfg, "reg_guard")
    assert isinstance(h.node, GuardedCallbacks)
    from rclpy.qos import DurabilityPolicy

    static = h.client.create_publisher(TFMessage, "/tf_static", reliable_qos(10, DurabilityPolicy.TRANSIENT_LOCAL))
    try:
        eye = np.eye(4)
        bad = [
            _tf(eye, "base_link", "zero_q", quat=(0.0, 0.0, 0.0, 0.0)),  # a zero quaternion
            _tf(eye, "base_link", "nan_q", quat=(np.nan, 0.0, 0.0, 1.0)),
            _tf(eye, "lidar", "lidar"),  # a frame its own parent
            _tf(eye, "", "no_parent"),
        ]
        bad[0].transform.translation.x = float("nan")
        T_bl = eye.copy()
        T_bl[2, 3] = 1.5
        static.publish(TFMessage(transforms=[*bad, _tf(T_bl, "base_link", "lidar")]))  # the valid one is used
        assert h.wait_for(lambda: h.node.static_tf.lookup("base_link", "lidar") is not None, 10.0)
        assert h.node.static_tf.lookup("base_link", "zero_q") is None
        warnings = h.node._warnings.counts  # each bad one said (rate-limited: one line per node.error_log_period)
        assert h.wait_for(lambda: warnings.get("bad_transform") == 4, 10.0), warnings
        static.publish(TFMessage(transforms=[_tf(eye, "base_link", "boom")]))  # the /tf_static callback raises
        errors = h.node._errors.counts
        assert h.wait_for(lambda: errors.get("callback /tf_static", 0) == 1, 10.0), errors

        # the input's callback raises once
        inp = h.node.inputs[0]
        real_submit = inp.submit

        def submit_once(msg, t):
            inp.submit = real_submit
            raise RuntimeError("injected input fault")

        inp.submit = submit_once
        h.send("cloud", scan(world, at(), seed=1), 10 * SEC)
        assert h.wait_for(lambda: errors.get("callback cloud", 0) == 1, 10.0), errors

        # the diagnostics timer raises once
        real_check = h.node._check_unpaired

        def check_once():
            h.node._check_unpaired = real_check
            raise ValueError("injected timer fault")

        h.node._check_unpaired = check_once
        kind = "callback timer NodeDiagnostics._publish_diagnostics"
        assert h.wait_for(lambda: errors.get(kind, 0) == 1, 10.0), errors
        assert h.wait_for(lambda: h.diagnostics().get(f"errors.{kind}") == "1", 10.0), h.diagnostics()

        # ~/reset raises: the client gets success false and the reason, not silence
        real_reset = h.node.sync.reset

        def reset_fails():
            raise RuntimeError("injected service fault")

        h.node.sync.reset = reset_fails
        assert h.reset.wait_for_service(timeout_sec=5.0)
        fut = h.reset.call_async(Trigger.Request())
        assert h.wait_for(fut.done, 10.0)
        assert not fut.result().success and "RuntimeError: injected service fault" in fut.result().message
        h.node.sync.reset = real_reset
        assert errors.get("callback ~/reset") == 1

        # still up: valid scans are answered, the base's motion from the valid /tf_static transform
        for k in range(3):
            h.send("cloud", scan(world, at(0.5 * k), seed=20 + k), (20 + k) * SEC)
        assert h.wait_for(lambda: len(h.poses) >= 2, 60.0), h.node.stats()
        assert all(p.header.frame_id == "odom" for p in h.poses)
        assert h.transforms[-1].child_frame_id == "base_link"
        fut = h.reset.call_async(Trigger.Request())
        assert h.wait_for(fut.done, 10.0) and fut.result().success
        assert h.spin_error == "" and h.thread.is_alive()
    finally:
        h.close()


def test_absurd_tf_static_is_one_error_line_and_a_good_one_is_used(ros, world, capfd):
    """Odometry mode: a base_link <- lidar on /tf_static that is finite but absurd (its inverse overflows; then one
    whose inverse is finite but the base's pose and covariance are not) withholds each scan's outputs: one error
    line naming the frames, counted as errors.bad_tf_static (a user error, no internal_error: it used to fail every
    scan on the worker thread); the odometry goes on, and once a usable transform arrives the base's motion since the
    first scan is published."""
    from rclpy.qos import DurabilityPolicy
    from tf2_msgs.msg import TFMessage

    from deepbbs_ros.node.qos import reliable_qos

    cfg = tiny_config(**{"node.mode": "odometry", "node.odom_frame": "odom", "node.base_frame": "base_link",
                         "node.tf_timeout": 5.0, "node.diagnostics_period": 0.2, "node.error_log_period": 60.0})
    h = Harness(cfg, "reg_mount")
    static = h.client.create_publisher(TFMessage, "/tf_static", reliable_qos(10, DurabilityPolicy.TRANSIENT_LOCAL))
    try:
        turned = np.eye(4)
        turned[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # the LiDAR turned 90 deg left on the base
        half = np.eye(4)
        half[:2, :2] = [[np.sqrt(0.5), -np.sqrt(0.5)], [np.sqrt(0.5), np.sqrt(0.5)]]  # 45 deg
        no_inverse = _tf(half, "base_link", "lidar")
        no_inverse.transform.translation.x = no_inverse.transform.translation.y = 1.7e308  # -R^T t overflows
        no_pose = _tf(np.eye(4), "base_link", "lidar")
        no_pose.transform.translation.x = 1e308  # its inverse is finite; the base's covariance is not
        good = turned.copy()
        good[2, 3] = 1.5
        errors = h.node._errors.counts
        for k, bad in enumerate((no_inverse, no_inverse, no_pose)):
            static.publish(TFMessage(transforms=[bad]))
            x = bad.transform.translation.x
            assert h.wait_for(lambda x=x: (T := h.node.static_tf.lookup("base_link", "lidar")) is not None
                              and T[0, 3] == x, 10.0)
            h.send("cloud", scan(world, at(0.5 * k), seed=40 + k), (40 + k) * SEC)
            h.wait_processed(k + 1)
            assert errors.get("bad_tf_static") == k + 1, h.node.stats()
        assert h.node.stats()["processed"] == 0 and not h.poses and not h.odoms
        static.publish(TFMessage(transforms=[_tf(good, "base_link", "lidar")]))
        assert h.wait_for(lambda: h.node.static_tf.lookup("base_link", "lidar")[2, 3] == 1.5, 10.0)
        for k in (3, 4):
            h.send("cloud", scan(world, at(0.5 * k), seed=40 + k), (40 + k) * SEC)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.odoms) == 2, 10.0), h.node.stats()
        # the base's motion since the first scan (the odom frame), the LiDAR's x the base's y
        for k, odom in zip((3, 4), h.odoms):
            T, _, frame, child = odometry_to_matrix(odom)
            assert (frame, child) == ("odom", "base_link")
            np.testing.assert_allclose(T[:3, 3], [0.0, 0.5 * k, 0.0], atol=0.15)
        assert h.wait_for(lambda: h.diagnostics().get("errors.bad_tf_static") == "3", 10.0), h.diagnostics()
        assert "internal_error" not in errors and not any(k.startswith("callback") for k in errors), errors
        assert h.spin_error == "" and h.thread.is_alive()
    finally:
        h.close()
    lines = [line for line in capfd.readouterr().err.splitlines() if "[bad_tf_static]" in line]
    assert len(lines) == 1, lines  # rate-limited: one line per node.error_log_period
    assert "base_link <- lidar on /tf_static is not usable: the inverse of the transform is not finite" in lines[0]
    assert "withheld until a usable transform arrives" in lines[0]


def test_localization_bad_initialpose_tf_and_services(ros, drive, tmp_path):
    """Localization mode: bad /initialpose messages (zero quaternion, NaN covariance, another frame) are warnings and
    no hint; an odom -> base on /tf whose inverse overflows gives no map -> odom (it used to be kept, and the
    map -> odom timer's republish raised TransformFormatError in the executor every period); ~/relocalize and
    ~/reset answer; the next scan is placed and the spin thread stays up."""
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from test_node import _check_pose
    from test_node_rep105 import _harness, _send
    from tf2_msgs.msg import TFMessage

    from msg_adapters.transforms import matrix_to_pose, pose_stamped_to_matrix

    sim, _, _, scan_k = drive
    cfg = test_node_localization._config(**{"node.base_frame": "", "node.tf_timeout": 0.5,
                                            "node.map_odom_period": 0.1, "node.error_log_period": 60.0})
    h = _harness(cfg, "guard_loc", drive, tmp_path)
    try:
        relocalize = h.client.create_client(Trigger, "/guard_loc/relocalize")
        good = PoseWithCovarianceStamped()
        good.header.frame_id = "map"
        good.pose.pose = matrix_to_pose(sim.pose_at(40))
        zero_q = PoseWithCovarianceStamped()
        zero_q.header.frame_id = "map"
        zero_q.pose.pose.orientation.w = 0.0  # (the message's default is the identity, w = 1)
        nan_cov = PoseWithCovarianceStamped()
        nan_cov.header.frame_id = "map"
        nan_cov.pose.pose = matrix_to_pose(np.eye(4))
        nan_cov.pose.covariance = [float("nan")] * 36
        other = PoseWithCovarianceStamped()
        other.header.frame_id = "odom"
        other.pose.pose = matrix_to_pose(np.eye(4))
        for msg in (zero_q, nan_cov, other):
            h.initialpose.publish(msg)
        warnings = h.node._warnings.counts
        assert h.wait_for(lambda: warnings.get("initialpose_bad", 0) == 2 and warnings.get("initialpose_frame") == 1,
                          10.0), warnings
        assert h.node.rep105.hints == 0
        # odom -> lidar at the scan's stamp: turned 1 rad, 1.7e308 m away (finite; its inverse is not)
        stamp = sim.stamp_ns(40)
        T_bad = np.eye(4)
        T_bad[:2, :2] = [[np.cos(1.0), -np.sin(1.0)], [np.sin(1.0), np.cos(1.0)]]
        tf_pub = h.client.create_publisher(TFMessage, "/tf", 10)
        ts = matrix_to_transform_stamped(T_bad, stamp, "odom", "lidar")
        ts.transform.translation.x = ts.transform.translation.y = ts.transform.translation.z = 1.7e308
        tf_pub.publish(TFMessage(transforms=[ts]))  # (no zero quaternion: the test client's TfTree would raise)
        assert h.wait_for(lambda: h.node.static_tf.has_edge("odom", "lidar"), 10.0)
        h.initialpose.publish(good)
        assert h.wait_for(lambda: h.node.rep105.hints == 1, 10.0)
        _send(h, sim, scan_k, [40])
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], scan_k(40)[1])
        assert warnings.get("bad_odom_tf") == 1 and h.node.rep105.last_map_odom is None, warnings
        assert h.wait_for(lambda: "not usable" in h.diagnostics().get("localization.map -> odom", ""), 10.0)
        for client in (relocalize, h.reset):
            assert client.wait_for_service(timeout_sec=5.0)
            fut = client.call_async(Trigger.Request())
            assert h.wait_for(fut.done, 10.0) and fut.result().success
        _send(h, sim, scan_k, [42], start=1)
        _check_pose(pose_stamped_to_matrix(h.poses[-1])[0], scan_k(42)[1])
        assert not any(k.startswith("callback") for k in h.node._errors.counts), h.node._errors.counts
        assert h.spin_error == "" and h.thread.is_alive()
    finally:
        h.close()


def test_managed_node_bond_fault_and_services_while_inactive(ros, drive, tmp_path, monkeypatch):
    """The managed node: a fault in the bond's status callback (its own heartbeat reaches it 10 times a second) is
    one error line, counted; the transitions go on, ~/reset and ~/relocalize answer while inactive, and the next scan
    after activate is placed; the executor's spin thread stays up."""
    pytest.importorskip("bond.msg")
    import test_node_lifecycle
    from lifecycle_msgs.msg import Transition
    from test_node import _check_pose

    from deepbbs_ros.node.bond import BondHeartbeat
    from msg_adapters.transforms import pose_stamped_to_matrix

    test_node_lifecycle._shipped_weights()

    def on_status(self, msg):
        raise RuntimeError("injected bond fault")

    monkeypatch.setattr(BondHeartbeat, "_on_status", on_status)
    sim = drive[0]
    cfg = test_node_lifecycle._config(**{"localization.map_path": test_node_lifecycle._map(tmp_path, drive[:3]),
                                         "node.error_log_period": 60.0})
    m = test_node_lifecycle.Manager(cfg, "guard_lc")
    try:
        assert m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.transition(Transition.TRANSITION_ACTIVATE) and m.state() == "active"
        errors = m.node._errors.counts
        assert m.wait_for(lambda: errors.get("callback bond", 0) >= 3, 10.0), errors
        assert m.transition(Transition.TRANSITION_DEACTIVATE) and m.state() == "inactive"
        for service in ("reset", "relocalize"):
            client = m.client.create_client(Trigger, f"/guard_lc/{service}")
            assert client.wait_for_service(timeout_sec=5.0)
            assert m._call(client, Trigger.Request(), 10.0).success
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        assert m.wait_for(lambda: m.subscribed() == 1, 10.0)
        m.send(sim.scan_at(12).points, sim.stamp_ns(12))
        assert m.wait_for(lambda: m.poses, 90.0), m.node.stats()
        _check_pose(pose_stamped_to_matrix(m.poses[0])[0], sim.pose_at(12))
        assert m.thread.is_alive()
    finally:
        m.close()
