"""Launch the managed localization node (deepbbs-localizer) and a lifecycle manager, as Nav2's localization_launch.py.

    ros2 launch deepbbs_ros localization.launch.py map:=/maps/town.pcd
    ros2 launch deepbbs_ros localization.launch.py map:=/maps/town.pcd cloud:=/lidar/points use_sim_time:=true
    ros2 launch deepbbs_ros localization.launch.py map:=/maps/town.pcd autostart:=false   # configure/activate later

Arguments: ``namespace`` (''), ``use_sim_time`` (false), ``autostart`` (true: configure and activate the node at
start), ``params_file`` (default: this package's config/nav2_localization.yaml, Nav2's layout: a section for
``deepbbs_localizer`` and one for ``lifecycle_manager_localization``), ``map`` (the .pcd / .ply prior map:
``localization.map_path``), ``cloud`` (the scans' PointCloud2 topic, the node's ``source_cloud``), ``log_level``
(info), ``use_lifecycle_manager`` (true where nav2_lifecycle_manager is installed).

With Nav2 installed, ``nav2_lifecycle_manager`` (``lifecycle_manager_localization``, ``node_names:
[deepbbs_localizer]``) drives the node through ``deepbbs_localizer/change_state`` and watches its bond heartbeat
(``bond_timeout`` in the params file). Without Nav2 (a pip install), ``autostart`` is done by
this file: configure at start, activate once the node is inactive (launch_ros lifecycle events).
The node runs with the shipped Fast DDS shared-memory profile (resources/fastdds_shm.xml) unless
FASTRTPS_DEFAULT_PROFILES_FILE / FASTDDS_DEFAULT_PROFILES_FILE is already set.
"""

import os

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.parameter_descriptions import ParameterValue
from lifecycle_msgs.msg import Transition

from deepbbs_ros.node.dds import profile_env
from launch import LaunchDescription

NODE_NAME = "deepbbs_localizer"
MANAGER_NAME = "lifecycle_manager_localization"


def _has_nav2() -> bool:
    try:
        get_package_share_directory("nav2_lifecycle_manager")
    except PackageNotFoundError:
        return False
    return True


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("deepbbs_ros")
    use_sim_time = ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)
    autostart = ParameterValue(LaunchConfiguration("autostart"), value_type=bool)
    args = [
        DeclareLaunchArgument("namespace", default_value="", description="top-level namespace"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="follow /clock"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure and activate the node at start"),
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "nav2_localization.yaml"),
            description="ROS 2 parameter file in Nav2's layout (deepbbs_localizer, lifecycle_manager_localization)",
        ),
        DeclareLaunchArgument("map", default_value="", description="the prior map (.pcd / .ply, map frame)"),
        DeclareLaunchArgument("cloud", default_value="source_cloud", description="the scans' PointCloud2 topic"),
        DeclareLaunchArgument("log_level", default_value="info", description="log level"),
        DeclareLaunchArgument("use_lifecycle_manager", default_value=str(_has_nav2()).lower(),
                              description="start nav2_lifecycle_manager (default: true where it is installed)"),
    ]
    localizer = LifecycleNode(
        package="deepbbs_ros",
        executable="deepbbs-localizer",
        name=NODE_NAME,
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "localization.map_path": ParameterValue(LaunchConfiguration("map"), value_type=str),
                "use_sim_time": use_sim_time,
            },
        ],
        remappings=[("source_cloud", LaunchConfiguration("cloud"))],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
        additional_env=profile_env(),
    )
    manager = Node(
        package="nav2_lifecycle_manager",
        executable="lifecycle_manager",
        name=MANAGER_NAME,
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        parameters=[
            LaunchConfiguration("params_file"),
            {"use_sim_time": use_sim_time, "autostart": autostart, "node_names": [NODE_NAME]},
        ],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
        condition=IfCondition(LaunchConfiguration("use_lifecycle_manager")),
    )
    # no lifecycle manager: autostart by launch_ros's lifecycle events (configure now, activate once inactive)
    by_events = IfCondition(PythonExpression(["'", LaunchConfiguration("autostart"), "'.lower() == 'true' and '",
                                              LaunchConfiguration("use_lifecycle_manager"), "'.lower() != 'true'"]))
    configure = EmitEvent(
        event=ChangeState(lifecycle_node_matcher=matches_action(localizer),
                          transition_id=Transition.TRANSITION_CONFIGURE),
        condition=by_events,
    )
    activate = RegisterEventHandler(
        OnStateTransition(
            target_lifecycle_node=localizer, start_state="configuring", goal_state="inactive",
            entities=[EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(localizer),
                                                  transition_id=Transition.TRANSITION_ACTIVATE))],
        ),
        condition=by_events,
    )
    return LaunchDescription([*args, localizer, manager, activate, configure])
