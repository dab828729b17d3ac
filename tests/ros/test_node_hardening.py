"""Regression tests of issue 26 through the node over DDS (see tests/ros/test_node_dds.py for
how the processes find each other)."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from scanfuse.motion import PlanarPose
from scanfuse.ros.messages import (
    ODOMETRY,
    OdometrySample,
    odometry_to_cdr,
    scan_from_cdr,
    typestore,
)
from tests.ros.test_node_dds import (
    BOX,
    SCENE_PARAMS,
    SOAK_RSS_BOUND_MIB,
    TOLERANCE,
    Loopback,
    _rss_kib,
    ahead,
)
from tests.support.synthetic import (
    REAR_TOPIC,
    Scene,
    two_lidar_messages,
    write_bag,
    write_scene_bag,
)

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros


# Scene time the node may pass scans through at start-up: until the first CameraInfo and
# depth frame, and while it builds that camera's tables and the floor's sample (issue 25's
# ground estimate made the first fused frame slower: on a busy 2-core machine one or two
# more scans of a replay then pass).
START_UP = 0.35e9


@pytest.fixture
def loop_factory(tmp_path):
    made = []

    def make(**params):
        made.append(Loopback(tmp_path, params))
        return made[-1]

    yield make
    for item in made:
        item.close()


def test_memory_sizes_the_grid_cannot_hold_are_refused_at_run_time(tmp_path, loop_factory):
    """Issue 26.1: memory_radius 20 (in the old table's range) with the default memory_cell
    needed more cells than the grid holds and ended the node. Now the table stops at a
    radius the default cell allows, and a combination no grid holds is refused with a reason;
    the node keeps fusing."""
    scene = Scene(duration=3.0)
    bag = write_scene_bag(tmp_path / 'in.mcap', scene)
    # Each scan waits for its frame (as its sibling tests): a loaded machine's late frame
    # would otherwise pass a scan through with the LiDAR alone (the wall, not the box).
    loop = loop_factory(use_tf=False, memory_radius=10.0, pair_wait=0.1, **SCENE_PARAMS)
    go = tmp_path / 'started'
    setters = {
        'radius': ('memory_radius', '20.0'),
        'cell': ('memory_cell', '0.005'),  # 10 m in 5 mm cells: 16 million cells
    }
    processes = {
        key: loop.loopback(
            key, 'set-param', name, value, '--out', str(tmp_path / f'{key}.json'), '--go', str(go)
        )
        for key, (name, value) in setters.items()
    }
    loop.record('/scan_fused')
    player = loop.play(bag, '--started', str(go))
    for key, process in processes.items():
        assert process.wait(timeout=60) == 0, loop.log(key)
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received()['/scan_fused']
    assert loop.node.poll() is None, loop.log('node')
    radius = json.loads((tmp_path / 'radius.json').read_text())
    cell = json.loads((tmp_path / 'cell.json').read_text())
    assert not radius['successful']
    assert 'memory_radius' in radius['reason']
    assert not cell['successful']
    assert 'memory_cell' in cell['reason']
    assert 'memory cells' in cell['reason']
    done = max(radius['done'], cell['done'])
    # The first scans may pass while the node still waits for the first CameraInfo, or builds
    # the camera's tables and the floor's sample on its first frame (START_UP).
    after = [
        ahead(scan)
        for t, raw in received
        if t > done + 0.15 and (scan := scan_from_cdr(raw)).stamp_ns >= scene.start_ns + START_UP
    ]
    assert after, 'the replay ended before the parameters were set'
    assert all(value == pytest.approx(BOX, abs=TOLERANCE) for value in after), after


def test_soak_with_memory_odometry_and_a_second_lidar_under_a_malformed_flood(
    tmp_path, loop_factory
):
    """Issue 26 (done when): the node with the memory, odometry and a second LiDAR, flooded
    with malformed scans on both LiDARs' topics (increments of 1e-7 and 1e-9, angle_min
    -1e12, a NaN time_increment, a Hokuyo's zeros), bad odometry and the older floods, keeps
    its resident memory bounded, counts what it dropped and publishes valid scans after."""
    scene = Scene(duration=4.0)  # long enough to see past the start-up (START_UP)
    odometry = [
        (
            '/odom',
            ODOMETRY,
            stamp,
            odometry_to_cdr(OdometrySample(stamp, 'odom', 'base_link', PlanarPose(0.0, 0.0, 0.0))),
        )
        for stamp in range(scene.start_ns - 100_000_000, scene.start_ns + 4_100_000_000, 20_000_000)
    ]
    messages = sorted(two_lidar_messages(scene) + odometry, key=lambda message: message[2])
    bag = write_bag(tmp_path / 'in.mcap', messages)
    sources = {
        'lidars': '[front, rear]',
        'front.topic': '/scan',
        'front.z': 0.3,
        'rear.topic': REAR_TOPIC,
        'rear.z': 0.3,
        'rear.yaw': math.pi,
    }
    loop = loop_factory(use_tf=False, pair_wait=0.1, **SCENE_PARAMS, **sources)
    loop.record('/scan_fused', '/scan_memory', '/diagnostics')
    # The running node's memory, not a process still loading (or, with a cold numba cache,
    # compiling) its kernels: it logs 'fusing' once warmed up and subscribed.
    deadline = time.monotonic() + 120.0
    while 'fusing' not in loop.log('node') and time.monotonic() < deadline:
        assert loop.node.poll() is None, loop.log('node')
        time.sleep(0.1)
    baseline = _rss_kib(loop.node.pid, 'VmRSS')
    flood = loop.loopback('flood', 'flood', '--seconds', '8', '--sources')
    assert flood.wait(timeout=60) == 0, loop.log('flood')
    assert loop.node.poll() is None, loop.log('node')
    player = loop.play(bag, '--wait-for', REAR_TOPIC, '--wait-for', '/odom')
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    assert loop.node.poll() is None, loop.log('node')
    peak = _rss_kib(loop.node.pid, 'VmHWM')
    assert (peak - baseline) / 1024 <= SOAK_RSS_BOUND_MIB, (baseline, peak)
    fused = [scan_from_cdr(raw) for _, raw in received['/scan_fused']]
    for scan in [*fused, *(scan_from_cdr(raw) for _, raw in received.get('/scan_memory', []))]:
        values = scan.ranges[np.isfinite(scan.ranges)]
        assert np.all((values >= scan.range_min) & (values <= scan.range_max) & (values > 0.0))
    later = [scan for scan in fused if scan.stamp_ns >= scene.start_ns + START_UP]
    assert len([s for s in later if ahead(s) == pytest.approx(BOX, abs=TOLERANCE)]) >= 10
    store = typestore()
    last = store.deserialize_cdr(
        received['/diagnostics'][-1][1], 'diagnostic_msgs/msg/DiagnosticArray'
    )
    values = {kv.key: kv.value for kv in last.status[0].values}
    assert int(values['malformed scan (rear)']) >= 1
    assert int(values['malformed odometry']) >= 1
    assert int(values['malformed scan']) >= 1
    assert values['odometry from'] == '/odom'
