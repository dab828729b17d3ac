"""The `scanfuse` entry point: exit codes and one clean line for known errors."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from scanfuse.cli import main

SRC = Path(__file__).resolve().parent.parent / 'src'
# The CLI under `python -S` (no site-packages) with one site directory added by hand: the
# same interpreter, but only the packages that directory holds are importable.
RUN_IN_SITE = (
    'import os, site, sys\n'
    "sys.path.insert(0, os.environ['SCANFUSE_SRC'])\n"
    "site.addsitedir(os.environ['SCANFUSE_SITE'])\n"
    'from scanfuse.cli import main\n'
    'raise SystemExit(main(sys.argv[1:]))\n'
)
needs_rclpy = pytest.mark.skipif(
    importlib.util.find_spec('rclpy') is None,
    reason="needs the ROS 2 wheels to leave some out: pip install -e '.[ros]' (make test)",
)


def test_help_exits_zero(capsys):
    assert main(['--help']) == 0
    assert 'bag' in capsys.readouterr().out


def test_usage_error_exits_two():
    assert main(['bag']) == 2


def test_known_error_is_one_line_and_exit_one(tmp_path, capsys):
    assert main(['bag', str(tmp_path / 'missing'), str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert 'does not exist' in err
    assert 'Traceback' not in err


def test_missing_simulator_names_the_extra(tmp_path):
    # `None` in sys.modules makes `import mujoco` fail as if it were not installed.
    script = (
        'import sys\n'
        'sys.modules["mujoco"] = None\n'
        'from scanfuse.cli import main\n'
        f'raise SystemExit(main(["simulate", "--depth-backend", "multiray", "--out", '
        f'"{tmp_path / "run.mcap"}"]))\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=False
    )
    assert done.returncode == 1
    assert "pip install 'scanfuse[sim]'" in done.stderr


def site_packages() -> Path:
    return Path(sysconfig.get_paths()['purelib'])


def ros_wheel_entries(*names: str) -> set[str]:
    """Top-level entries of site-packages installed by the named (or all `ros-*`) wheels."""
    entries: set[str] = set()
    for dist in importlib.metadata.distributions(path=[str(site_packages())]):
        name = dist.metadata['Name'].lower()
        if name in names or (not names and name.startswith('ros-')):
            entries.update(f.parts[0] for f in dist.files or [] if f.parts[0] != '..')
    return entries


def site_without(tmp_path: Path, dropped: set[str]) -> Path:
    """This environment's site-packages as it would be with some packages uninstalled.

    A folder of symlinks to every top-level entry but the dropped ones (and the editable
    install's .pth: the child puts this checkout's src/ first on its path itself).
    """
    site = tmp_path / 'site-packages'
    site.mkdir(parents=True)
    for entry in site_packages().iterdir():
        if entry.name not in dropped and not entry.name.startswith('__editable__'):
            (site / entry.name).symlink_to(entry)
    return site


def run_cli(site: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {key: value for key, value in os.environ.items() if key != 'PYTHONPATH'}
    env |= {'SCANFUSE_SRC': str(SRC), 'SCANFUSE_SITE': str(site)}
    return subprocess.run(
        [sys.executable, '-S', '-c', RUN_IN_SITE, *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def lines_with(text: str, needle: str) -> list[str]:
    return [line for line in text.splitlines() if needle in line]


def test_node_without_ros_says_what_is_missing_and_the_two_ways(tmp_path):
    # As after `pip install .` without the ros extra: no ROS wheel, no tf2_msgs.
    dropped = ros_wheel_entries() | {'tf2_msgs'}
    done = run_cli(site_without(tmp_path, dropped), 'node')
    assert done.returncode == 1
    assert 'Traceback' not in done.stderr
    (line,) = lines_with(done.stderr, 'is not installed')
    assert line.startswith('error: rclpy is not installed;')
    assert "pip install 'scanfuse[ros]'" in line
    assert "'scanfuse[ros-kilted]'" in line
    assert 'source a ROS 2 install' in line


@needs_rclpy
def test_node_without_the_message_packages_names_the_missing_one(tmp_path):
    # rclpy is there; the node's first message import is diagnostic_msgs.
    dropped = ros_wheel_entries('ros-diagnostic-msgs', 'ros-sensor-msgs')
    assert 'diagnostic_msgs' in dropped
    done = run_cli(site_without(tmp_path, dropped), 'node')
    assert done.returncode == 1
    assert 'Traceback' not in done.stderr
    (line,) = lines_with(done.stderr, 'is not installed')
    assert line.startswith('error: diagnostic_msgs is not installed;')
    assert "pip install 'scanfuse[ros]'" in line
    assert 'source a ROS 2 install' in line


@needs_rclpy
def test_node_without_tf2_msgs_warns_in_one_line_and_goes_on(tmp_path):
    # A parameter file that does not exist stops the node after the warning, before DDS.
    missing = str(tmp_path / 'missing.yaml')
    done = run_cli(site_without(tmp_path, {'tf2_msgs'}), 'node', '--params-file', missing)
    assert done.returncode == 1
    (warning,) = lines_with(done.stderr, 'tf2_msgs is not installed')
    assert warning.startswith('warning: tf2_msgs is not installed,')
    assert 'sourced ROS 2 install' in warning
    assert "pip install -e '.[rosbuild]' && python tools/build_tf2_msgs.py" in warning
    # The node went on to read the parameter file.
    assert lines_with(done.stderr, 'missing.yaml')
    if importlib.util.find_spec('tf2_msgs') is not None:
        with_tf2 = run_cli(site_without(tmp_path / 'all', set()), 'node', '--params-file', missing)
        assert with_tf2.returncode == 1
        assert not lines_with(with_tf2.stderr, 'tf2_msgs is not installed')
