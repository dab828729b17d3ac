"""Recorded bags: readable by rosbags and by the independent mcap reader, transforms resolve."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import TYPE_CHECKING

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from rosbags.typesys import Stores, get_typestore

from scanfuse.cli import main
from scanfuse.frames import TransformStore
from scanfuse.ros.messages import transforms_from_msg
from scanfuse.sim import SimConfig, SimError, fusion_config, record, scripted_path
from scanfuse.sim.cli import parse_backend, parse_resolution
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    from pathlib import Path

EXPECTED_TYPES = {
    '/scan': 'sensor_msgs/msg/LaserScan',
    '/scan_truth': 'sensor_msgs/msg/LaserScan',
    '/camera/depth/image_raw': 'sensor_msgs/msg/Image',
    '/camera/depth/camera_info': 'sensor_msgs/msg/CameraInfo',
    '/tf': 'tf2_msgs/msg/TFMessage',
    '/tf_static': 'tf2_msgs/msg/TFMessage',
    '/odom': 'nav_msgs/msg/Odometry',
    '/ground_truth/pose': 'geometry_msgs/msg/PoseStamped',
    '/collisions': 'std_msgs/msg/String',
    '/imu': 'sensor_msgs/msg/Imu',
}
CONFIG = SimConfig(world='bookshelf', resolution=(256, 144), depth_rate=5.0)


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp('sim') / 'run.mcap'
    # 7.5 s at 0.3 m/s: the robot reaches the shelf and pushes against it for a while.
    record(CONFIG, scripted_path('straight'), 7.5, out)
    return out


def read_all(path: Path) -> dict[str, list]:
    messages: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for connection, _, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype)
            )
    return messages


def test_bag_is_one_mcap_file_with_every_topic_and_type(bag):
    assert bag.is_file()
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
        static = next(c for c in reader.connections if c.topic == '/tf_static')
        durability = static.ext.offered_qos_profiles[0].durability
    assert types == EXPECTED_TYPES
    # 10 Hz sweeps from 0 to 7.4 s, delivered at their end (the one at 7.5 s would end later).
    assert counts['/scan'] == counts['/scan_truth'] == 75
    # 5 Hz exposures at 0, 0.2, ..., 7.4 s, delivered 40 ms later, before 7.5 s.
    assert counts['/camera/depth/image_raw'] == counts['/camera/depth/camera_info'] == 38
    # Odometry, TF and the true pose at 50 Hz over [0, 7.5] s, both ends.
    assert counts['/odom'] == counts['/tf'] == counts['/ground_truth/pose'] == 376
    # The IMU at 100 Hz over [0, 7.5] s, both ends.
    assert counts['/imu'] == 751
    assert counts['/tf_static'] == 1
    assert counts['/collisions'] >= 1
    assert durability == QosDurability.TRANSIENT_LOCAL


def test_messages_hold_what_the_simulation_produced(bag):
    messages = read_all(bag)
    scan = messages['/scan'][0]
    truth = messages['/scan_truth'][0]
    assert scan.header.frame_id == truth.header.frame_id == 'laser'
    assert len(scan.ranges) == len(truth.ranges) == 1080
    assert scan.header.stamp == truth.header.stamp
    # Straight ahead at the start: the wall 2.8 m away through the shelf; the truth: boards at 2 m.
    assert scan.ranges[540] == pytest.approx(2.8, abs=0.05)
    assert truth.ranges[540] == pytest.approx(2.0, abs=0.002)
    image = messages['/camera/depth/image_raw'][0]
    assert (image.encoding, image.width, image.height, image.step) == ('16UC1', 256, 144, 512)
    assert image.header.frame_id == 'camera_depth_optical_frame'
    depth = np.frombuffer(image.data, dtype='<u2').reshape(144, 256)
    assert 0 < np.count_nonzero(depth) < depth.size
    info = messages['/camera/depth/camera_info'][0]
    focal = 72.0 / math.tan(math.radians(29.0))
    assert info.k.tolist() == pytest.approx([focal, 0, 127.5, 0, focal, 71.5, 0, 0, 1])
    collision = json.loads(messages['/collisions'][0].data)
    assert collision['contacts'][0]['kind'] in {'shelf_board', 'shelf_side'}
    assert collision['contacts'][0]['robot_geom'] == 'robot/chassis'
    odom, pose = messages['/odom'][0], messages['/ground_truth/pose'][0]
    assert (odom.header.frame_id, odom.child_frame_id, pose.header.frame_id) == (
        'odom',
        'base_link',
        'world',
    )
    # Before the contact, odometry and the true displacement agree.
    early_odom, early_pose = messages['/odom'][100], messages['/ground_truth/pose'][100]
    assert early_odom.pose.pose.position.x == pytest.approx(early_pose.pose.position.x, abs=0.05)
    assert early_pose.pose.position.x > 0.5


def test_log_times_are_delivery_times_and_stamps_the_sensors(bag):
    log: dict[str, list[tuple[int, int]]] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for connection, log_time, raw in reader.messages():
            if connection.topic in {'/scan', '/camera/depth/image_raw', '/odom'}:
                message = reader.deserialize(raw, connection.msgtype)
                stamp = message.header.stamp.sec * 10**9 + message.header.stamp.nanosec
                log.setdefault(connection.topic, []).append((log_time, stamp))
    # A scan is logged when its 100 ms sweep ends, stamped with its first beam.
    assert {t - s for t, s in log['/scan']} == {100_000_000}
    # An image is logged 40 ms (the camera's latency) after its exposure.
    assert {t - s for t, s in log['/camera/depth/image_raw']} == {40_000_000}
    # Odometry at its stamp, every 20 ms.
    odom = np.array(log['/odom'])
    assert np.all(odom[:, 0] == odom[:, 1])
    assert set(np.diff(odom[:, 1])) == {20_000_000}
    scans = reader_scans(bag)
    assert scans[0].time_increment == pytest.approx(0.1 / 1080, rel=1e-6)
    assert scans[0].scan_time == pytest.approx(0.1)


def reader_scans(path: Path) -> list:
    return read_all(path)['/scan']


def test_independent_mcap_reader_decodes_the_bag(bag):
    seen: dict[str, int] = {}
    with bag.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages():
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            if channel.topic == '/scan' and seen[channel.topic] == 1:
                assert len(message.ranges) == 1080
                assert message.header.frame_id == 'laser'
            if channel.topic == '/camera/depth/image_raw' and seen[channel.topic] == 1:
                assert message.encoding == '16UC1'
    assert set(seen) == set(EXPECTED_TYPES)


def test_transforms_resolve_from_base_link_to_the_optical_frame(bag):
    messages = read_all(bag)
    store = TransformStore()
    store.add_all(transforms_from_msg(messages['/tf_static'][0]), static=True)
    laser = store.lookup('base_link', 'laser')
    assert laser[:3, 3] == pytest.approx([0.0, 0.0, 0.30])
    optical = store.lookup('base_link', 'camera_depth_optical_frame')
    pitch = math.radians(20.0)
    assert optical[:3, 3] == pytest.approx([0.12, 0.0, 0.45])
    # The optical z axis looks forward and 20 degrees down, x to the right, y down-ish (REP-103).
    assert optical[:3, 2] == pytest.approx([math.cos(pitch), 0.0, -math.sin(pitch)])
    assert optical[:3, 0] == pytest.approx([0.0, -1.0, 0.0])
    assert optical[:3, 1] == pytest.approx([-math.sin(pitch), 0.0, -math.cos(pitch)])
    odom = transforms_from_msg(messages['/tf'][-1])[0]
    assert (odom.parent, odom.child) == ('odom', 'base_link')


def test_a_folder_name_gives_a_rosbag2_directory(tmp_path):
    out = tmp_path / 'run_dir'
    summary = record(CONFIG, scripted_path('rotate'), 0.3, out)
    assert (out / 'metadata.yaml').is_file()
    assert summary.counts['/scan'] == 3  # delivered at 0.1, 0.2, 0.3 s
    with pytest.raises(SimError, match='exists already; remove it'):
        record(CONFIG, scripted_path('rotate'), 0.3, out)


def test_cli_simulate_writes_bag_and_snapshot(tmp_path, capsys):
    out, png = tmp_path / 'cli.mcap', tmp_path / 'world.png'
    code = main(
        [
            'simulate',
            '--world',
            'barricade',
            '--path',
            'straight',
            '--duration',
            '0.5',
            '--out',
            str(out),
            '--resolution',
            '424x240',
            '--depth-rate',
            '4',
            '--no-noise',
            '--seed',
            '3',
            '--snapshot',
            str(png),
        ]
    )
    assert code == 0
    assert out.is_file()
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'real-time factor' in capsys.readouterr().out


def test_cli_reports_bad_options_in_one_line(tmp_path, capsys):
    code = main(['simulate', '--out', str(tmp_path / 'x.mcap'), '--resolution', '640by480'])
    assert code == 1
    assert "resolution '640by480' is not WIDTHxHEIGHT" in capsys.readouterr().err
    with pytest.raises(SimError, match="unknown depth backend 'opengl'"):
        parse_backend('opengl')
    assert parse_resolution(' 848x480 ') == (848, 480)


def test_fusion_config_of_the_simulation_matches_the_recorded_tf(bag):
    messages = read_all(bag)
    store = TransformStore()
    store.add_all(transforms_from_msg(messages['/tf_static'][0]), static=True)
    extrinsics = Extrinsics.from_config(fusion_config(CONFIG))
    assert extrinsics.base_to_camera_optical.matrix == pytest.approx(
        store.lookup('base_link', 'camera_depth_optical_frame'), abs=1e-9
    )
    assert extrinsics.base_to_laser.matrix == pytest.approx(
        store.lookup('base_link', 'laser'), abs=1e-9
    )


def test_scanfuse_bag_fuses_the_recording_without_options(bag, tmp_path):
    out = tmp_path / 'fused'
    assert main(['bag', str(bag), str(out)]) == 0
    messages = read_all(out)
    fused, lidar = messages['/scan_fused'][0], messages['/scan'][0]
    # Within 1.7 degrees of straight ahead at the start, the LiDAR sees only the wall 2.8 m
    # away; the fusion adds the boards 2.0 m away, beyond far_confirm_range: once the
    # camera's second frame (5 Hz, the LiDAR's 10 Hz) showed them where its first did.
    # (At 256 px a pixel column is 0.44 degrees wide, so not every 0.33 degree LiDAR slot
    # holds a depth pixel: take the nearest.)
    ahead = slice(535, 546)
    assert np.nanmin(lidar.ranges[ahead]) == pytest.approx(2.8, abs=0.05)
    assert np.nanmin(fused.ranges[ahead]) == pytest.approx(2.8, abs=0.05)
    later = min(np.nanmin(scan.ranges[ahead]) for scan in messages['/scan_fused'][1:4])
    assert later == pytest.approx(2.0, abs=0.15)


def test_a_failing_run_leaves_no_partial_bag(tmp_path):
    def broken(observation):
        msg = 'controller failed'
        raise RuntimeError(msg)

    out = tmp_path / 'broken.mcap'
    with pytest.raises(RuntimeError, match='controller failed'):
        record(CONFIG, broken, 1.0, out)
    assert list(tmp_path.iterdir()) == []


def test_cli_mounting_options_reach_the_recorded_tf(tmp_path):
    out = tmp_path / 'mount.mcap'
    code = main(
        [
            'simulate', '--world', 'room', '--path', 'rotate', '--duration', '0.2',
            '--out', str(out), '--resolution', '256x144', '--depth-rate', '5',
            '--lidar-height', '0.2', '--camera-height', '0.6', '--camera-pitch', '0.5236',
        ]
    )  # fmt: skip
    assert code == 0
    store = TransformStore()
    store.add_all(transforms_from_msg(read_all(out)['/tf_static'][0]), static=True)
    assert store.lookup('base_link', 'laser')[2, 3] == pytest.approx(0.2)
    optical = store.lookup('base_link', 'camera_depth_optical_frame')
    assert optical[2, 3] == pytest.approx(0.6)
    pitch = 0.5236  # radians, as the parameter files
    assert optical[:3, 2] == pytest.approx([math.cos(pitch), 0.0, -math.sin(pitch)])


def test_the_parameter_file_mounts_the_simulated_sensors_and_flags_override_it(tmp_path):
    params = tmp_path / 'robot.yaml'
    values = {'camera_height': 0.52, 'camera_pitch': 0.3, 'camera_x': 0.2, 'lidar_height': 0.25}
    params.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}))
    out = tmp_path / 'params.mcap'
    code = main(
        [
            'simulate', '--world', 'room', '--path', 'rotate', '--duration', '0.2',
            '--out', str(out), '--resolution', '256x144', '--depth-rate', '5',
            '--params', str(params), '--lidar-height', '0.35',
        ]
    )  # fmt: skip
    assert code == 0
    store = TransformStore()
    store.add_all(transforms_from_msg(read_all(out)['/tf_static'][0]), static=True)
    assert store.lookup('base_link', 'laser')[2, 3] == pytest.approx(0.35)  # the flag wins
    optical = store.lookup('base_link', 'camera_depth_optical_frame')
    assert optical[0, 3] == pytest.approx(0.2)
    assert optical[2, 3] == pytest.approx(0.52)
    assert optical[:3, 2] == pytest.approx([math.cos(0.3), 0.0, -math.sin(0.3)])


def test_every_lazy_export_of_the_sim_package_stays_itself_whatever_was_imported_first():
    # A submodule named like one of the package's exports would replace that export with
    # the module once anything imports the submodule (the import system binds it on the
    # package). A fresh interpreter imports every submodule first, then asks for each export.
    script = (
        'import importlib, pkgutil, scanfuse.sim as sim\n'
        'for info in pkgutil.iter_modules(sim.__path__):\n'
        '    importlib.import_module(f"scanfuse.sim.{info.name}")\n'
        'import types\n'
        'bad = [n for n in sim.__all__ if isinstance(getattr(sim, n), types.ModuleType)]\n'
        'print(bad)\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', script], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'


def test_imu_messages_hold_the_bases_orientation_in_base_link(bag):
    messages = read_all(bag)
    imu = messages['/imu']
    poses = {
        (p.header.stamp.sec, p.header.stamp.nanosec): p.pose.orientation
        for p in messages['/ground_truth/pose']
    }
    compared = 0
    for message in imu:
        assert message.header.frame_id == 'base_link'
        # The noise's variance on the diagonal (0.1 degree).
        assert message.orientation_covariance[0] == pytest.approx(math.radians(0.1) ** 2)
        true = poses.get((message.header.stamp.sec, message.header.stamp.nanosec))
        if true is None:
            continue
        # The IMU's orientation is the base's, within its noise (a few sigma of 0.1 degree).
        dot = abs(
            message.orientation.x * true.x
            + message.orientation.y * true.y
            + message.orientation.z * true.z
            + message.orientation.w * true.w
        )
        assert math.degrees(2 * math.acos(min(1.0, dot))) < 0.8
        compared += 1
    assert compared == 376
    # Gravity, measured by the accelerometer at rest: 9.81 m/s^2 up in base_link.
    assert imu[0].linear_acceleration.z == pytest.approx(9.81, abs=0.1)
