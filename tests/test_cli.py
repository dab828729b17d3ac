"""The `scanfuse` entry point: exit codes and one clean line for known errors."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import logging
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from scanfuse.cli import main
from scanfuse.ros.bag import fuse_bag
from tests.support import REPOSITORY
from tests.support.synthetic import Scene, write_scene_bag

SRC = REPOSITORY / 'src'
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


# A `scanfuse bag` run that says when it is fusing and then waits on its stdin, so a test
# can signal it mid-run without guessing at timing; the signal ends the wait.
BLOCKING_BAG = """
import sys
import scanfuse.progress as progress
from scanfuse.cli import main

class Blocking(progress.NullProgress):
    def __init__(self, *args, **kwargs):
        self.seen = 0

    def advance(self, count=1):
        self.seen += count
        if self.seen == 10:
            print('fusing', flush=True)
            sys.stdin.readline()

progress.RichProgress = Blocking
raise SystemExit(main(sys.argv[1:]))
"""


def start_blocked_bag(source: Path, output: Path) -> subprocess.Popen[str]:
    child = subprocess.Popen(
        [sys.executable, '-c', BLOCKING_BAG, 'bag', str(source), str(output)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    assert line == 'fusing\n', child.communicate(timeout=60)
    return child


def staging_folders(folder: Path, name: str) -> list[Path]:
    return sorted(folder.glob(f'.{name}.*.partial'))


def test_sigterm_while_fusing_removes_the_staging_folder(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=1.0))
    child = start_blocked_bag(source, tmp_path / 'out')
    (staging,) = staging_folders(tmp_path, 'out')
    assert (staging / 'out' / 'out.mcap').is_file()  # the half-written bag
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 128 + signal.SIGTERM
    assert 'terminated' in err
    assert 'Traceback' not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in']


def test_staging_left_by_a_killed_run_is_removed_by_the_next_run(tmp_path, caplog):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=1.0))
    child = start_blocked_bag(source, tmp_path / 'out')
    (staging,) = staging_folders(tmp_path, 'out')
    # While that run lives, its lock keeps another run from sweeping its folder.
    fuse_bag(source, tmp_path / 'second')
    assert staging.is_dir()
    child.kill()  # SIGKILL: no handler runs, the folder stays
    child.communicate(timeout=60)
    assert staging.is_dir()
    with caplog.at_level(logging.INFO, logger='scanfuse.ros.staging'):
        fuse_bag(source, tmp_path / 'third')
    assert not staging.exists()
    assert f'removed {staging} (' in caplog.text
    assert 'left by an interrupted scanfuse run' in caplog.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in', 'second', 'third']


def private_tmpfs(tmp_path: Path, options: str, command: list[str]) -> subprocess.CompletedProcess:
    """Run `command` with a fresh tmpfs (mount `options`) at tmp_path/'mnt', in a private
    user and mount namespace (nothing is mounted for the rest of the machine); stdout ends
    with 'left: ' and what the tmpfs holds when the command is done."""
    if shutil.which('unshare') is None:
        pytest.skip('unshare (util-linux) is not installed')
    mount = tmp_path / 'mnt'
    mount.mkdir()
    probe = subprocess.run(
        ['unshare', '--user', '--map-root-user', '--mount', 'mount', '-t', 'tmpfs', 'x', mount],
        capture_output=True,
        check=False,
    )
    if probe.returncode != 0:
        pytest.skip(f'no private mount namespace here: {probe.stderr.decode().strip()}')
    script = (
        'mount -t tmpfs -o "$1" scanfuse-test "$0" || exit 99; shift; "$@"; code=$?; '
        'echo "left: $(ls -A "$0")"; exit $code'
    )
    return subprocess.run(
        [
            'unshare',
            '--user',
            '--map-root-user',
            '--mount',
            'sh',
            '-c',
            script,
            mount,
            options,
            *command,
        ],
        capture_output=True,
        text=True,
        check=False,
    )


def bag_command(*args: object) -> list[str]:
    return [sys.executable, '-m', 'scanfuse.cli', 'bag', *map(str, args)]


@pytest.mark.parametrize(
    ('storage', 'problem'),
    [
        ('mcap', 'No space left on device; the disk is full; free space or write somewhere else'),
        ('sqlite3', 'sqlite3: database or disk is full; free space or write somewhere else'),
    ],
)
def test_disk_full_is_one_line(tmp_path, storage, problem):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=1.0))  # about 1.2 MB
    out = tmp_path / 'mnt' / 'out'
    done = private_tmpfs(tmp_path, 'size=256k', bag_command(source, out, '--storage', storage))
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip() == f'error: cannot write the output {out}: {problem}'
    assert done.stdout.endswith('left: \n')  # no staging folder left on the full disk


def test_read_only_output_is_one_line(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    out = tmp_path / 'mnt' / 'out'
    done = private_tmpfs(tmp_path, 'ro', bag_command(source, out))
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip() == (
        f'error: cannot write the output {out}: Read-only file system; '
        'the filesystem is read-only; write somewhere else'
    )


def test_file_size_limit_is_one_line(tmp_path):
    """RLIMIT_FSIZE (ulimit -f) with SIGXFSZ ignored: write(2) fails with EFBIG (POSIX)."""
    source = write_scene_bag(tmp_path / 'in', Scene(duration=1.0))
    script = (
        'import resource, signal, sys\n'
        'signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n'
        'resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))\n'
        'from scanfuse.cli import main\n'
        'raise SystemExit(main(sys.argv[1:]))\n'
    )
    out = tmp_path / 'out'
    done = subprocess.run(
        [sys.executable, '-c', script, 'bag', str(source), str(out)],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, 'PYTHONDONTWRITEBYTECODE': '1'},
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip() == (
        f'error: cannot write the output {out}: File too large; a file grew past the size '
        "this system allows (ulimit -f, or the filesystem's file size limit); "
        'write somewhere else'
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in']


def test_config_error_from_the_params_file_is_one_line(tmp_path, capsys):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    params = tmp_path / 'params.yaml'
    params.write_text('scanfuse:\n  ros__parameters:\n    no_such_parameter: 1\n')
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: ')
    assert 'no_such_parameter' in err
    assert len(err.strip().splitlines()) == 1


# `scanfuse simulate` whose drive says when the recording is under way, then waits on stdin.
BLOCKING_SIMULATE = """
import sys
import scanfuse.sim.cli as sim_cli
from scanfuse.cli import main
from tests.support import REPOSITORY

scripted = sim_cli.scripted_path

def blocking_path(name):
    drive = scripted(name)
    calls = 0

    def controller(observation):
        nonlocal calls
        calls += 1
        if calls == 5:
            print('recording', flush=True)
            sys.stdin.readline()
        return drive(observation)

    return controller

sim_cli.scripted_path = blocking_path
raise SystemExit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize('name', ['run.mcap', 'run'])
def test_sigterm_while_simulating_leaves_nothing(tmp_path, name):
    pytest.importorskip('mujoco')
    out = tmp_path / name
    argv = ['simulate', '--world', 'room', '--depth-backend', 'multiray', '--resolution', '256x144',
            '--duration', '30', '--out', str(out)]  # fmt: skip
    child = subprocess.Popen(
        [sys.executable, '-c', BLOCKING_SIMULATE, *argv],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    assert line == 'recording\n', child.communicate(timeout=60)
    (staging,) = staging_folders(tmp_path, name)
    assert (staging / name / f'{name}.mcap').is_file()
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 128 + signal.SIGTERM, err
    assert 'Traceback' not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.ros
@pytest.mark.parametrize(
    ('ros_args', 'problem'),
    [
        # Ranges and types are the descriptors' (scanfuse.ros.params); rclpy checks overrides.
        (['-p', 'max_time_offset:=11.0'], r'max_time_offset out of range .*; fix the -p override'),
        (['-p', 'obstacle_min_points:=abc'], r"expecting type 'INTEGER'.*; fix the -p override"),
        (['-p', 'scan_topic:=bad topic'], r"Invalid topic name: .*'bad topic'; fix the topic"),
        (['-r', '__node:=bad.name'], r"Couldn't parse remap rule: '-r __node:=bad.name'.*; ROS"),
    ],
)
def test_node_start_up_errors_are_one_line(ros_args, problem):
    pytest.importorskip('rclpy')
    env = {
        **os.environ,
        'ROS_DOMAIN_ID': str(220 + os.getpid() % 10),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
    }
    command = [sys.executable, '-m', 'scanfuse.cli', 'node', '--ros-args', *ros_args]
    child = subprocess.Popen(command, env=env, stderr=subprocess.PIPE, text=True)
    try:
        _, err = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 1, err
    assert 'Traceback' not in err
    (line,) = [line for line in err.splitlines() if line.startswith('scanfuse node: ')]
    assert re.search(problem, line), line


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


def write_params(path: Path, **values: object) -> Path:
    import yaml

    path.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}), encoding='utf-8')
    return path


def test_bag_takes_the_depth_topic_the_parameter_file_names(tmp_path, capsys):
    # The scene's depth topic is /camera/depth/image_raw (tests/support/synthetic.py); a file
    # for a RealSense names another, as the node would subscribe to it.
    bag = write_scene_bag(tmp_path / 'scene.mcap', Scene(duration=0.5))
    realsense = write_params(
        tmp_path / 'realsense.yaml', depth_topic='/camera/camera/depth/image_rect_raw'
    )
    assert main(['bag', str(bag), str(tmp_path / 'out'), '--params', str(realsense)]) == 1
    line = ' '.join(capsys.readouterr().err.split())
    assert 'depth topic /camera/camera/depth/image_rect_raw is not in the bag' in line
    assert f'[depth_topic in {realsense} (--depth overrides it)]' in line
    # --depth overrides the file, as -r remaps the node's topic.
    args = ['--params', str(realsense), '--depth', '/camera/depth/image_raw']
    assert main(['bag', str(bag), str(tmp_path / 'out'), *args]) == 0


def test_an_angle_in_degrees_is_refused_with_its_value_in_radians(tmp_path, capsys):
    pitched = write_params(tmp_path / 'pitch.yaml', camera_pitch=20)
    assert (
        main(['bag', str(tmp_path / 'any.mcap'), str(tmp_path / 'out'), '--params', str(pitched)])
        == 1
    )
    line = ' '.join(capsys.readouterr().err.split())
    assert f'(radians: 20 deg = {math.radians(20):.3f})' in line
    assert '(radians: 20 deg = 0.349)' in line


def test_a_misspelled_parameter_in_a_file_names_the_nearest_one(tmp_path, capsys):
    typo = write_params(tmp_path / 'typo.yaml', min_obstacle_heigth=0.08)
    assert (
        main(['bag', str(tmp_path / 'any.mcap'), str(tmp_path / 'out'), '--params', str(typo)]) == 1
    )
    line = ' '.join(capsys.readouterr().err.split())
    assert (
        'min_obstacle_heigth: Extra inputs are not permitted (did you mean min_obstacle_height?)'
        in line
    )


def fused_scans(bag: Path) -> dict[int, bytes]:
    from rosbags.highlevel import AnyReader

    from scanfuse.ros.messages import scan_from_cdr

    with AnyReader([bag]) as reader:
        wanted = [c for c in reader.connections if c.topic == '/scan_fused']
        return {scan_from_cdr(raw).stamp_ns: bytes(raw) for _, _, raw in reader.messages(wanted)}


def test_a_bag_without_camera_info_fuses_with_the_intrinsics_given(tmp_path, capsys):
    from tests.support.synthetic import scene_messages, write_bag

    scene = Scene(duration=1.0)
    everything = scene_messages(scene)
    without_info = write_bag(
        tmp_path / 'no_info.mcap',
        [message for message in everything if message[0] != '/camera/depth/camera_info'],
    )
    assert main(['bag', str(without_info), str(tmp_path / 'refused')]) == 1
    assert '--intrinsics FX FY CX CY' in ' '.join(capsys.readouterr().err.split())
    # The scene's camera (tests/support/synthetic.py): its CameraInfo's K, typed in.
    camera = scene.camera
    given = [str(value) for value in (camera.fx, camera.fy, camera.cx, camera.cy)]
    out = tmp_path / 'given'
    assert (
        main(['bag', str(without_info), str(out), '--intrinsics', *given, '--no-depth-scan']) == 0
    )
    with_info = write_bag(tmp_path / 'with_info.mcap', everything)
    assert main(['bag', str(with_info), str(tmp_path / 'from_info'), '--no-depth-scan']) == 0
    expected = fused_scans(tmp_path / 'from_info')
    assert expected
    assert fused_scans(out) == expected


def test_node_help_lists_the_foxglove_options(capsys):
    from scanfuse.ros.live_view import DEFAULT_HOST, DEFAULT_PORT

    assert main(['node', '--help']) == 0
    text = ' '.join(capsys.readouterr().out.split())
    assert f'--foxglove [PORT]: serve a Foxglove live view on PORT (default {DEFAULT_PORT};' in text
    assert f'--foxglove-host HOST: the address it listens on (default {DEFAULT_HOST}:' in text


def test_a_bag_report_prints_as_a_table_within_80_columns(tmp_path):
    bag = write_scene_bag(tmp_path / 'scene.mcap', Scene(duration=0.5))
    report = fuse_bag(bag, tmp_path / 'out')
    text = str(report.table())
    assert 'scanfuse bag:' in text
    assert 'object at 0x' not in text
    assert max(len(line) for line in text.splitlines()) <= 80
    # A long path wraps inside its cell instead of being cut off.
    assert '...' not in text
    assert '\u2026' not in text
    assert 'messages read' in text


def test_a_simulated_bag_does_not_suggest_fusing_its_ground_truth(tmp_path):
    from tests.support.synthetic import scene_messages, write_bag

    # The simulator writes the ground-truth scan beside the LiDAR's (/scan -> /scan_truth).
    messages = scene_messages(Scene(duration=0.5))
    truth = [('/scan_truth', kind, t, raw) for topic, kind, t, raw in messages if topic == '/scan']
    bag = write_bag(tmp_path / 'sim.mcap', [*messages, *truth])
    report = fuse_bag(bag, tmp_path / 'out')
    assert report.topics.unused == ()
    assert 'scan_truth' not in str(report.table())


def test_one_parameter_file_names_the_topics_for_simulate_and_bag(tmp_path):
    from rosbags.highlevel import AnyReader

    realsense = write_params(
        tmp_path / 'robot.yaml',
        scan_topic='/rplidar/scan',
        depth_topic='/camera/camera/depth/image_rect_raw',
        camera_info_topic='/camera/camera/depth/camera_info',
    )
    recording = tmp_path / 'drive.mcap'
    simulate = ['simulate', '--out', str(recording), '--duration', '1', '--params', str(realsense)]
    assert main([*simulate, '--resolution', '424x240', '--depth-backend', 'multiray']) == 0
    with AnyReader([recording]) as reader:
        topics = set(reader.topics)
    assert {
        '/rplidar/scan',
        '/camera/camera/depth/image_rect_raw',
        '/camera/camera/depth/camera_info',
    } <= topics
    assert '/camera/depth/image_raw' not in topics
    fused = tmp_path / 'fused'
    assert main(['bag', str(recording), str(fused), '--params', str(realsense)]) == 0
    assert fused_scans(fused)
