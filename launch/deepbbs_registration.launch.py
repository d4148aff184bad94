"""Launch the DeepBBS++ registration node with the shipped parameter file.

    ros2 launch deepbbs_ros deepbbs_registration.launch.py mode:=odometry topic:=/points \
        base_frame:=base_link odom_frame:=odom publish_tf:=true use_sim_time:=false visualize:=true
    ros2 launch deepbbs_ros deepbbs_registration.launch.py \
        source_cloud:=/lidar/points target_cloud:=/map/points target_mode:=latched

Arguments (the names KISS-ICP's launch file uses where they mean the same): ``params_file`` (default: this
package's config/deepbbs_ros.yaml), ``mode`` (pair | odometry), ``topic`` (the odometry input, as KISS-ICP;
``cloud`` is the same), ``source_cloud``, ``target_cloud``, ``target_mode`` (stamped | latched: a map
published once, transient local), ``base_frame`` (odometry: the motion published is this frame's, with
base <- sensor from /tf_static; '' = the cloud frame), ``odom_frame``, ``publish_tf``, ``invert_tf``
(publish base -> odom), ``publish_odometry``, ``use_sim_time``, ``visualize`` (start RViz2 with the shipped
rviz/deepbbs_ros.rviz: input cloud /points, aligned cloud, trajectory, TF; turns on ~/aligned_cloud).
The node runs with the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml) unless
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE is already set (README, "Large clouds").
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from deepbbs_ros.node.dds import profile_env
from launch import LaunchDescription


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
                              description="pair mode: stamped (pairs by stamp) | latched (a map / reference cloud)"),
        DeclareLaunchArgument("base_frame", default_value="base_link",
                              description="odometry: frame whose motion is published ('' = the cloud frame)"),
        DeclareLaunchArgument("odom_frame", default_value="odom", description="odometry frame"),
        DeclareLaunchArgument("publish_tf", default_value="true", description="odometry: odom -> base on /tf"),
        DeclareLaunchArgument("invert_tf", default_value="false", description="publish base -> odom instead"),
        DeclareLaunchArgument("publish_odometry", default_value="true", description="~/odometry (nav_msgs/Odometry)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("visualize", default_value="false", description="start RViz2 with the shipped config"),
    ]
    node = Node(
        package="deepbbs_ros",
        executable="deepbbs-node",
        name="deepbbs_registration",
        output="screen",
        emulate_tty=True,
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "node.mode": LaunchConfiguration("mode"),
                "node.target_mode": LaunchConfiguration("target_mode"),
                "node.base_frame": ParameterValue(LaunchConfiguration("base_frame"), value_type=str),
                "node.odom_frame": ParameterValue(LaunchConfiguration("odom_frame"), value_type=str),
                "node.publish_tf": ParameterValue(LaunchConfiguration("publish_tf"), value_type=bool),
                "node.invert_tf": ParameterValue(LaunchConfiguration("invert_tf"), value_type=bool),
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
    return LaunchDescription([*args, node, rviz])
