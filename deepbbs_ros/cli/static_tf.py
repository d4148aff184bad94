"""``deepbbs-ros static-tf``: a static transform on ``/tf_static`` until stopped, from the flags of tf2_ros
static_transform_publisher."""

from __future__ import annotations

import argparse
from typing import Any

from deepbbs_ros.errors import NodeError


def add_parser(sub: Any) -> None:
    st = sub.add_parser(
        "static-tf", formatter_class=argparse.RawDescriptionHelpFormatter,
        help="publish a static transform on /tf_static until stopped (tf2_ros static_transform_publisher's flags)",
        description="Publish frame-id -> child-frame-id on /tf_static (transient local, reliable: latched for late "
                    "subscribers) until Ctrl-C / SIGTERM; the flags of tf2_ros static_transform_publisher. Rotation "
                    "from --roll --pitch --yaw (rad, about the fixed x, y, z axes) or --qx --qy --qz --qw, not both.",
        epilog="example:\n  deepbbs-ros static-tf --x 0.5 --z 1.8 --yaw 0.1 --frame-id base_link "
               "--child-frame-id velodyne",
    )
    for axis in ("x", "y", "z"):
        st.add_argument(f"--{axis}", type=float, default=0.0, help=f"translation {axis} (m)")
    for angle in ("roll", "pitch", "yaw"):
        st.add_argument(f"--{angle}", type=float, default=None, help=f"{angle} (rad)")
    for comp in ("qx", "qy", "qz", "qw"):
        st.add_argument(f"--{comp}", type=float, default=None, help=f"quaternion {comp[1]}")
    st.add_argument("--frame-id", required=True, help="parent frame")
    st.add_argument("--child-frame-id", required=True, help="child frame")


def transform(args: argparse.Namespace) -> tuple[Any, str, str]:
    """(``T_parent_child`` (4, 4), parent, child) from static_transform_publisher's flags; NodeError on a
    mix of roll/pitch/yaw and quaternion, a zero quaternion, or a frame id that is empty, equal or starts with /."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from deepbbs_ros.datasets.poses import xyzquat_to_T

    for key in ("frame_id", "child_frame_id"):
        frame = getattr(args, key)
        if not frame or frame.startswith("/") or any(c.isspace() for c in frame):
            raise NodeError(f"--{key.replace('_', '-')}: invalid frame id {frame!r} (not empty, no leading '/', "
                            "no spaces)")
    if args.frame_id == args.child_frame_id:
        raise NodeError(f"--frame-id and --child-frame-id are the same frame {args.frame_id!r}")
    rpy = [args.roll, args.pitch, args.yaw]
    quat = [args.qx, args.qy, args.qz, args.qw]
    if any(v is not None for v in rpy) and any(v is not None for v in quat):
        raise NodeError("give the rotation as --roll --pitch --yaw or as --qx --qy --qz --qw, not both")
    T = np.eye(4)
    T[:3, 3] = [args.x, args.y, args.z]
    if any(v is not None for v in quat):
        q = [0.0 if v is None else v for v in quat[:3]] + [1.0 if quat[3] is None else quat[3]]
        try:
            T[:3, :3] = xyzquat_to_T([0.0, 0.0, 0.0, *q])[:3, :3]  # normalised, as every pose reader's
        except ValueError:
            raise NodeError(f"--qx --qy --qz --qw: not a rotation {q}") from None
    else:  # tf2's setRPY: roll about x, then pitch about y, then yaw about z (fixed axes)
        T[:3, :3] = Rotation.from_euler("xyz", [0.0 if v is None else v for v in rpy]).as_matrix()
    if not np.all(np.isfinite(T)):
        raise NodeError("the transform has a non-finite value")
    return T, args.frame_id, args.child_frame_id


def serve(node: Any, transform: tuple[Any, str, str]) -> int:
    """Publish the transform once on ``/tf_static`` (reliable, transient local, as tf2_ros's static broadcaster:
    late subscribers get it) and keep the publisher until Ctrl-C / SIGTERM (exit code 0)."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as err:
        raise NodeError("tf2_msgs is not installed: build it with `deepbbs-ros build-interfaces`") from err
    from msg_adapters.transforms import matrix_to_transform_stamped

    T, parent, child = transform
    qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(TFMessage, "/tf_static", qos)
    stamp = node.get_clock().now().nanoseconds
    pub.publish(TFMessage(transforms=[matrix_to_transform_stamped(T, stamp, parent, child)]))
    t, yaw = T[:3, 3], _yaw_deg(T)
    print(f"/tf_static: {parent} -> {child} xyz [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] yaw {yaw:.2f} deg "
          "(latched; Ctrl-C to stop)", flush=True)
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.5)
    return 0


def _yaw_deg(T: Any) -> float:
    import numpy as np

    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))
