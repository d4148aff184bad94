"""Launch the DeepBBS++ registration node with the shipped parameter file.

    ros2 launch deepbbs_ros deepbbs_registration.launch.py mode:=odometry topic:=/points \
        base_frame:=base_link odom_frame:=odom publish_tf:=true use_sim_time:=false visualize:=true
    ros2 launch deepbbs_ros deepbbs_registration.launch.py \
        source_cloud:=/lidar/points target_cloud:=/map/points target_mode:=latched
    ros2 launch deepbbs_ros deepbbs_registration.launch.py mode:=odometry bagfile:=bags/urban_drive_hdl64
    ros2 launch deepbbs_ros deepbbs_registration.launch.py source_cloud:=/points target_mode:=localization \
        map_path:=/maps/town.pcd

Arguments: ``params_file`` (default: this package's config/deepbbs_ros.yaml), ``mode`` (pair | odometry),
``topic`` (the odometry input; ``cloud`` is the same), ``source_cloud``, ``target_cloud``, ``target_mode``
(stamped | latched: a map published once, transient local | localization: the pose in a prior map with no initial
pose), ``map_path`` (localization: the map file, .pcd / .ply; '' = the map from ``target_cloud``), ``base_frame``
(odometry: the motion published is this frame's, with base <- sensor from /tf_static; '' = the cloud frame),
``odom_frame``, ``publish_tf``,
``invert_tf`` (publish base -> odom), ``publish_odometry``, ``use_sim_time``, ``visualize`` (start RViz2 with the
shipped rviz/deepbbs_ros.rviz: input cloud /points, aligned cloud, trajectory, TF; turns on ~/aligned_cloud),
``bagfile`` (play a recording into the node with deepbbs-play: odometry mode on ``topic``; pair mode each scan
on ``source_cloud`` and the scan before it on ``target_cloud``, restamped, so that they pair).

KISS-ICP's launch argument names are accepted too, for the same settings: ``lidar_odom_frame`` (= ``odom_frame``),
``publish_odom_tf`` (= ``publish_tf``), ``invert_odom_tf`` (= ``invert_tf``), ``config_file`` (= ``params_file``),
``topic``, ``base_frame``, ``visualize``, ``use_sim_time``, ``bagfile``; given both ways, KISS-ICP's name wins.
``position_covariance`` / ``orientation_covariance`` are accepted and not used (one log line): the node's
``~/odometry`` covariances come from the registration residuals. The defaults are this node's, not KISS-ICP's.
The node runs with the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml) unless
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE is already set (README, "Large clouds").
"""

import os
import sys

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess, LogInfo
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from deepbbs_ros.node.dds import profile_env
from launch import LaunchDescription

#: KISS-ICP's launch argument -> this file's argument of the same meaning (the node setting it feeds)
KISS_ICP_ALIASES = {
    "lidar_odom_frame": "odom_frame",
    "publish_odom_tf": "publish_tf",
    "invert_odom_tf": "invert_tf",
    "config_file": "params_file",
}


def _is(name: str, op: str, value: str) -> PythonExpression:
    """``'<the argument>' <op> '<value>'`` evaluated at launch time."""
    return PythonExpression(["'", LaunchConfiguration(name), f"' {op} '{value}'"])


def _bag_and_mode(mode: str) -> PythonExpression:
    return PythonExpression(["'", LaunchConfiguration("bagfile"), "' != '' and '", LaunchConfiguration("mode"),
                             f"' == '{mode}'"])


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("deepbbs_ros")
    args = [
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "deepbbs_ros.yaml"),
            description="ROS 2 parameter file (same schema as deepbbs_ros.config.Config)",
        ),
        DeclareLaunchArgument("mode", default_value="pair", description="pair | odometry"),
        DeclareLaunchArgument("topic", default_value="cloud", description="input PointCloud2 topic (odometry mode)"),
        DeclareLaunchArgument("cloud", default_value=LaunchConfiguration("topic"), description="same as topic"),
        DeclareLaunchArgument("source_cloud", default_value="source_cloud", description="source PointCloud2 topic"),
        DeclareLaunchArgument("target_cloud", default_value="target_cloud", description="target PointCloud2 topic"),
        DeclareLaunchArgument("target_mode", default_value="stamped",
                              description="pair mode: stamped (pairs by stamp) | latched (a map / reference cloud) | "
                                          "localization (the pose in a prior map, no initial pose)"),
        DeclareLaunchArgument("map_path", default_value="",
                              description="localization: the map file (.pcd / .ply, map frame); '' = target_cloud"),
        DeclareLaunchArgument("base_frame", default_value="base_link",
                              description="odometry: frame whose motion is published ('' = the cloud frame)"),
        DeclareLaunchArgument("odom_frame", default_value="odom", description="odometry frame"),
        DeclareLaunchArgument("publish_tf", default_value="true", description="odometry: odom -> base on /tf"),
        DeclareLaunchArgument("invert_tf", default_value="false", description="publish base -> odom instead"),
        DeclareLaunchArgument("publish_odometry", default_value="true", description="~/odometry (nav_msgs/Odometry)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("visualize", default_value="false", description="start RViz2 with the shipped config"),
        DeclareLaunchArgument("bagfile", default_value="",
                              description="play this recording into the node (deepbbs-play; '' = none)"),
        # KISS-ICP's names: each defaults to this file's argument, so either name sets the node's setting
        *(DeclareLaunchArgument(kiss, default_value=LaunchConfiguration(ours), description=f"KISS-ICP's name of {ours}")
          for kiss, ours in KISS_ICP_ALIASES.items()),
        DeclareLaunchArgument("position_covariance", default_value="",
                              description="KISS-ICP's; not used: the covariances come from the registration"),
        DeclareLaunchArgument("orientation_covariance", default_value="",
                              description="KISS-ICP's; not used: the covariances come from the registration"),
    ]
    node = Node(
        package="deepbbs_ros",
        executable="deepbbs-node",
        name="deepbbs_registration",
        output="screen",
        emulate_tty=True,
        parameters=[
            LaunchConfiguration("config_file"),
            {
                "node.mode": LaunchConfiguration("mode"),
                "node.target_mode": LaunchConfiguration("target_mode"),
                "localization.map_path": ParameterValue(LaunchConfiguration("map_path"), value_type=str),
                "node.base_frame": ParameterValue(LaunchConfiguration("base_frame"), value_type=str),
                "node.odom_frame": ParameterValue(LaunchConfiguration("lidar_odom_frame"), value_type=str),
                "node.publish_tf": ParameterValue(LaunchConfiguration("publish_odom_tf"), value_type=bool),
                "node.invert_tf": ParameterValue(LaunchConfiguration("invert_odom_tf"), value_type=bool),
                "node.publish_odometry": ParameterValue(LaunchConfiguration("publish_odometry"), value_type=bool),
                # RViz shows the aligned cloud: published when visualising
                "node.publish_aligned_cloud": ParameterValue(LaunchConfiguration("visualize"), value_type=bool),
                "use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
            },
        ],
        remappings=[
            ("source_cloud", LaunchConfiguration("source_cloud")),
            ("target_cloud", LaunchConfiguration("target_cloud")),
            ("cloud", LaunchConfiguration("cloud")),
        ],
        additional_env=profile_env(),
    )
    rviz = ExecuteProcess(
        cmd=["rviz2", "-d", os.path.join(share, "rviz", "deepbbs_ros.rviz")],
        condition=IfCondition(LaunchConfiguration("visualize")),
        output="screen",
    )
    # the recording: deepbbs-play (this interpreter: the package is importable here) waits for the node's start
    play_odometry = ExecuteProcess(
        cmd=[sys.executable, "-m", "deepbbs_ros.cli.play", LaunchConfiguration("bagfile"), "--wait", "120", "--quiet",
             "--cloud-topic", LaunchConfiguration("cloud")],
        condition=IfCondition(_bag_and_mode("odometry")),
        output="screen",
        additional_env=profile_env(),
    )
    play_pair = ExecuteProcess(
        cmd=[sys.executable, "-m", "deepbbs_ros.cli.play", LaunchConfiguration("bagfile"), "--wait", "120", "--quiet",
             "--cloud-topic", LaunchConfiguration("source_cloud"),
             "--previous-topic", LaunchConfiguration("target_cloud")],
        condition=IfCondition(_bag_and_mode("pair")),
        output="screen",
        additional_env=profile_env(),
    )
    unused = [
        LogInfo(msg=f"{name} is not used: deepbbs-node's ~/odometry covariances come from the registration residuals",
                condition=IfCondition(_is(name, "!=", "")))
        for name in ("position_covariance", "orientation_covariance")
    ]
    return LaunchDescription([*args, *unused, node, rviz, play_odometry, play_pair])
