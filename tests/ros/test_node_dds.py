"""The node over real DDS on loopback: a player, the node and a recorder, each its own process.

Every test runs in its own ROS_DOMAIN_ID with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
Discovery takes 0.4 to 4 s here, so processes wait for each other (subscription
counts, a ready file) with generous timeouts instead of fixed sleeps. The scene
is that of tests/test_node.py: straight ahead the box at 1.2 m (fused) behind
which the LiDAR sees the wall at 2.0 m.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from scanfuse.config import FusionConfig
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.messages import scan_from_cdr, typestore
from tests.support import with_repository_on_path
from tests.support.synthetic import Scene, write_scene_bag

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros

PY = sys.executable
BOX, WALL, TOLERANCE = 1.2, 2.0, 0.02
START_TIMEOUT = 60.0
_counter = itertools.count()

# The scene's mounting, as parameters (the node's TF path needs tf2_msgs).
SCENE_PARAMS = {
    'camera_x': 0.1,
    'camera_height': 0.45,
    'camera_pitch': math.radians(20.0),
    'lidar_height': 0.3,
}


def domain_id() -> int:
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw')
    worker_index = int(worker) if worker.isdigit() else 0
    return 120 + (worker_index * 20 + next(_counter) + os.getpid() % 7 * 3) % 100


class Loopback:
    """Processes of one test, all in one isolated DDS domain."""

    def __init__(self, tmp_path, node_params: dict):
        self.tmp = tmp_path
        self.env = with_repository_on_path(
            {
                **os.environ,
                'ROS_DOMAIN_ID': str(domain_id()),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
            }
        )
        self.processes: list[subprocess.Popen] = []
        ros_args = []
        for name, value in node_params.items():
            ros_args += ['-p', f'{name}:={value}']
        self.node = self.start('node', '-m', 'scanfuse.ros.node', '--ros-args', *ros_args)

    def start(self, name: str, *args: str) -> subprocess.Popen:
        log = (self.tmp / f'{name}.log').open('w')
        process = subprocess.Popen(
            [PY, *args], env=self.env, stdout=log, stderr=subprocess.STDOUT, cwd=self.tmp
        )
        self.processes.append(process)
        return process

    def loopback(self, name: str, *args: str) -> subprocess.Popen:
        return self.start(name, '-m', 'tests.support.loopback', *args)

    def record(self, *topics: str, drain_until_level: int | None = None) -> None:
        args = [] if drain_until_level is None else ['--drain-until-level', str(drain_until_level)]
        for topic in topics:
            args += ['--topic', topic]
        self.recorder = self.loopback(
            'recorder',
            'record',
            str(self.tmp / 'received'),
            *args,
            '--duration',
            '120',
            '--ready',
            str(self.tmp / 'ready'),
            '--stop',
            str(self.tmp / 'stop'),
            '--expect-publisher',
        )
        deadline = time.monotonic() + START_TIMEOUT
        while not (self.tmp / 'ready').exists():
            assert self.recorder.poll() is None, self.log('recorder')
            assert self.node.poll() is None, self.log('node')
            assert time.monotonic() < deadline, 'recorder did not see the node in time'
            time.sleep(0.05)

    def play(self, bag, *extra: str) -> subprocess.Popen:
        return self.loopback(
            'player',
            'play',
            str(bag),
            '--wait-for',
            '/scan',
            '--wait-for',
            '/camera/depth/image_raw',
            *extra,
        )

    def received(self, linger: float = 1.0) -> dict[str, list[tuple[float, bytes]]]:
        """Stop the recorder `linger` s from now; (receive time s, CDR) per topic."""
        time.sleep(linger)
        (self.tmp / 'stop').write_text('stop')
        assert self.recorder.wait(timeout=30) == 0, self.log('recorder')
        out: dict[str, list[tuple[float, bytes]]] = {}
        with AnyReader([self.tmp / 'received']) as reader:
            for connection, log_time, raw in reader.messages():
                out.setdefault(connection.topic, []).append((log_time / 1e9, bytes(raw)))
        return out

    def log(self, name: str) -> str:
        return (self.tmp / f'{name}.log').read_text(encoding='utf-8', errors='replace')

    def close(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.terminate()
        for process in self.processes:
            stop(process)


def stop(process: subprocess.Popen) -> None:
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()


@pytest.fixture
def loopback_factory(tmp_path):
    made = []

    def make(**params):
        made.append(Loopback(tmp_path, params))
        return made[-1]

    yield make
    for item in made:
        item.close()


def ahead(scan) -> float:
    index = round(-scan.angle_min / scan.angle_increment)
    return float(np.nanmin(scan.ranges[index - 1 : index + 2]))


def test_node_publishes_what_the_bag_processor_writes(tmp_path, loopback_factory):
    scene = Scene(duration=2.0)
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    config = FusionConfig(use_tf=False, **SCENE_PARAMS)
    fuse_bag(bag, tmp_path / 'offline', config=config)
    with AnyReader([tmp_path / 'offline']) as reader:
        wanted = [c for c in reader.connections if c.topic in {'/scan_fused', '/scan'}]
        offline: dict[str, dict[int, bytes]] = {'/scan_fused': {}, '/scan': {}}
        for connection, _, raw in reader.messages(connections=wanted):
            offline[connection.topic][scan_from_cdr(raw).stamp_ns] = bytes(raw)

    loop = loopback_factory(use_tf=False, pair_wait=0.1, **SCENE_PARAMS)
    loop.record('/scan_fused')
    assert loop.play(bag).wait(timeout=60) == 0, loop.log('player')
    received = loop.received()['/scan_fused']
    # The first scans may pass while the node still waits for the first CameraInfo.
    later = {
        scan_from_cdr(raw).stamp_ns: raw
        for _, raw in received
        if scan_from_cdr(raw).stamp_ns >= scene.start_ns + 0.15e9
    }
    expected = [stamp for stamp in offline['/scan_fused'] if stamp >= scene.start_ns + 0.15e9]
    assert len(later) >= 0.8 * len(expected), loop.log('node')  # best effort may drop a few
    for stamp, raw in later.items():
        assert raw == offline['/scan_fused'][stamp]
        fused = scan_from_cdr(raw)
        assert ahead(fused) == pytest.approx(BOX, abs=TOLERANCE)
        lidar = scan_from_cdr(offline['/scan'][stamp]).ranges
        finite = np.isfinite(lidar)
        assert np.all(fused.ranges[finite] <= lidar[finite])


def test_camera_dropout_malformed_images_and_lidar_loss(tmp_path, loopback_factory):
    scene = Scene(duration=3.0, depth_gap=(1.0, 2.0))
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    loop = loopback_factory(use_tf=False, camera_timeout=0.3, lidar_timeout=0.5, **SCENE_PARAMS)
    # The recorder stops at the node's first ERROR report after the replay (LiDAR silent),
    # however long the node's 1 s report timer and lidar_timeout take under load.
    loop.record('/scan_fused', '/diagnostics', drain_until_level=2)
    assert loop.play(bag, '--garbage-at', '0.5').wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=0.0)
    assert loop.node.poll() is None, loop.log('node')  # survived the malformed images
    start = scene.start_ns
    last_before = max(s for s in scene.depth_stamps() if s < start + 1e9)
    first_after = min(s for s in scene.depth_stamps() if s >= start + 2e9)
    period = 1e9 / scene.scan_hz
    through = fused_after = 0
    for _, raw in received['/scan_fused']:
        scan = scan_from_cdr(raw)
        # Silent > camera_timeout (+ the camera's 30 ms delivery delay) + one scan period.
        if last_before + 0.33e9 + period < scan.stamp_ns < start + 2e9:
            assert ahead(scan) == pytest.approx(WALL, abs=TOLERANCE)  # the LiDAR alone
            through += 1
        # Back within one scan period of the camera's return.
        if scan.stamp_ns > first_after + period:
            assert ahead(scan) == pytest.approx(BOX, abs=TOLERANCE)
            fused_after += 1
    assert through >= 2
    assert fused_after >= 5
    store = typestore()
    statuses = [
        store.deserialize_cdr(raw, 'diagnostic_msgs/msg/DiagnosticArray').status[0]
        for _, raw in received['/diagnostics']
    ]
    levels = [int(status.level) for status in statuses]
    assert 1 in levels  # WARN while the camera was silent
    assert levels[-1] == 2  # ERROR once the LiDAR stopped
    last_values = {kv.key: kv.value for kv in statuses[-1].values}
    assert int(last_values['malformed depth image']) >= 1


def test_parameter_changes_at_run_time(tmp_path, loopback_factory):
    scene = Scene(duration=5.0)
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    loop = loopback_factory(use_tf=False, **SCENE_PARAMS)
    go = tmp_path / 'started'
    setter = loop.loopback(
        'setter',
        'set-param',
        'min_obstacle_height',
        '0.25',
        '--out',
        str(tmp_path / 'set.json'),
        '--go',
        str(go),
        '--after',
        '2.0',
    )
    refused = loop.loopback(
        'refused',
        'set-param',
        'scan_topic',
        '/other',
        '--out',
        str(tmp_path / 'refused.json'),
        '--go',
        str(go),
    )
    loop.record('/scan_fused')
    player = loop.play(bag, '--started', str(go))
    assert setter.wait(timeout=60) == 0, loop.log('setter')
    assert refused.wait(timeout=60) == 0, loop.log('refused')
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received()['/scan_fused']
    result = json.loads((tmp_path / 'set.json').read_text())
    assert result['successful'], result
    rejection = json.loads((tmp_path / 'refused.json').read_text())
    assert not rejection['successful']
    assert 'can only be set at start-up' in rejection['reason']
    before = [ahead(scan_from_cdr(raw)) for t, raw in received if result['sent'] - t > 0.3]
    after = [ahead(scan_from_cdr(raw)) for t, raw in received if t > result['done'] + 0.15]
    assert before
    assert after, 'the replay ended before the parameter was set'
    assert before[-1] == pytest.approx(BOX, abs=TOLERANCE)
    assert all(value == pytest.approx(WALL, abs=TOLERANCE) for value in after)


def test_incompatible_qos_is_reported_for_inputs_by_the_node_and_for_outputs_by_the_peer(
    tmp_path, loopback_factory
):
    """The node warns of an input publisher it cannot hear (rclpy's default handler on its
    subscriptions); of a subscriber its outputs cannot reach, that subscriber's own node is
    told (the node's publishers carry no event handlers: issue 12, CPU)."""
    pytest.importorskip('tf2_msgs.msg')
    loop = loopback_factory(**SCENE_PARAMS)
    result = tmp_path / 'probe.json'
    probe = loop.loopback('probe', 'qos-probe', '--out', str(result))
    warning = "New publisher discovered on topic '/tf_static', offering incompatible QoS"
    deadline = time.monotonic() + START_TIMEOUT
    while warning not in loop.log('node'):
        assert loop.node.poll() is None, loop.log('node')
        assert time.monotonic() < deadline, loop.log('node')
        time.sleep(0.05)
    assert 'RELIABILITY' in loop.log('node').split(warning, 1)[1].splitlines()[0]
    deadline = time.monotonic() + START_TIMEOUT
    while not result.exists():
        assert probe.poll() is None, loop.log('probe')
        assert time.monotonic() < deadline, loop.log('probe')
        time.sleep(0.05)
    assert json.loads(result.read_text())['scan_fused_policy'] == 'DURABILITY'


def test_a_second_lidar_reading_reaches_scan_fused(tmp_path, loopback_factory):
    from tests.support.synthetic import REAR_TOPIC, two_lidar_messages, write_bag

    scene = Scene(duration=2.0)
    back_wall = 1.5
    bag = write_bag(tmp_path / 'in.mcap', two_lidar_messages(scene, back_wall=back_wall))
    sources = {
        'lidars': '[front, rear]',
        'front.topic': '/scan',
        'front.z': 0.3,
        'rear.topic': REAR_TOPIC,
        'rear.z': 0.3,
        'rear.yaw': math.pi,
    }
    loop = loopback_factory(use_tf=False, pair_wait=0.1, **SCENE_PARAMS, **sources)
    loop.record('/scan_fused', '/diagnostics')
    assert loop.play(bag, '--wait-for', REAR_TOPIC).wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    half = scene.angle_increment / 2
    checked = lacking = 0
    rear_heard = False
    for _, raw in received['/scan_fused']:
        scan = scan_from_cdr(raw)
        if scan.stamp_ns < scene.start_ns + 0.15e9:
            continue  # before the first CameraInfo and rear scan
        b = scan.angle_min + scan.angle_increment * np.arange(len(scan.ranges))
        # Only the rear LiDAR (yaw pi) sees behind the side: the back wall at x = -1.5 m,
        # r = 1.5 / |cos| of a bearing within half a slot of the slot's (see test_node_sources).
        behind = (np.abs(b) >= 0.6 * math.pi) & (np.abs(b) <= 0.74 * math.pi)
        # The player waits until it has matched the node's subscriptions, but the node's
        # side may match the rear publisher a little later and lose its first (best-effort)
        # scans (1 run in 6 did), and on a loaded host best effort may lose one later. A scan
        # fused without the rear's message has none of its readings, and the node counts it
        # missing (checked below): a lost message, told from a wrong fusion.
        heard_now = bool(np.isfinite(scan.ranges[behind]).any())
        rear_heard = rear_heard or heard_now
        if not rear_heard:
            continue
        assert ahead(scan) == pytest.approx(BOX, abs=TOLERANCE)
        if not heard_now:
            lacking += 1
            continue
        near = back_wall / np.abs(np.cos(np.abs(b[behind]) + half))
        far = back_wall / np.abs(np.cos(np.abs(b[behind]) - half))
        assert np.all((scan.ranges[behind] >= near - 1e-3) & (scan.ranges[behind] <= far + 1e-3))
        checked += 1
    assert checked >= 0.8 * (len(scene.scan_stamps()) - 2), loop.log('node')
    store = typestore()
    last = store.deserialize_cdr(
        received['/diagnostics'][-1][1], 'diagnostic_msgs/msg/DiagnosticArray'
    )
    values = {kv.key: kv.value for kv in last.status[0].values}
    used, missing = (int(n) for n in re.findall(r'(?:used|missing) (\d+)', values['source rear']))
    assert used >= checked
    assert missing >= lacking, (lacking, values['source rear'])


def _rss_kib(pid: int, field: str) -> int:
    for line in Path(f'/proc/{pid}/status').read_text(encoding='utf-8').splitlines():
        if line.startswith(f'{field}:'):
            return int(line.split()[1])
    raise AssertionError(field)


# What a malformed flood may add to the node's resident memory at its peak (VmHWM) over
# what it holds once up: the obstacle tables of one camera (~9 MB), a few buffered frames
# and allocator slack; a leak of even 1 KiB per message would pass it within the flood.
SOAK_RSS_BOUND_MIB = 64


def test_soak_malformed_flood_then_valid_traffic(tmp_path, loopback_factory):
    scene = Scene(duration=2.0)
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    loop = loopback_factory(use_tf=False, **SCENE_PARAMS)
    loop.record('/scan_fused', '/diagnostics')
    baseline = _rss_kib(loop.node.pid, 'VmRSS')
    flood = loop.loopback('flood', 'flood', '--seconds', '8')
    assert flood.wait(timeout=60) == 0, loop.log('flood')
    assert loop.node.poll() is None, loop.log('node')
    assert loop.play(bag).wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    assert loop.node.poll() is None, loop.log('node')
    peak = _rss_kib(loop.node.pid, 'VmHWM')
    sent = int(loop.log('flood').rsplit('flood: ', 1)[1].split()[0])
    assert sent > 10_000
    fused = [
        scan_from_cdr(raw)
        for _, raw in received['/scan_fused']
        if scan_from_cdr(raw).stamp_ns >= scene.start_ns + 0.15e9
    ]
    # Output resumes: the valid replay's scans come back fused with the box ahead.
    assert len([s for s in fused if ahead(s) == pytest.approx(BOX, abs=TOLERANCE)]) >= 10
    assert (peak - baseline) / 1024 <= SOAK_RSS_BOUND_MIB, (baseline, peak)
    store = typestore()
    last = store.deserialize_cdr(
        received['/diagnostics'][-1][1], 'diagnostic_msgs/msg/DiagnosticArray'
    )
    values = {kv.key: kv.value for kv in last.status[0].values}
    assert int(values['malformed depth image']) >= 1
    assert int(values['malformed scan']) >= 1
    assert int(values['malformed camera info']) >= 1
