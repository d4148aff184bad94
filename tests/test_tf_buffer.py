"""The node's TF buffer (node/tf_buffer.py): interpolation of stamped edges, chains through static and dynamic
edges, history, extrapolation and frames that do not connect."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepbbs_ros.node.tf_buffer import TransformBuffer, interpolate, slerp

S = 1_000_000_000  # ns per second


def _T(x: float, y: float, z: float, yaw: float, roll: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [roll, 0.0, yaw]).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def test_interpolation_is_linear_in_translation_and_slerp_in_rotation():
    T0, T1 = _T(0, 0, 0, 0.0), _T(2.0, -4.0, 1.0, np.radians(90))
    mid = interpolate(T0, T1, 0.5)
    np.testing.assert_allclose(mid[:3, 3], [1.0, -2.0, 0.5])
    np.testing.assert_allclose(mid[:3, :3], _T(0, 0, 0, np.radians(45))[:3, :3], atol=1e-12)
    np.testing.assert_allclose(interpolate(T0, T1, 0.0), T0, atol=1e-12)
    np.testing.assert_allclose(interpolate(T0, T1, 1.0), T1, atol=1e-12)
    # the shorter way round: +170 deg to -170 deg passes 180, not 0
    q0 = Rotation.from_euler("z", 170, degrees=True).as_quat()
    q1 = Rotation.from_euler("z", -170, degrees=True).as_quat()
    yaw = Rotation.from_quat(slerp(q0, q1, 0.5)).as_euler("xyz", degrees=True)[2]
    assert abs(abs(yaw) - 180.0) < 1e-9


def test_lookup_interpolates_each_dynamic_edge_of_a_chain():
    """map -> odom (dynamic), odom -> base (dynamic, 20 Hz), base -> lidar (static): T_map_lidar at a stamp between
    the edges' stamps is the product of each edge interpolated there."""
    rng = np.random.default_rng(3)
    buf = TransformBuffer(history_s=10.0)
    T_base_lidar = _T(1.2, 0.1, 1.8, np.radians(-3), roll=np.radians(2))
    buf.add("base_link", "lidar", T_base_lidar)
    odom = {k * S // 20: _T(0.5 * k, 0.02 * k, 0.0, np.radians(k)) for k in range(60)}
    for s, T in odom.items():
        buf.add_stamped("odom", "base_link", s, T)
    buf.add_stamped("map", "odom", 0, _T(10.0, 5.0, 0.0, 0.3))
    buf.add_stamped("map", "odom", 3 * S, _T(10.4, 5.2, 0.0, 0.32))
    for stamp in rng.integers(0, 59 * S // 20, size=20):
        k = int(stamp // (S // 20))
        s0, s1 = k * S // 20, (k + 1) * S // 20
        T_ob = interpolate(odom[s0], odom[s1], (stamp - s0) / (s1 - s0))
        T_mo = interpolate(_T(10.0, 5.0, 0.0, 0.3), _T(10.4, 5.2, 0.0, 0.32), stamp / (3 * S))
        np.testing.assert_allclose(buf.lookup("map", "lidar", int(stamp)), T_mo @ T_ob @ T_base_lidar, atol=1e-9)
        # the other way round, and between two frames below a common ancestor
        np.testing.assert_allclose(buf.lookup("lidar", "map", int(stamp)),
                                   np.linalg.inv(T_mo @ T_ob @ T_base_lidar), atol=1e-9)
        np.testing.assert_allclose(buf.lookup("odom", "lidar", int(stamp)), T_ob @ T_base_lidar, atol=1e-9)
    # exactly at a stamp: that transform
    np.testing.assert_allclose(buf.lookup("odom", "base_link", 20 * S // 20), odom[20 * S // 20], atol=1e-12)
    # the latest (tf2's time 0)
    np.testing.assert_allclose(buf.lookup("odom", "base_link"), odom[59 * S // 20], atol=1e-12)
    # static lookups work as StaticTransforms' (no stamp)
    np.testing.assert_allclose(buf.lookup("base_link", "lidar"), T_base_lidar)


def test_out_of_range_stamps_history_and_unconnected_frames():
    buf = TransformBuffer(history_s=2.0)
    for k in range(50):  # 5 s at 10 Hz; 2 s kept
        buf.add_stamped("odom", "base_link", 10 * S + k * S // 10, _T(0.1 * k, 0, 0, 0))
    assert buf.lookup("odom", "base_link", 15 * S) is None  # after the newest: no extrapolation by default
    assert buf.lookup("odom", "base_link", 11 * S) is None  # dropped from the history
    assert buf.lookup("odom", "base_link", 13 * S) is not None
    assert buf.lookup("map", "base_link", 13 * S) is None  # map not connected
    assert buf.wait("map", "base_link", 0.05, 13 * S) is None
    assert buf.has_edge("odom", "base_link") and not buf.has_edge("map", "odom")
    assert buf.newest("odom", "base_link") == 10 * S + 49 * S // 10 and buf.newest("map", "odom") is None
    # a small allowance answers just past the ends with the end's transform
    ext = TransformBuffer(extrapolation_s=0.2)
    ext.add_stamped("odom", "base_link", 1 * S, _T(1, 0, 0, 0))
    ext.add_stamped("odom", "base_link", 2 * S, _T(2, 0, 0, 0))
    np.testing.assert_allclose(ext.lookup("odom", "base_link", 2 * S + S // 10)[:3, 3], [2, 0, 0])
    assert ext.lookup("odom", "base_link", 2 * S + S // 2) is None
    # a transform arriving out of order is kept in order; the same stamp again replaces it
    ext.add_stamped("odom", "base_link", S + S // 2, _T(5, 0, 0, 0))
    np.testing.assert_allclose(ext.lookup("odom", "base_link", S + S // 2)[:3, 3], [5, 0, 0])
    ext.add_stamped("odom", "base_link", 2 * S, _T(3, 0, 0, 0))
    np.testing.assert_allclose(ext.lookup("odom", "base_link", 2 * S)[:3, 3], [3, 0, 0])


def test_tf_messages_feed_the_buffer():
    pytest.importorskip("tf2_msgs")
    from tf2_msgs.msg import TFMessage

    from msg_adapters.transforms import matrix_to_transform_stamped

    buf = TransformBuffer()
    msg = TFMessage(transforms=[matrix_to_transform_stamped(_T(1, 2, 0, 0.1), 5 * S, "odom", "base_link"),
                                matrix_to_transform_stamped(_T(0, 0, 0, 0), 5 * S, "same", "same")])
    assert buf.add_dynamic_message(msg) == 1
    np.testing.assert_allclose(buf.lookup("odom", "base_link", 5 * S), _T(1, 2, 0, 0.1), atol=1e-9)
    # the ones skipped, each named with why (the node warns with these)
    zero_q = matrix_to_transform_stamped(np.eye(4), 0, "base_link", "lidar")
    zero_q.transform.rotation.w = 0.0
    nameless = matrix_to_transform_stamped(np.eye(4), 0, "", "lidar")
    rejected: list[str] = []
    assert buf.add_message(TFMessage(transforms=[*msg.transforms, zero_q, nameless]), rejected) == 1
    assert rejected == ["'same' -> 'same': a frame is its own parent",
                        "'base_link' -> 'lidar': quaternion has zero norm; it is not a rotation",
                        "'' -> 'lidar': a frame name is empty"]


def test_quaternions_of_random_rotations():
    """The quaternions the buffer interpolates with (msg_adapters.transforms, the messages' own)."""
    from msg_adapters.transforms import matrix_to_quaternion, quaternion_to_matrix

    for R in Rotation.random(200, random_state=1).as_matrix():
        q = matrix_to_quaternion(R)
        assert q[3] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)
    for yaw in (0.0, np.pi, -np.pi / 2):  # w near 0 (180 deg) and the axes
        np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(_T(0, 0, 0, yaw)[:3, :3])),
                                   _T(0, 0, 0, yaw)[:3, :3], atol=1e-12)
