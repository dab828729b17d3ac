"""`scanfuse bag` in the drop-in modes (issue 27): LiDARs only (the mergers' use) and camera
only (depthimage_to_laserscan's), on bags written with rosbags and read back with it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from scanfuse import BagError, FusionConfig
from scanfuse.cli import main
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.messages import (
    POINT_CLOUD,
    cloud_to_cdr,
    scan_from_msg,
)
from tests.support.modes import (
    D2L_CX,
    D2L_CY,
    D2L_FX,
    D2L_RANGE,
    box_cloud,
    camera_messages,
    camera_only_params,
    clouds_only_params,
    d2l_images,
    lidar_in_world,
    lidar_messages,
    lidars_only_params,
    room_truth,
    turning_messages,
)
from tests.support.reference import d2l_scan_loop
from tests.support.render import square_room_ranges
from tests.support.synthetic import write_bag

if TYPE_CHECKING:
    from pathlib import Path


def _fused(path: Path, topic: str = '/scan_fused') -> list[tuple[int, object]]:
    with AnyReader([path]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [
            (t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages(connections=connections)
        ]


def _params_file(path: Path, values: dict) -> Path:
    path.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}))
    return path


def test_two_corner_lidars_without_a_camera_through_scanfuse_bag(tmp_path):
    source = write_bag(tmp_path / 'in', lidar_messages(10))
    params = _params_file(tmp_path / 'params.yaml', lidars_only_params())
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 0
    fused = _fused(tmp_path / 'out')
    assert len(fused) == 10  # one per front scan
    for _, scan in fused:
        assert scan.header.frame_id == 'base_link'
        assert len(scan.ranges) == 720
        covered, error = room_truth(scan)
        assert covered >= 0.95
        assert error <= 0.02


def test_a_lidar_only_bag_without_depth_topic_empty_says_how(tmp_path):
    source = write_bag(tmp_path / 'in', lidar_messages(2))
    values = {k: v for k, v in lidars_only_params().items() if k != 'depth_topic'}
    with pytest.raises(BagError, match="for LiDARs or clouds only set depth_topic: ''"):
        fuse_bag(source, tmp_path / 'out', config=FusionConfig.from_dict(values))


def test_camera_only_row_d2l_through_scanfuse_bag_is_depthimage_to_laserscan(tmp_path):
    images = d2l_images()
    source = write_bag(tmp_path / 'in', camera_messages(list(images.values())))
    params = _params_file(tmp_path / 'params.yaml', camera_only_params())
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 0
    fused = _fused(tmp_path / 'out')
    assert len(fused) == len(images)
    for (name, image), (_, scan) in zip(images.items(), fused, strict=True):
        angle_min, angle_max, increment, ranges = d2l_scan_loop(
            image, D2L_FX, D2L_CX, D2L_CY, scan_height=1, range_min=D2L_RANGE[0],
            range_max=D2L_RANGE[1],
        )  # fmt: skip
        np.testing.assert_array_equal(np.asarray(scan.ranges), ranges, err_msg=name)
        assert np.float32(scan.angle_min) == np.float32(angle_min)
        assert np.float32(scan.angle_max) == np.float32(angle_max)
        assert np.float32(scan.angle_increment) == np.float32(increment)
        assert (scan.range_min, scan.range_max) == pytest.approx(D2L_RANGE)
        assert scan.header.frame_id == 'camera_depth_frame'
    # Each scan carries its image's stamp.
    stamps = [s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for _, s in fused]
    assert stamps == [1_000_000_000 + k * 33_333_333 for k in range(len(images))]


def test_clouds_only_through_scanfuse_bag_find_the_slab_box_not_the_floor(tmp_path):
    points = box_cloud()
    stamps = [1_000_000_000 + k * 100_000_000 for k in range(3)]
    messages = [
        ('/points', POINT_CLOUD, t, cloud_to_cdr(points, frame_id='points', stamp_ns=t))
        for t in stamps
    ]
    source = write_bag(tmp_path / 'in', messages)
    fuse_bag(source, tmp_path / 'out', config=FusionConfig.from_dict(clouds_only_params()))
    fused = _fused(tmp_path / 'out')
    assert [t for t, _ in fused] == stamps
    for _, scan in fused:
        assert scan.header.frame_id == 'base_link'
        ranges = np.asarray(scan.ranges)
        angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
        ahead = np.abs(angles) < np.arctan2(0.18, 1.5)
        np.testing.assert_allclose(ranges[ahead], 1.5 / np.cos(angles[ahead]), atol=0.03)
        assert not np.isfinite(ranges[np.abs(angles) > np.arctan2(0.25, 1.5)]).any()


def test_a_fixed_rate_through_scanfuse_bag_moves_a_turning_robots_scans_to_its_stamps(tmp_path):
    # The robot of tests/test_output.py: turning at 1 rad/s, a LiDAR 0.2 m ahead of the base
    # at 10 Hz, odometry at 100 Hz; outputs at 20 Hz.
    messages = turning_messages(100)
    values = {
        'use_tf': False,
        'memory': False,
        'depth_topic': '',
        'publish_rate': 20.0,
        'lidar_x': 0.2,
    }
    source = write_bag(tmp_path / 'in', messages)
    fuse_bag(source, tmp_path / 'out', config=FusionConfig.from_dict(values))
    fused = [scan_from_msg(message) for _, message in _fused(tmp_path / 'out')]
    assert sorted(s.stamp_ns for s in fused) == [1_000_000_000 + k * 50_000_000 for k in range(21)]
    for scan in fused:
        origin, yaw = lidar_in_world(scan.stamp_ns / 1e9)
        truth = square_room_ranges(origin, yaw, scan.angles(), 2.0)
        finite = np.isfinite(scan.ranges)
        assert finite.mean() >= 0.95
        np.testing.assert_allclose(scan.ranges[finite], truth[finite], atol=0.02)
