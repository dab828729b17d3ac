"""The node among other nodes, over real DDS: the launch files' parameters, `-p` names it
does not know, and inputs that nothing publishes.

Each test runs in its own ROS_DOMAIN_ID with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import pytest
import yaml

from scanfuse.ros.messages import typestore
from tests.support import REPOSITORY, with_repository_on_path
from tests.support.synthetic import Scene, scene_messages, write_bag

if TYPE_CHECKING:
    from pathlib import Path

pytest.importorskip('rclpy')

from tests.ros.test_node_dds import SCENE_PARAMS, Loopback
from tests.support.loopback_domains import domain_id

pytestmark = pytest.mark.ros

PY = sys.executable
SCANFUSE = [PY, '-m', 'scanfuse']
# A user's file whose values differ from the defaults and from what the example launch file
# used to force (-p min_obstacle_height:=0.03 max_obstacle_height:=0.5 camera_timeout:=0.5).
USER_VALUES = {'min_obstacle_height': 0.08, 'max_obstacle_height': 0.4, 'camera_timeout': 0.3}


def ros_env() -> dict[str, str]:
    return with_repository_on_path(
        {
            **os.environ,
            'ROS_DOMAIN_ID': str(domain_id()),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        }
    )


def launch_defaults(tree: ast.AST) -> dict[str, str]:
    """DeclareLaunchArgument(name, default_value=...) of a launch file."""
    defaults = {}
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == 'DeclareLaunchArgument'
        ):
            name = node.args[0]
            value = next(k.value for k in node.keywords if k.arg == 'default_value')
            if isinstance(name, ast.Constant) and isinstance(value, ast.Constant):
                defaults[name.value] = value.value
    return defaults


def example_launch_command(params_file: Path) -> list[str]:
    """The command examples/scanfuse.launch.py's ExecuteProcess runs, its substitutions
    resolved: the launch arguments' defaults, `scanfuse` as this environment's."""
    tree = ast.parse((REPOSITORY / 'examples' / 'scanfuse.launch.py').read_text(encoding='utf-8'))
    defaults = launch_defaults(tree)
    (call,) = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == 'ExecuteProcess'
    ]
    cmd = next(k.value for k in call.keywords if k.arg == 'cmd')
    assert isinstance(cmd, ast.List)
    names = {'executable': 'scanfuse', 'params_file': str(params_file)}

    def resolve(item: ast.expr) -> list[str]:
        if isinstance(item, ast.Constant):
            return [item.value]
        if isinstance(item, ast.Name):
            return [names[item.id]]
        if isinstance(item, ast.List):
            return [''.join(part for element in item.elts for part in resolve(element))]
        if isinstance(item, ast.Call) and ast.unparse(item.func) == 'LaunchConfiguration':
            argument = item.args[0]
            assert isinstance(argument, ast.Constant)
            return [defaults[argument.value]]
        raise AssertionError(ast.unparse(item))

    command = [part for element in cmd.elts for part in resolve(element)]
    assert command[0] == 'scanfuse'
    return [*SCANFUSE, *command[1:]]


def package_launch_command(params_file: Path) -> list[str]:
    """What launch_ros runs for launch/scanfuse.launch.py's Node(name='scanfuse',
    parameters=[params_file], remappings=[('/scan', scan)]): the executable, then ROS args."""
    tree = ast.parse((REPOSITORY / 'launch' / 'scanfuse.launch.py').read_text(encoding='utf-8'))
    (call,) = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == 'Node'
    ]
    parameters = next(k.value for k in call.keywords if k.arg == 'parameters')
    # One entry, the user's file: no dict of values beside it that would override it.
    assert ast.unparse(parameters) == "[LaunchConfiguration('params_file')]"
    ros_args = ['-r', '__node:=scanfuse', '--params-file', str(params_file), '-r', '/scan:=/scan']
    return [
        PY,
        '-c',
        'from scanfuse.__main__ import node_entry; node_entry()',
        '--ros-args',
        *ros_args,
    ]


def get_params(tmp_path: Path, env: dict[str, str], names: list[str]) -> dict[str, object]:
    out = tmp_path / 'params.json'
    done = subprocess.run(
        [PY, '-m', 'tests.support.loopback', 'get-params', *names, '--out', str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(out.read_text(encoding='utf-8'))


@pytest.mark.parametrize('launch', ['examples', 'package'])
def test_the_launch_files_run_the_node_with_the_users_file_unchanged(tmp_path, launch):
    for path in (
        REPOSITORY / 'examples' / 'scanfuse.launch.py',
        REPOSITORY / 'launch' / 'scanfuse.launch.py',
    ):
        strings = {
            node.value
            for node in ast.walk(ast.parse(path.read_text(encoding='utf-8')))
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
        }
        assert not strings & {'-p', '--param'}, path
    params_file = tmp_path / 'robot.yaml'
    params_file.write_text(
        yaml.safe_dump({'scanfuse': {'ros__parameters': {**USER_VALUES, 'use_tf': False}}}),
        encoding='utf-8',
    )
    command = (example_launch_command if launch == 'examples' else package_launch_command)(
        params_file
    )
    env = ros_env()
    log = (tmp_path / 'node.log').open('w')
    node = subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        values = get_params(tmp_path, env, list(USER_VALUES))
    finally:
        node.terminate()
        node.wait(timeout=30)
    assert values == USER_VALUES, (tmp_path / 'node.log').read_text(encoding='utf-8')


@pytest.mark.parametrize(
    'given', ['min_obstacle_heigth:=0.08', 'scanfuse:min_obstacle_heigth:=0.08']
)
def test_an_unknown_p_name_stops_the_node_naming_the_nearest_parameter(given):
    done = subprocess.run(
        [*SCANFUSE, 'node', '--ros-args', '-p', given, '-p', 'use_tf:=false'],
        env=ros_env(),
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    expected = (
        'unknown parameter given with -p: min_obstacle_heigth (did you mean min_obstacle_height?)'
    )
    assert expected in ' '.join((done.stdout + done.stderr).split())


RENAMED = {
    '/camera/depth/image_raw': '/camera/camera/depth/image_rect_raw',
    '/camera/depth/camera_info': '/camera/camera/depth/camera_info',
}


def test_inputs_nobody_publishes_are_named_with_the_topics_that_exist(tmp_path):
    # A RealSense's topics, and the node left at its defaults: nothing publishes its depth
    # and CameraInfo topics.
    bag = write_bag(
        tmp_path / 'realsense.mcap',
        [
            (RENAMED.get(topic, topic), msgtype, log_time, raw)
            for topic, msgtype, log_time, raw in scene_messages(Scene(duration=2.0))
        ],
    )
    loop = Loopback(tmp_path, {'use_tf': False, **SCENE_PARAMS})
    try:
        loop.record('/diagnostics')
        loop.start('player', '-m', 'scanfuse', 'play', str(bag), '--loop')
        depth = (
            'nothing publishes /camera/depth/image_raw (depth_topic); Image topics published '
            'now: /camera/camera/depth/image_rect_raw: set depth_topic or remap'
        )
        info = (
            'nothing publishes /camera/depth/camera_info (camera_info_topic); CameraInfo '
            'topics published now: /camera/camera/depth/camera_info: set camera_info_topic '
            'or remap'
        )
        expected = [depth, info]
        deadline = time.monotonic() + 90
        while not all(text in ' '.join(loop.log('node').split()) for text in expected):
            assert time.monotonic() < deadline, loop.log('node')
            assert loop.node.poll() is None, loop.log('node')
            time.sleep(0.2)
        received = loop.received(linger=2.5)['/diagnostics']
    finally:
        loop.close()
    store = typestore()
    statuses = [
        status
        for _, raw in received
        for status in store.deserialize_cdr(raw, 'diagnostic_msgs/msg/DiagnosticArray').status
    ]
    named = [status for status in statuses if all(text in status.message for text in expected)]
    assert named, [status.message for status in statuses]
    assert named[-1].level >= 1  # WARN or worse
    values = {item.key: item.value for item in named[-1].values}
    assert values['no publisher: /camera/depth/image_raw'] == expected[0]
    # The LiDAR is published: it is not among the silent inputs.
    assert 'no publisher: /scan' not in values


def test_an_angle_in_degrees_on_the_command_line_is_refused_with_its_value_in_radians():
    done = subprocess.run(
        [*SCANFUSE, 'node', '--ros-args', '-p', 'camera_pitch:=20.0'],
        env=ros_env(),
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert '(radians: 20 deg = 0.349)' in done.stderr
