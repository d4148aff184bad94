"""Launch the DeepBBS++ registration node with the shipped parameter file.

    ros2 launch deepbbs_ros deepbbs_registration.launch.py \
        source_cloud:=/lidar/points target_cloud:=/map/points mode:=pair use_sim_time:=false

Arguments: ``params_file`` (default: this package's config/deepbbs_ros.yaml), ``mode`` (pair |
odometry), ``source_cloud``, ``target_cloud``, ``cloud`` (odometry input), ``use_sim_time``.
The node runs with the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml) unless
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE is already set (README, "Large clouds").
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
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
        DeclareLaunchArgument("source_cloud", default_value="source_cloud", description="source PointCloud2 topic"),
        DeclareLaunchArgument("target_cloud", default_value="target_cloud", description="target PointCloud2 topic"),
        DeclareLaunchArgument("cloud", default_value="cloud", description="input PointCloud2 topic (odometry mode)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
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
    return LaunchDescription([*args, node])
