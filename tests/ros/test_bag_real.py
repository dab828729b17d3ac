"""`fuse_bag` on real recordings (see ../shared/data/real/README.md).

No public bag holds a LiDAR and a depth camera of one robot, so the fusion input
combines the Hokuyo scans (ROS 2 sqlite3 bag) with the Kinect depth frames (ROS 2
MCAP bag) re-stamped onto the Hokuyo's timeline, with stated extrinsics on
/tf_static: laser 0.3 m above base_link; camera 0.7 m up, pitched 45 degrees down,
looking forward (the README's description of the Kinect's pose).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import tifffile
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from scanfuse import BagError
from scanfuse.cli import main
from scanfuse.frames import StampedTransform
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.messages import (
    depth_from_cdr,
    ros1_to_cdr,
    scan_from_cdr,
    tf_message_to_cdr,
)

pytestmark = pytest.mark.real_data

HOKUYO = 'lidar/scan_tools/hokuyo_scan_matcher_demo_ros2_db3'
KINECT = 'pcl_grabber/pcl_grabber_depth_ros2_mcap'
ROS1_BAGS = [
    'lidar/scan_tools/laser_scan_matcher_demo_reindexed.bag',
    'lidar/leg_tracker/demo_stationary_simple_environment.bag',
]
HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
SECOND = 1_000_000_000
# Optical frame in camera_link (x forward, z up): z_opt = x, x_opt = -y, y_opt = -z.
BODY_TO_OPTICAL = (-0.5, 0.5, -0.5, 0.5)
PITCH_45 = (0.0, math.sin(math.radians(45.0) / 2), 0.0, math.cos(math.radians(45.0) / 2))


def _messages(path):
    with AnyReader([path]) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]


@pytest.fixture(scope='module')
def combined(real_data, tmp_path_factory):
    """Hokuyo scans + Kinect depth every 1 s on the Hokuyo timeline + /tf_static."""
    scans = _messages(real_data / HOKUYO)
    kinect = _messages(real_data / KINECT)
    images = [raw for topic, _, _, raw in kinect if topic.endswith('image_raw')]
    infos = [raw for topic, _, _, raw in kinect if topic.endswith('camera_info')]
    first_stamp = HUMBLE.deserialize_cdr(scans[0][3], 'sensor_msgs/msg/LaserScan').header.stamp
    start = first_stamp.sec * SECOND + first_stamp.nanosec
    last = HUMBLE.deserialize_cdr(scans[-1][3], 'sensor_msgs/msg/LaserScan').header.stamp
    end = last.sec * SECOND + last.nanosec
    depth_stamps = list(range(start + SECOND // 20, end, SECOND))
    path = tmp_path_factory.mktemp('real') / 'combined'
    tf = [
        StampedTransform('base_link', 'laser', (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0), start),
        StampedTransform('base_link', 'camera_link', (0.0, 0.0, 0.7), PITCH_45, start),
        StampedTransform(
            'camera_link', 'camera_depth_optical_frame', (0, 0, 0), BODY_TO_OPTICAL, start
        ),
    ]
    with Writer(path, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conns = {
            topic: writer.add_connection(topic, msgtype, typestore=HUMBLE)
            for topic, msgtype in [
                ('/tf_static', 'tf2_msgs/msg/TFMessage'),
                ('/scan', 'sensor_msgs/msg/LaserScan'),
                ('/camera/depth/image_raw', 'sensor_msgs/msg/Image'),
                ('/camera/depth/camera_info', 'sensor_msgs/msg/CameraInfo'),
            ]
        }
        writer.write(conns['/tf_static'], start, tf_message_to_cdr(tf))
        for _, _, log_time, raw in scans:
            writer.write(conns['/scan'], log_time, raw)
        for index, stamp in enumerate(depth_stamps):
            for topic, source in (
                ('/camera/depth/image_raw', images),
                ('/camera/depth/camera_info', infos),
            ):
                message = HUMBLE.deserialize_cdr(source[index % len(source)], conns[topic].msgtype)
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, SECOND)
                writer.write(
                    conns[topic], stamp, bytes(HUMBLE.serialize_cdr(message, conns[topic].msgtype))
                )
    return path, depth_stamps


@pytest.fixture(scope='module')
def fused_real(combined, tmp_path_factory):
    path, depth_stamps = combined
    output = tmp_path_factory.mktemp('real_out') / 'fused'
    return path, output, fuse_bag(path, output), depth_stamps


def test_every_input_message_is_kept(fused_real):
    source, output, report, _ = fused_real
    originals = [(topic, t, raw) for topic, _, t, raw in _messages(source)]
    kept = [
        (topic, t, raw)
        for topic, _, t, raw in _messages(output)
        if topic not in {'/scan_fused', '/scan_depth'}
    ]
    assert sorted(kept) == sorted(originals)
    assert report.messages_read == len(originals)
    assert report.extrinsics_source.startswith('TF')


def test_pairs_exactly_the_scans_with_a_frame_within_a_tenth_of_a_second(fused_real):
    source, _, report, depth_stamps = fused_real
    scans = [
        HUMBLE.deserialize_cdr(raw, 'sensor_msgs/msg/LaserScan').header.stamp
        for topic, _, _, raw in _messages(source)
        if topic == '/scan'
    ]
    stamps = [s.sec * SECOND + s.nanosec for s in scans]
    near = sum(any(abs(s - d) <= SECOND // 10 for d in depth_stamps) for s in stamps)
    assert report.scans == len(stamps) == 360
    assert report.scans_paired == near
    assert report.scans_passed_through == 360 - near
    assert 0 < near < 360


def test_fused_scans_keep_the_lidar_grid_and_never_reach_farther(fused_real):
    source, output, _, _ = fused_real
    lidar = [
        (t, HUMBLE.deserialize_cdr(raw, msgtype))
        for topic, msgtype, t, raw in _messages(source)
        if topic == '/scan'
    ]
    with (output / 'fused.mcap').open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        fused = [
            (message.log_time, decoded)
            for _, _, message, decoded in reader.iter_decoded_messages(topics=['/scan_fused'])
        ]
    assert len(fused) == len(lidar) == 360
    shorter = 0
    for (lidar_time, scan), (time, out) in zip(lidar, fused, strict=True):
        assert time == lidar_time
        assert out.header.stamp.sec == scan.header.stamp.sec
        assert out.header.stamp.nanosec == scan.header.stamp.nanosec
        assert len(out.ranges) == len(scan.ranges) == 681
        assert out.angle_min == pytest.approx(scan.angle_min, abs=0)
        assert out.angle_increment == pytest.approx(scan.angle_increment, abs=0)
        ranges = np.asarray(out.ranges)
        valid = (scan.ranges >= scan.range_min) & (scan.ranges <= scan.range_max)
        assert np.all(ranges[valid] <= scan.ranges[valid])
        shorter += int(np.sum(ranges[valid] < scan.ranges[valid]))
    # The camera sees the floor objects in front of it: fusion added obstacles somewhere.
    assert shorter > 0


@pytest.mark.parametrize('name', ROS1_BAGS)
def test_ros1_lidar_bags_have_no_depth(real_data, tmp_path, name):
    with pytest.raises(
        BagError,
        match=r'no depth Image topic \(16UC1 or 32FC1\) in bag .*; depth Image topics.*none; '
        r'all topics: .*/scan \(sensor_msgs/msg/LaserScan\)',
    ):
        fuse_bag(real_data / name, tmp_path / 'out')
    assert not (tmp_path / 'out').exists()


def test_cli_on_a_ros1_bag_reports_the_missing_depth(real_data, tmp_path, capsys):
    assert main(['bag', str(real_data / ROS1_BAGS[0]), str(tmp_path / 'out')]) == 1
    assert 'no depth Image topic' in ' '.join(capsys.readouterr().err.split())


def test_kinect_depth_in_the_mcap_bag_is_the_tiff(real_data):
    tiff = tifffile.imread(next((real_data / 'pcl_grabber').glob('*_depth.tiff')))
    images = [
        raw for topic, _, _, raw in _messages(real_data / KINECT) if topic.endswith('image_raw')
    ]
    image = depth_from_cdr(images[0])
    assert image.encoding == '16UC1'
    assert image.frame_id == 'camera_depth_optical_frame'
    np.testing.assert_array_equal(image.depth, tiff)


def test_ros1_scans_convert_like_rosbags_reads_them(real_data):
    with AnyReader([real_data / ROS1_BAGS[0]]) as reader:
        for count, (c, _, raw) in enumerate(reader.messages()):
            original = reader.deserialize(raw, c.msgtype)
            scan = scan_from_cdr(ros1_to_cdr(raw, c.msgtype))
            np.testing.assert_array_equal(scan.ranges, original.ranges)
            assert scan.stamp_ns == original.header.stamp.sec * SECOND + (
                original.header.stamp.nanosec
            )
            if count == 20:
                break
