"""Launch scanfuse next to a RealSense camera and an RPLIDAR (Humble and Jazzy).

    ros2 launch examples/scanfuse.launch.py params_file:=examples/scanfuse_robot.yaml

For a pip install without a colcon workspace: the node runs as the `scanfuse` executable
of the Python environment it was installed into (`pip install scanfuse[ros]`, or into the
system Python of a ROS install), started here with ExecuteProcess. In a colcon workspace
use the package's own `ros2 launch scanfuse scanfuse.launch.py` (launch/). Inputs and
outputs can be remapped like any node's. Every parameter comes from params_file: nothing
here overrides it (tests/ros/test_launch_files.py).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration


def generate_launch_description() -> LaunchDescription:
    params_file = LaunchConfiguration('params_file')
    executable = LaunchConfiguration('scanfuse')
    return LaunchDescription(
        [
            DeclareLaunchArgument('params_file', default_value='examples/scanfuse_robot.yaml'),
            DeclareLaunchArgument('scanfuse', default_value='scanfuse'),
            DeclareLaunchArgument('scan', default_value='/scan'),
            ExecuteProcess(
                cmd=[
                    executable,
                    'node',
                    '--params-file',
                    params_file,
                    '--ros-args',
                    '-r',
                    ['/scan:=', LaunchConfiguration('scan')],
                ],
                name='scanfuse',
                output='screen',
            ),
        ]
    )
