"""The repository as a ROS 2 package: package.xml, and what `colcon build` installs.

The colcon test builds a fresh workspace whose src/ holds the repository (a symlink), with
and without --symlink-install, under the system setuptools of Humble (59.6.0, Ubuntu 22.04)
and Jazzy (68.1.2, Ubuntu 24.04) as well as the test environment's own, sources
install/setup.bash and looks the package up the way `ros2 run` and `ros2 launch` do:
through the ament index (ament_index_python).
`ros2 launch` itself is not run: launch and launch_ros are not among the PyPI wheels, so
the launch file is read with `ast` and what it names is checked against the install.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from tests.support import REPOSITORY

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: the test extra brings tomli
    import tomli as tomllib

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


# What colcon runs setup.py with on a stock ROS 2 machine: the system's setuptools.
SYSTEM_SETUPTOOLS = {'humble': '59.6.0', 'jazzy': '68.1.2'}
COLCON = 'import sys; from colcon_core.command import main; sys.exit(main(argv=sys.argv[1:]))'


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


# Each of pyproject.toml's dependencies and its rosdep key (ros/rosdistro rosdep/python.yaml),
# or None where no key resolves on Ubuntu 22.04 and 24.04.
ROSDEP_KEYS = {
    'numpy': 'python3-numpy',
    'pydantic': 'python3-pydantic',
    'pyyaml': 'python3-yaml',
    'typer': None,
    'rich': None,
    'rosbags': None,
    'numba': None,  # python3-numba has rules for bionic and focal only
}


def test_package_xml_declares_the_python_dependencies_that_have_rosdep_keys():
    pyproject = tomllib.loads((ROOT / 'pyproject.toml').read_text(encoding='utf-8'))
    names = {
        re.split(r'[<>=!~ ;\[]', spec)[0].lower() for spec in pyproject['project']['dependencies']
    }
    # A new dependency needs a decision here: its key, or None.
    assert names == set(ROSDEP_KEYS)
    declared = {element.text for element in manifest().iter('exec_depend')}
    expected = {key for key in ROSDEP_KEYS.values() if key is not None}
    assert expected <= declared
    assert {name for name in declared if name and name.startswith('python3-')} == expected


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


@pytest.fixture(scope='session')
def colcon_pythons(tmp_path_factory) -> dict[str, str]:
    """An interpreter per setuptools: the test environment's, and one venv per distribution.

    Each venv holds exactly that distribution's setuptools and colcon; a .pth file appends
    this environment's site-packages after its own, so the built node can import numpy and
    rclpy while setup.py sees only the pinned setuptools. The venvs use this interpreter's
    Python version (the ROS wheels here are built for it), not the distributions' 3.10/3.12.
    """
    pythons = {'current': sys.executable}
    base = (
        Path(sys.base_prefix) / 'bin' / f'python{sys.version_info.major}.{sys.version_info.minor}'
    )
    for distribution, version in SYSTEM_SETUPTOOLS.items():
        venv = tmp_path_factory.mktemp(f'colcon-{distribution}') / 'venv'
        subprocess.run([str(base), '-m', 'venv', str(venv)], check=True, timeout=300)
        python = venv / 'bin' / 'python'
        subprocess.run(
            [str(python), '-m', 'pip', 'install', '-q', '--disable-pip-version-check',
             f'setuptools=={version}', 'colcon-common-extensions'],
            check=True, timeout=600, capture_output=True,
        )  # fmt: skip
        purelib = Path(
            subprocess.run(
                [str(python), '-c', 'import sysconfig; print(sysconfig.get_paths()["purelib"])'],
                check=True, capture_output=True, text=True, timeout=60,
            ).stdout.strip()
        )  # fmt: skip
        (purelib / 'zz_test_environment.pth').write_text(
            sysconfig.get_paths()['purelib'] + '\n', encoding='utf-8'
        )
        pythons[distribution] = str(python)
    return pythons


def test_setup_py_reads_pyproject_tables_as_tomllib_does():
    # setup.py's own reader serves setuptools 59.6 on Python 3.10, which has no tomllib.
    spec = importlib.util.spec_from_file_location('scanfuse_setup_under_test', ROOT / 'setup.py')
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # under this name setup() does not run
    text = (ROOT / 'pyproject.toml').read_text(encoding='utf-8')
    expected = tomllib.loads(text)['project']
    read = module.read_project_tables(text)
    assert read['project'] == {
        key: value for key, value in expected.items() if key in read['project']
    }
    assert {'name', 'version', 'description', 'license', 'requires-python', 'dependencies'} <= set(
        read['project']
    )
    assert read['project.scripts'] == expected['scripts']


@needs_colcon
@pytest.mark.parametrize('setuptools', ['current', 'humble', 'jazzy'])
@pytest.mark.parametrize('options', [[], ['--symlink-install']], ids=['install', 'symlink'])
def test_colcon_build_installs_the_node_and_its_launch_and_parameter_files(
    tmp_path, options, setuptools, colcon_pythons
):
    python = colcon_pythons[setuptools]
    if setuptools in SYSTEM_SETUPTOOLS:
        used = subprocess.run(
            [python, '-c', 'import setuptools; print(setuptools.__version__)'],
            check=True, capture_output=True, text=True, timeout=60, env=clean_environment(),
        ).stdout.strip()  # fmt: skip
        assert used == SYSTEM_SETUPTOOLS[setuptools]
    workspace = tmp_path / 'ws'
    (workspace / 'src').mkdir(parents=True)
    (workspace / 'src' / 'scanfuse').symlink_to(ROOT, target_is_directory=True)
    colcon_folders = ('build', 'install', 'log')
    already = {name for name in colcon_folders if (ROOT / name).exists()}
    build = subprocess.run(
        [python, '-c', COLCON, '--log-base', str(workspace / 'log'), 'build', *options],
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


def test_pip_builds_a_wheel_from_pyproject_alone(tmp_path):
    # `pip install .`: pyproject.toml (setuptools >= 77) without colcon's additions. Built from
    # a copy of the tracked files so the build folders land outside the repository.
    tracked = (
        subprocess.run(
            ['git', 'ls-files', '-z'], cwd=ROOT, capture_output=True, check=True, timeout=60
        )
        .stdout.decode()
        .split('\0')
    )
    source = tmp_path / 'source'
    for name in filter(None, tracked):
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    environment = {key: value for key, value in clean_environment().items() if key != 'COLCON'}
    built = subprocess.run(
        [sys.executable, '-m', 'pip', 'wheel', '--no-deps', '--no-build-isolation', '-q',
         '-w', str(tmp_path / 'dist'), str(source)],
        env=environment, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (tmp_path / 'dist').glob('scanfuse-*.whl')
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        info = next(name for name in names if name.endswith('.dist-info/METADATA'))
        metadata = archive.read(info).decode()
        entry_points = archive.read(info.replace('METADATA', 'entry_points.txt')).decode()
    assert 'scanfuse/py.typed' in names
    assert 'License-Expression: Apache-2.0' in metadata
    assert 'scanfuse = scanfuse.__main__:main' in entry_points
    # The ROS executable and data files are colcon's business only.
    assert 'scanfuse_node' not in entry_points
    assert not any(name.endswith('scanfuse.launch.py') for name in names)
