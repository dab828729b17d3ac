"""The node's drop-in modes over real DDS on loopback (issue 27): two corner LiDARs and no
camera, output in base_link over 360 degrees (the mergers' use); a camera and no LiDAR with
`row` + `d2l_compat` (depthimage_to_laserscan's use). The player, the node and the recorder
are each their own process, as in tests/ros/test_node_dds.py; the health reports too."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.ros.messages import (
    POINT_CLOUD,
    cloud_to_cdr,
    scan_from_cdr,
    typestore,
)
from tests.ros.test_node_dds import loopback_factory  # noqa: F401 - the fixture
from tests.support.modes import (
    D2L_RANGE,
    FRONT,
    REAR,
    SMALL_CAMERA,
    box_cloud,
    camera_messages,
    camera_only_params,
    d2l_images,
    lidar_in_world,
    lidar_messages,
    room_truth,
    turning_messages,
)
from tests.support.reference import d2l_scan_loop
from tests.support.render import square_room_ranges
from tests.support.synthetic import write_bag

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros

START_UP = 300_000_000  # ns of scene time the node may take to hear the first odometry


def _diagnostics(received) -> list[dict[str, str]]:
    """Every health report: level, message and values."""
    reports = []
    for _, raw in received['/diagnostics']:
        status = typestore().deserialize_cdr(raw, 'diagnostic_msgs/msg/DiagnosticArray').status[0]
        values = {kv.key: kv.value for kv in status.values}
        reports.append({'level': str(status.level), 'message': status.message} | values)
    return reports


def test_two_corner_lidars_without_a_camera_in_base_link_over_dds(tmp_path, loopback_factory):  # noqa: F811
    bag = write_bag(tmp_path / 'in.mcap', lidar_messages(20))
    params = {
        'use_tf': False,
        'memory': False,
        'depth_topic': "''",
        'output_frame': 'base_link',
        'angle_min': -math.pi,
        'angle_max': math.pi,
        'angle_increment': math.pi / 360,
        'lidars': '[front, rear]',
    }
    for name, (topic, _, (x, y), yaw) in (('front', FRONT), ('rear', REAR)):
        params |= {f'{name}.topic': topic, f'{name}.x': x, f'{name}.y': y, f'{name}.yaw': yaw}
    loop = loopback_factory(**params)
    loop.record('/scan_fused', '/diagnostics')
    player = loop.play(bag, '--wait-for', FRONT[0], '--wait-for', REAR[0])
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    scans = [scan_from_cdr(raw) for _, raw in received.get('/scan_fused', [])]
    # The node may match the rear publisher a little after the front one, and best effort
    # may lose a message: a scan fused while one LiDAR's message is missing covers only the
    # other's share. Every scan must be right; from the first with both LiDARs' readings on,
    # at most two (one lost message's) may lack one.
    checked = partial = 0
    for scan in scans:
        assert scan.frame_id == 'base_link'
        assert len(scan) == 720
        covered, error = room_truth(scan)
        assert error <= 0.02
        if covered < 0.95 and not checked:
            continue
        if covered >= 0.95:
            checked += 1
        else:
            partial += 1
    assert checked >= 14, loop.log('node')
    assert partial <= 2, loop.log('node')
    # No camera is no problem: fusing while the LiDARs played, never a word of a camera.
    reports = _diagnostics(received)
    assert any(h['level'] == '0' and float(h['scan rate (Hz)']) > 0 for h in reports), reports
    assert not [h for h in reports if 'camera' in h['message'].lower()], reports


def test_camera_only_row_d2l_over_dds_is_depthimage_to_laserscan(tmp_path, loopback_factory):  # noqa: F811
    # The upstream cases on the fixture's camera at 160x120 (`SMALL_CAMERA`).
    images = d2l_images((SMALL_CAMERA.height, SMALL_CAMERA.width))
    names = list(images) * 3  # best effort may drop one: each case goes out three times
    period = 100_000_000
    messages = camera_messages(
        [images[n] for n in names], period_ns=period, lead=5, camera=SMALL_CAMERA
    )
    bag = write_bag(tmp_path / 'in.mcap', messages)
    params = {k: v for k, v in camera_only_params().items() if k != 'scan_topic'}
    loop = loopback_factory(scan_topic="''", pair_wait=0.0, **params)
    loop.record('/scan_fused', '/diagnostics')
    player = loop.play(bag, '--wait-for', '/camera/depth/camera_info')
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    start = 1_000_000_000
    seen = set()
    for _, raw in received.get('/scan_fused', []):
        scan = scan_from_cdr(raw)
        index = round((scan.stamp_ns - start) / period)
        assert scan.stamp_ns == start + index * period
        name = names[index]
        fx, cx, cy = SMALL_CAMERA.fx, SMALL_CAMERA.cx, SMALL_CAMERA.cy
        angle_min, angle_max, increment, ranges = d2l_scan_loop(
            images[name], fx, cx, cy, scan_height=1, range_min=D2L_RANGE[0],
            range_max=D2L_RANGE[1],
        )  # fmt: skip
        np.testing.assert_array_equal(scan.ranges, ranges, err_msg=name)
        assert np.float32(scan.angle_min) == np.float32(angle_min)
        assert np.float32(scan.angle_max) == np.float32(angle_max)
        assert np.float32(scan.angle_increment) == np.float32(increment)
        assert scan.frame_id == 'camera_depth_frame'
        seen.add(name)
    assert seen == set(images), loop.log('node')
    # Fusing while the images came, never a word of a LiDAR (once they stop: "no depth
    # image ...: publishing nothing").
    reports = _diagnostics(received)
    assert any(h['level'] == '0' and float(h['paired rate (Hz)']) > 0 for h in reports), reports
    assert not [h for h in reports if 'lidar' in h['message'].lower()], reports


def test_a_fixed_rate_over_dds_moves_a_turning_robots_scans(tmp_path, loopback_factory):  # noqa: F811
    # The robot of tests/test_output.py: turning on the spot at 1 rad/s, a LiDAR 0.2 m ahead
    # of the base at 10 Hz, odometry at 100 Hz; the node publishes at 20 Hz, each output the
    # freshest scan moved to its stamp: the room's walls as the LiDAR sees them then.
    messages = turning_messages(200)
    bag = write_bag(tmp_path / 'in.mcap', messages)
    params = {
        'use_tf': False,
        'memory': False,
        'depth_topic': "''",
        'publish_rate': 20.0,
        'lidar_x': 0.2,
    }
    loop = loopback_factory(**params)
    loop.record('/scan_fused')
    player = loop.play(bag, '--wait-for', '/odom')
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    # Under load the first scan may reach the node before any odometry sample: the stream
    # then moves nothing ("no odometry": fusing as if standing still), one period's turn off.
    # From START_UP of scene time on, odometry is there.
    scans = [
        scan
        for _, raw in received.get('/scan_fused', [])
        if (scan := scan_from_cdr(raw)).stamp_ns >= 1_000_000_000 + START_UP
    ]
    for scan in scans:
        assert scan.stamp_ns % 50_000_000 == 0  # on the rate's stamps, k / 20 Hz
        origin, yaw = lidar_in_world(scan.stamp_ns / 1e9)
        truth = square_room_ranges(origin, yaw, scan.angles(), 2.0)
        finite = np.isfinite(scan.ranges)
        assert finite.mean() >= 0.95
        np.testing.assert_allclose(scan.ranges[finite], truth[finite], atol=0.02)
    # 2 s of scans at 20 Hz: 41 stamps, 35 after START_UP; best effort may lose a few.
    assert len({scan.stamp_ns for scan in scans}) >= 20, loop.log('node')


def test_clouds_only_over_dds_find_the_slab_box_not_the_floor(tmp_path, loopback_factory):  # noqa: F811
    # pointcloud_to_laserscan's use: a 3D sensor 1 m up at the base origin sees the floor and
    # a box whose near face is 1.5 m ahead, 0.4 m wide (`modes.box_cloud`); the output, in
    # base_link, holds the face and nothing else.
    points = box_cloud().astype(np.float32)
    stamps = [1_000_000_000 + k * 100_000_000 for k in range(20)]
    messages = [
        ('/points', POINT_CLOUD, t, cloud_to_cdr(points, frame_id='points', stamp_ns=t))
        for t in stamps
    ]
    bag = write_bag(tmp_path / 'in.mcap', messages)
    params = {
        'scan_topic': "''",
        'depth_topic': "''",
        'use_tf': False,
        'memory': False,
        'obstacle_min_points': 1,
        'clouds': '[points]',
        'points.topic': '/points',
        'points.z': 1.0,
    }
    loop = loopback_factory(**params)
    loop.record('/scan_fused')
    player = loop.play(bag, '--wait-for', '/points')
    assert player.wait(timeout=60) == 0, loop.log('player')
    received = loop.received(linger=1.5)
    scans = [scan_from_cdr(raw) for _, raw in received.get('/scan_fused', [])]
    for scan in scans:
        assert scan.frame_id == 'base_link'
        assert scan.stamp_ns in stamps
        angles = scan.angles()
        ahead = np.abs(angles) < np.arctan2(0.18, 1.5)
        np.testing.assert_allclose(scan.ranges[ahead], 1.5 / np.cos(angles[ahead]), atol=0.03)
        assert not np.isfinite(scan.ranges[np.abs(angles) > np.arctan2(0.25, 1.5)]).any()
    assert len(scans) >= 5, loop.log('node')
