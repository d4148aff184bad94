"""4x4 transforms <-> Pose / PoseStamped / TransformStamped / Odometry and stamps <-> ns (CONVENTIONS.md)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from msg_adapters.transforms import (
    TransformFormatError,
    invert,
    matrix_to_odometry,
    matrix_to_pose,
    matrix_to_pose_stamped,
    matrix_to_quaternion,
    matrix_to_transform_stamped,
    ns_to_stamp,
    odometry_covariances,
    odometry_to_matrix,
    odometry_twist,
    pose_stamped_to_matrix,
    pose_to_matrix,
    quaternion_to_matrix,
    stamp_to_ns,
    transform_stamped_to_matrix,
)

FLAVORS = ("rclpy", "rosbags")


def _cdr_roundtrip(msg):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    return ts.deserialize_cdr(ts.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


def _random_T(rng: np.random.Generator) -> np.ndarray:
    """A seeded random rigid transform (uniform rotation via a random unit quaternion)."""
    q = rng.normal(size=4)
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix(q)
    T[:3, 3] = rng.uniform(-50, 50, 3)
    return T


def _q(msg_q) -> np.ndarray:
    return np.array([msg_q.x, msg_q.y, msg_q.z, msg_q.w])


# --------------------------------------------------------------------------------------------------
# conventions pinned against hand-computed ground truth
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flavor", FLAVORS)
def test_yaw_90_degrees_convention(flavor):
    """T_target_source: yaw +90 deg about z, t = (1, 2, 3): source x-axis point (1, 0, 0) lands at (1, 3, 3)."""
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [1, 2, 3]
    msg = matrix_to_pose_stamped(T, 5, "target", flavor=flavor)
    s = np.sqrt(0.5)
    np.testing.assert_allclose(_q(msg.pose.orientation), [0, 0, s, s], atol=1e-15)
    assert (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z) == (1.0, 2.0, 3.0)
    T_back, stamp_ns, frame = pose_stamped_to_matrix(msg)
    np.testing.assert_allclose(T_back @ [1, 0, 0, 1], [1, 3, 3, 1], atol=1e-12)
    assert (stamp_ns, frame) == (5, "target")


def test_quaternion_sign_and_180_degree_rotations():
    # q and -q are the same rotation; the writer always picks w >= 0
    q = np.array([0.1, -0.7, 0.3, -0.5])
    np.testing.assert_allclose(quaternion_to_matrix(q), quaternion_to_matrix(-q), atol=1e-15)
    out = matrix_to_quaternion(quaternion_to_matrix(q))
    assert out[3] >= 0
    np.testing.assert_allclose(out, -q / np.linalg.norm(q), atol=1e-12)
    # 180 degrees about x, y, z and a diagonal axis (w = 0: the numerically delicate case)
    for axis in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]):
        a = np.array(axis, float) / np.linalg.norm(axis)
        R = 2 * np.outer(a, a) - np.eye(3)
        qq = matrix_to_quaternion(R)
        assert abs(qq[3]) < 1e-12 and np.isclose(np.linalg.norm(qq), 1.0)
        np.testing.assert_allclose(quaternion_to_matrix(qq), R, atol=1e-12)


def test_unnormalised_quaternion_in_message_is_normalised():
    from geometry_msgs.msg import Pose

    pose = Pose()
    pose.orientation.z, pose.orientation.w = 2.0, 2.0  # 90 deg yaw, norm 2*sqrt(2)
    R = pose_to_matrix(pose)[:3, :3]
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


# --------------------------------------------------------------------------------------------------
# round trips, both flavours (rosbags messages also through CDR)
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flavor", FLAVORS)
def test_all_message_types_round_trip(rng, flavor):
    T = _random_T(rng)
    stamp = 1_700_000_001_000_000_007
    post = _cdr_roundtrip if flavor == "rosbags" else (lambda m: m)

    np.testing.assert_allclose(pose_to_matrix(post(matrix_to_pose(T, flavor))), T, atol=1e-12)

    T2, ns, frame = pose_stamped_to_matrix(post(matrix_to_pose_stamped(T, stamp, "map", flavor)))
    np.testing.assert_allclose(T2, T, atol=1e-12)
    assert (ns, frame) == (stamp, "map")

    tf = post(matrix_to_transform_stamped(T, stamp, "odom", "velodyne64", flavor))
    T3, ns, frame, child = transform_stamped_to_matrix(tf)
    np.testing.assert_allclose(T3, T, atol=1e-12)
    assert (ns, frame, child) == (stamp, "odom", "velodyne64")
    assert tf.transform.rotation.w >= 0

    twist = rng.normal(size=6)
    pose_cov = np.diag(rng.uniform(0.01, 1.0, 6))
    pose_cov[0, 1] = pose_cov[1, 0] = 0.005
    twist_cov = np.eye(6) * 0.1
    odom = post(
        matrix_to_odometry(
            T,
            stamp,
            "odom",
            "base_link",
            twist=twist,
            pose_covariance=pose_cov,
            twist_covariance=twist_cov.reshape(36),
            flavor=flavor,
        )
    )
    T4, ns, frame, child = odometry_to_matrix(odom)
    np.testing.assert_allclose(T4, T, atol=1e-12)
    assert (ns, frame, child) == (stamp, "odom", "base_link")
    np.testing.assert_array_equal(odometry_twist(odom), twist)
    pc, tc = odometry_covariances(odom)
    np.testing.assert_array_equal(pc, pose_cov)
    np.testing.assert_array_equal(tc, twist_cov)


@pytest.mark.parametrize("flavor", FLAVORS)
def test_odometry_optional_parts_default_to_zero(flavor):
    odom = matrix_to_odometry(np.eye(4), 0, "odom", "lidar", flavor=flavor)
    np.testing.assert_array_equal(odometry_twist(odom), np.zeros(6))
    pc, tc = odometry_covariances(odom)
    assert not pc.any() and not tc.any()
    if flavor == "rclpy":
        from nav_msgs.msg import Odometry

        assert isinstance(odom, Odometry)
    else:
        assert odom.__msgtype__ == "nav_msgs/msg/Odometry"


_quats = hnp.arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda q: np.linalg.norm(q) > 0.1)
_trans = hnp.arrays(np.float64, 3, elements=st.floats(-1e4, 1e4))


@settings(max_examples=60, deadline=None)
@given(q=_quats, t=_trans, flavor=st.sampled_from(FLAVORS), ns=st.integers(0, 2**31 * 10**9 - 1))
def test_property_matrix_msg_matrix(q, t, flavor, ns):
    T = np.eye(4)
    T[:3, :3] = quaternion_to_matrix(q)
    T[:3, 3] = t
    msg = matrix_to_transform_stamped(T, ns, "a", "b", flavor)
    qm = _q(msg.transform.rotation)
    assert qm[3] >= 0 and abs(np.linalg.norm(qm) - 1) < 1e-12
    T_back, ns_back, _, _ = transform_stamped_to_matrix(msg)
    assert ns_back == ns
    np.testing.assert_allclose(T_back[:3, :3], T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(T_back[:3, 3], t, atol=0)
    np.testing.assert_array_equal(T_back[3], [0, 0, 0, 1])
    # same quaternion up to sign as the one we started from
    qn = q / np.linalg.norm(q)
    assert min(np.abs(qm - qn).max(), np.abs(qm + qn).max()) < 1e-9


# --------------------------------------------------------------------------------------------------
# stamps
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flavor", FLAVORS)
@pytest.mark.parametrize(
    "ns,sec,nanosec",
    [
        (0, 0, 0),
        (1_700_000_000_999_999_999, 1_700_000_000, 999_999_999),
        (-1, -1, 999_999_999),
        (2**31 * 10**9 - 1, 2**31 - 1, 999_999_999),
    ],
)
def test_stamps(flavor, ns, sec, nanosec):
    stamp = ns_to_stamp(ns, flavor)
    assert (stamp.sec, stamp.nanosec) == (sec, nanosec)
    assert stamp_to_ns(stamp) == ns


@pytest.mark.parametrize("flavor", FLAVORS)
def test_stamp_out_of_range_raises(flavor):
    stamp = ns_to_stamp(0, flavor)
    stamp.sec, stamp.nanosec = 3, 1_000_000_000  # would read as 4 s
    with pytest.raises(TransformFormatError, match=r"nanosec=1000000000 is out of range"):
        stamp_to_ns(stamp)
    if flavor == "rosbags":  # rclpy's Time refuses a sec outside int32 itself
        stamp.sec, stamp.nanosec = 2**31, 0
        with pytest.raises(TransformFormatError, match=r"sec=2147483648 does not fit"):
            stamp_to_ns(stamp)


def test_stamp_from_rclpy_time():
    from rclpy.time import Time

    t = Time(seconds=12, nanoseconds=34)
    assert stamp_to_ns(t) == 12_000_000_034
    assert stamp_to_ns(t.to_msg()) == 12_000_000_034


# --------------------------------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "T,match",
    [
        (np.eye(3), r"\(4, 4\) matrix, got shape \(3, 3\)"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), r"not a proper rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), r"not a proper rotation .*det -1"),
        (np.array([[1, 0, 0, np.nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]), r"NaN or Inf"),
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), r"last row"),
    ],
)
def test_bad_matrix_raises(T, match):
    with pytest.raises(TransformFormatError, match=match):
        matrix_to_pose(T)


def test_invert_rigid_transforms_and_refuses_an_overflowing_inverse():
    """invert(T) @ T = I over seeded random rigid transforms; a finite but huge translation whose -R^T t overflows,
    or a non-finite T, is a TransformFormatError."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    for _ in range(20):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.uniform(-100.0, 100.0, 3)
        np.testing.assert_allclose(invert(T) @ T, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(invert(T), np.linalg.inv(T), atol=1e-12)
    huge = np.eye(4)
    huge[:3, 3] = 1e308
    np.testing.assert_array_equal(invert(huge)[:3, 3], -1e308)  # finite: usable
    huge[:3, :3] = Rotation.from_euler("z", 45.0, degrees=True).as_matrix()
    huge[:3, 3] = 1.7e308  # -R^T t sums two terms of 1.2e308
    with pytest.raises(TransformFormatError, match=r"the inverse of the transform is not finite \(translation"):
        invert(huge)
    with pytest.raises(TransformFormatError, match="finite"):
        invert(np.full((4, 4), np.inf))


def test_other_errors():
    from geometry_msgs.msg import Pose

    with pytest.raises(TransformFormatError, match="zero norm"):
        pose_to_matrix(Pose(orientation=Pose().orientation.__class__(x=0.0, y=0.0, z=0.0, w=0.0)))
    with pytest.raises(TransformFormatError, match="unknown message flavor 'ros1'"):
        matrix_to_pose(np.eye(4), "ros1")
    with pytest.raises(TransformFormatError, match="int32 seconds"):
        ns_to_stamp(2**31 * 10**9)
    with pytest.raises(TransformFormatError, match="not a stamp"):
        stamp_to_ns(1.5)
    with pytest.raises(TransformFormatError, match=r"twist must be 6 finite numbers"):
        matrix_to_odometry(np.eye(4), twist=[1, 2, 3])
    with pytest.raises(TransformFormatError, match=r"pose_covariance must be \(6, 6\) or \(36,\)"):
        matrix_to_odometry(np.eye(4), pose_covariance=np.eye(3))
