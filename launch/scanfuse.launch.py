"""Launch the scanfuse node of the colcon package (Humble, Jazzy, Kilted).

    ros2 launch scanfuse scanfuse.launch.py [params_file:=FILE] [scan:=/scan]

The parameter file defaults to the package's own config/scanfuse_robot.yaml (installed
from examples/), found through the ament index, so it works from any directory. For a
pip install without a colcon workspace, examples/scanfuse.launch.py starts the
`scanfuse` command instead.
"""

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PARAMS_FILE = 'scanfuse_robot.yaml'


def generate_launch_description() -> LaunchDescription:
    share = Path(get_package_share_directory('scanfuse'))
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                'params_file',
                default_value=str(share / 'config' / PARAMS_FILE),
                description='ROS 2 parameter file (scanfuse: ros__parameters)',
            ),
            DeclareLaunchArgument('scan', default_value='/scan', description='LaserScan input'),
            Node(
                package='scanfuse',
                executable='scanfuse_node',
                name='scanfuse',
                output='screen',
                parameters=[LaunchConfiguration('params_file')],
                remappings=[('/scan', LaunchConfiguration('scan'))],
            ),
        ]
    )
