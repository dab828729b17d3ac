"""`scanfuse bag` with an IMU (issue 25): the bag's one Imu topic is found and tilts the
mounting's floor; the output read back with an independent decoder (mcap-ros2-support).

The scene is issue 25's (tests/convert/test_ground.py): a body pitched 2 deg nose-down, TF
absent (the parameters say level), the ground estimate off, so only the IMU can put the
floor where it is.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from scanfuse import BagError
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    IMU,
    LASER_SCAN,
    ImuOrientation,
    camera_to_cdr,
    depth_to_cdr,
    imu_to_cdr,
    scan_to_cdr,
)
from scanfuse.scan import Scan
from scanfuse.transforms import Transform
from tests.support.ground_scene import (
    BOX,
    CAMERA,
    NS,
    config,
    lidar_scan,
    optical_pose,
    score,
)
from tests.support.render import box_depth, millimetres
from tests.support.synthetic import write_bag

if TYPE_CHECKING:
    from pathlib import Path

FRAMES = 3
PITCH = 2.0


def scene_bag(path: Path, imu_topics: tuple[str, ...] = ('/imu',)) -> Path:
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=PITCH), [BOX]))
    tilt = Transform.from_rpy(0.0, math.radians(PITCH), 0.0).rotation
    messages: list[tuple[str, str, int, bytes]] = []
    for step in range(0, FRAMES * NS // 10, 5_000_000):  # 200 Hz
        for topic in imu_topics:
            cdr = imu_to_cdr(ImuOrientation(step, 'base_link', tilt))
            messages.append((topic, IMU, step, cdr))
    for index in range(1, FRAMES + 1):
        stamp = index * NS // 10
        image = depth_to_cdr(depth, frame_id='optical', stamp_ns=stamp)
        messages += [
            (
                '/camera/depth/camera_info',
                CAMERA_INFO,
                stamp,
                camera_to_cdr(CAMERA, stamp_ns=stamp),
            ),
            ('/camera/depth/image_raw', IMAGE, stamp, image),
            ('/scan', LASER_SCAN, stamp + 1, scan_to_cdr(lidar_scan(stamp))),
        ]
    messages.sort(key=lambda message: message[2])
    return write_bag(path, messages)


def depth_scans(output: Path) -> list[Scan]:
    """The /scan_depth messages, decoded by mcap-ros2-support (not by scanfuse)."""
    scans = []
    with (next(output.glob('*.mcap'))).open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages(topics=['/scan_depth']):
            assert channel.topic == '/scan_depth'
            scans.append(
                Scan(
                    angle_min=message.angle_min,
                    angle_max=message.angle_max,
                    angle_increment=message.angle_increment,
                    range_min=message.range_min,
                    range_max=message.range_max,
                    ranges=np.asarray(message.ranges, dtype=np.float32),
                )
            )
    return scans


def test_the_bags_one_imu_topic_tilts_the_floor(tmp_path):
    source = scene_bag(tmp_path / 'in')
    report = fuse_bag(source, tmp_path / 'out', config=config(ground_estimate=False))
    assert report.topics.imu == '/imu'
    scans = depth_scans(tmp_path / 'out')
    assert len(scans) == FRAMES
    for scan in scans:
        assert score(scan) == (0.0, 1.0)


def test_without_the_imu_the_same_bag_reports_the_floor(tmp_path):
    source = scene_bag(tmp_path / 'in', imu_topics=('/imu', '/imu/raw'))  # several: none used
    report = fuse_bag(source, tmp_path / 'out', config=config(ground_estimate=False))
    assert report.topics.imu == ''
    assert all(score(scan)[0] > 0.1 for scan in depth_scans(tmp_path / 'out'))


def test_a_named_imu_topic_missing_from_the_bag_is_refused(tmp_path):
    source = scene_bag(tmp_path / 'in')
    with pytest.raises(BagError, match='imu_topic /imu/data is not an Imu topic of the bag'):
        fuse_bag(source, tmp_path / 'out', config=config(imu_topic='/imu/data'))
