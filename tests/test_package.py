"""The repository as a ROS 2 package: package.xml, and what `colcon build` installs.

The colcon test builds a fresh workspace whose src/ holds the repository (a symlink), with
and without --symlink-install, sources install/setup.bash and looks the package up the way
`ros2 run` and `ros2 launch` do: through the ament index (ament_index_python).
`ros2 launch` itself is not run: launch and launch_ros are not among the PyPI wheels, so
the launch file is read with `ast` and what it names is checked against the install.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from tests.support import REPOSITORY

ROOT = REPOSITORY
SOURCES = ROOT / 'src' / 'scanfuse'
LAUNCH_FILE = ROOT / 'launch' / 'scanfuse.launch.py'
# Import names that are ROS packages (rosdep/ament names), not Python libraries.
ROS_PACKAGE = re.compile(r'^(rclpy|launch|launch_ros|ament_index_python|\w+_msgs|\w+_interfaces)$')

# What `ros2 run` and `ros2 launch` ask the ament index, and where scanfuse imports from.
LOOKUP = """
import json
import scanfuse
from ament_index_python.packages import (
    get_package_prefix, get_package_share_directory, get_packages_with_prefixes
)
print(json.dumps({
    'prefix': get_package_prefix('scanfuse'),
    'share': get_package_share_directory('scanfuse'),
    'packages': get_packages_with_prefixes(),
    'module': scanfuse.__file__,
}))
"""

needs_colcon = pytest.mark.skipif(
    importlib.util.find_spec('colcon_core') is None,
    reason="colcon is not installed: pip install -e '.[test]' (make test installs it)",
)


def manifest() -> ET.Element:
    return ET.parse(ROOT / 'package.xml').getroot()  # noqa: S314 - the repository's own file


def imported_ros_packages(paths: list[Path]) -> set[str]:
    names: set[str] = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module.split('.')[0])
    return {name for name in names if ROS_PACKAGE.match(name)}


def test_package_xml_is_format_3_ament_python_with_the_project_version():
    root = manifest()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'scanfuse'
    assert root.findtext('export/build_type') == 'ament_python'
    pyproject = (ROOT / 'pyproject.toml').read_text(encoding='utf-8')
    (version,) = re.findall(r'^version = "([^"]+)"$', pyproject, flags=re.MULTILINE)
    assert root.findtext('version') == version


def test_package_xml_declares_every_ros_package_the_code_and_launch_file_import():
    declared = {element.text for element in manifest().iter('exec_depend')}
    used = imported_ros_packages([*SOURCES.rglob('*.py'), LAUNCH_FILE])
    # The node's own imports: if one of these is missing, the scan above is broken.
    assert {'rclpy', 'sensor_msgs', 'diagnostic_msgs', 'tf2_msgs', 'rcl_interfaces'} <= used
    assert used - declared == set()


def test_tf_message_hash_is_one_for_humble_jazzy_and_kilted():
    # tools/build_tf2_msgs.py builds one definition for either distribution's wheels.
    hashes = {
        get_typestore(store).hash_rihs01('tf2_msgs/msg/TFMessage')
        for store in (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY, Stores.ROS2_KILTED)
    }
    assert len(hashes) == 1


def clean_environment() -> dict[str, str]:
    """This process's environment without anything that points at another ROS install."""
    dropped = ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH')
    return {key: value for key, value in os.environ.items() if key not in dropped}


def call_keywords(tree: ast.AST, function: str) -> dict[str, object]:
    (call,) = [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == function
    ]
    return {
        keyword.arg: keyword.value.value
        for keyword in call.keywords
        if keyword.arg and isinstance(keyword.value, ast.Constant)
    }


def sourced_environment(workspace: Path) -> dict[str, str]:
    """The environment a shell has after `source install/setup.bash`."""
    dump = 'import json, os; print(json.dumps(dict(os.environ)))'
    done = subprocess.run(
        ['bash', '-c', '. install/setup.bash && exec "$0" -c "$1"', sys.executable, dump],
        cwd=workspace,
        env=clean_environment(),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return json.loads(done.stdout.splitlines()[-1])


@needs_colcon
@pytest.mark.parametrize('options', [[], ['--symlink-install']], ids=['install', 'symlink'])
def test_colcon_build_installs_the_node_and_its_launch_and_parameter_files(tmp_path, options):
    workspace = tmp_path / 'ws'
    (workspace / 'src').mkdir(parents=True)
    (workspace / 'src' / 'scanfuse').symlink_to(ROOT, target_is_directory=True)
    colcon_folders = ('build', 'install', 'log')
    already = {name for name in colcon_folders if (ROOT / name).exists()}
    colcon = 'import sys; from colcon_core.command import main; sys.exit(main(argv=sys.argv[1:]))'
    build = subprocess.run(
        [sys.executable, '-c', colcon, '--log-base', str(workspace / 'log'), 'build', *options],
        cwd=workspace,
        env=clean_environment(),
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    # The build happened in the workspace, not in the repository.
    assert {name for name in colcon_folders if (ROOT / name).exists()} == already

    install = workspace / 'install' / 'scanfuse'
    env = sourced_environment(workspace)
    lookup = subprocess.run(
        [sys.executable, '-c', LOOKUP],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    found = json.loads(lookup.stdout)
    assert found['packages'] == {'scanfuse': str(install)}
    assert Path(found['prefix']) == install
    share = Path(found['share'])
    assert share == install / 'share' / 'scanfuse'
    # The workspace's package is the one that imports, not this checkout or a pip install
    # (with --symlink-install, a link in the build folder to the sources).
    assert Path(found['module']).is_relative_to(workspace)

    # `ros2 launch scanfuse scanfuse.launch.py` runs <share>/launch/scanfuse.launch.py.
    launch = share / 'launch' / 'scanfuse.launch.py'
    assert launch.read_bytes() == LAUNCH_FILE.read_bytes()
    tree = ast.parse(launch.read_text(encoding='utf-8'))
    node = call_keywords(tree, 'Node')
    assert node['package'] == 'scanfuse'
    (params_name,) = [
        statement.value.value
        for statement in tree.body
        if isinstance(statement, ast.Assign)
        and isinstance(statement.targets[0], ast.Name)
        and statement.targets[0].id == 'PARAMS_FILE'
        and isinstance(statement.value, ast.Constant)
    ]
    params = share / 'config' / str(params_name)
    assert params.read_bytes() == (ROOT / 'examples' / str(params_name)).read_bytes()
    assert (share / 'config' / 'scanfuse.yaml').is_file()
    assert (share / 'config' / 'fastdds_announce.xml').is_file()
    assert (share / 'package.xml').read_bytes() == (ROOT / 'package.xml').read_bytes()

    # `ros2 run scanfuse scanfuse_node` runs <prefix>/lib/scanfuse/scanfuse_node.
    executable = Path(found['prefix']) / 'lib' / 'scanfuse' / str(node['executable'])
    assert node['executable'] == 'scanfuse_node'
    assert os.access(executable, os.X_OK)
    assert os.access(executable.with_name('scanfuse'), os.X_OK)  # ros2 run scanfuse scanfuse bag
    ran = subprocess.run(
        [str(executable), '--help'],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert ran.returncode == 0, ran.stderr
    assert 'Usage: scanfuse node' in ran.stdout
    assert '--params-file' in ran.stdout
    if importlib.util.find_spec('rclpy') is None:
        return
    # The arguments launch_ros's Node(name=..., parameters=[file], remappings=...) passes:
    # the parameter file reaches scanfuse (a missing one stops it before DDS starts).
    missing = tmp_path / 'missing.yaml'
    ros_args = ['-r', '__node:=scanfuse', '--params-file', str(missing), '-r', '/scan:=/scan']
    launched = subprocess.run(
        [str(executable), '--ros-args', *ros_args],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert launched.returncode == 1
    assert f'cannot read parameter file {missing}' in launched.stderr
