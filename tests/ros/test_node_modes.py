"""The node's drop-in modes over real DDS on loopback (issue 27): two corner LiDARs and no
camera, output in base_link over 360 degrees (the mergers' use); a camera and no LiDAR with
`row` + `d2l_compat` (depthimage_to_laserscan's use). The player, the node and the recorder
are each their own process, as in tests/ros/test_node_dds.py; the health reports too."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.ros.messages import scan_from_cdr, typestore
from tests.ros.test_node_dds import loopback_factory  # noqa: F401 - the fixture
from tests.support.modes import (
    D2L_RANGE,
    FRONT,
    REAR,
    SMALL_CAMERA,
    camera_messages,
    camera_only_params,
    d2l_images,
    lidar_messages,
    room_truth,
)
from tests.support.reference import d2l_scan_loop
from tests.support.synthetic import write_bag

pytest.importorskip('rclpy')

pytestmark = pytest.mark.ros


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
    # Best effort may lose a few; the node may match the rear publisher a little after the
    # front one: from the first scan with both LiDARs' readings on, every one is checked.
    checked = 0
    for scan in scans:
        assert scan.frame_id == 'base_link'
        assert len(scan) == 720
        covered, error = room_truth(scan)
        assert error <= 0.02
        if covered < 0.95 and not checked:
            continue
        assert covered >= 0.95
        checked += 1
    assert checked >= 14, loop.log('node')
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
