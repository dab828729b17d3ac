"""`fuse_bag` and `scanfuse bag` on real bags written with rosbags into tmp_path.

The scene (tests.support.synthetic): a wall at x = 2 m seen by the LiDAR (0.3 m up),
a 0.2 m high box whose front face is at x = 1.2 m, |y| <= 0.15 m, below the LiDAR's
plane, and a depth camera 0.45 m up pitched 20 degrees down, all published on
/tf_static. 2 s of 10 Hz scans and 30 Hz depth with no depth between 0.5 s and 0.9 s.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import math
import os
import re
import shutil
from pathlib import Path  # noqa: TC003 - used at run time by pytest fixtures
from time import time as wall_clock

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from scanfuse import BagError, FusionConfig, TransformError
from scanfuse.cli import main
from scanfuse.frames import StampedTransform
from scanfuse.motion import PlanarPose
from scanfuse.ros.bag import Storage, cdr_problem, fuse_bag, header_stamp_ns
from scanfuse.ros.messages import (
    IMAGE,
    LASER_SCAN,
    ODOMETRY,
    TF_MESSAGE,
    OdometrySample,
    camera_to_cdr,
    odometry_to_cdr,
    scan_from_cdr,
    scan_to_cdr,
    tf_message_to_cdr,
)
from scanfuse.scan import Scan
from tests.support.synthetic import Scene, scene_messages, write_bag, write_scene_bag

GAP = (0.5, 0.9)
# Scans at 0.0, 0.1, ..., 1.9 s; frames at 1/90 s + k/30 s, none in [0.5, 0.9).
# Scan 0.5: frame 0.4778 is 22 ms away -> paired. Scan 0.6: nearest frames 0.4778 (122 ms)
# and 0.9111 (311 ms) -> unpaired; 0.7 unpaired; 0.8: 0.9111 is 111 ms away -> unpaired.
SCANS, PASSED = 20, 3
HUMBLE = get_typestore(Stores.ROS2_HUMBLE)


def _read_all(path: Path):
    """(topic, log time, raw bytes) of every message, read with rosbags."""
    with AnyReader([path]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _digest(path: Path) -> str:
    files = sorted(p for p in path.rglob('*') if p.is_file()) if path.is_dir() else [path]
    return hashlib.sha256(b''.join(p.read_bytes() for p in files)).hexdigest()


@pytest.fixture(scope='module', params=['mcap', 'sqlite3'])
def fused(request, tmp_path_factory):
    """A scene bag in one storage, fused into the other storage."""
    folder = tmp_path_factory.mktemp(request.param)
    source = write_scene_bag(folder / 'in', Scene(depth_gap=GAP), storage=request.param)
    before = _digest(source)
    out_storage = 'sqlite3' if request.param == 'mcap' else 'mcap'
    report = fuse_bag(source, folder / 'out', storage=out_storage)
    assert _digest(source) == before  # the input is never modified
    return source, folder / 'out', report


def test_report_counts(fused):
    source, _, report = fused
    inputs = len(_read_all(source))
    assert report.messages_read == inputs
    assert report.scans == SCANS
    assert report.scans_passed_through == PASSED
    assert report.scans_paired == SCANS - PASSED
    # every input message, one fused scan per LiDAR scan, one depth scan per paired scan
    assert report.messages_written == inputs + SCANS + (SCANS - PASSED)
    assert report.extrinsics_source.startswith('TF')
    assert len(report.scan_times_s) == SCANS - PASSED


def test_every_input_message_is_kept_byte_identical(fused):
    source, output, _ = fused
    written = _read_all(output)
    originals = _read_all(source)
    kept = [item for item in written if item[0] not in {'/scan_fused', '/scan_depth'}]
    assert sorted(kept) == sorted(originals)


def test_output_is_a_version_8_bag_of_the_requested_storage(fused):
    source, output, report = fused
    metadata = yaml.safe_load((output / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert metadata['version'] == 8
    assert metadata['storage_identifier'] == report.storage.value
    assert report.storage.value != ('mcap' if source.joinpath('in.mcap').exists() else 'sqlite3')
    assert not list(output.parent.glob('.out.*'))  # no staging folder left behind


def _scans(path: Path, topic: str):
    with AnyReader([path]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return [
            (t, bytes(raw), reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages(connections=connections)
        ]


def test_fused_scans_match_the_lidar(fused):
    source, output, _ = fused
    lidar = _scans(source, '/scan')
    fused_scans = _scans(output, '/scan_fused')
    assert len(fused_scans) == len(lidar) == SCANS
    for (lidar_time, lidar_raw, scan), (time, raw, out) in zip(lidar, fused_scans, strict=True):
        assert time == lidar_time
        assert out.header.stamp == scan.header.stamp
        assert out.header.frame_id == scan.header.frame_id
        assert (out.angle_min, out.angle_increment) == (scan.angle_min, scan.angle_increment)
        assert len(out.ranges) == len(scan.ranges)
        valid = (
            np.isfinite(scan.ranges)
            & (scan.ranges >= scan.range_min)
            & (scan.ranges <= scan.range_max)
        )
        assert np.all(out.ranges[valid] <= scan.ranges[valid])
        seconds = (scan.header.stamp.sec - 1_700_000_000) + scan.header.stamp.nanosec / 1e9
        if 0.55 < seconds < 0.85:  # no depth frame within 0.1 s: passed through unchanged
            assert raw == lidar_raw


def test_low_box_appears_in_the_fused_scan(fused):
    _, output, _ = fused
    scene = Scene()
    angles = scene.lidar_angles()
    for _, _, out in _scans(output, '/scan_fused')[:3]:
        # Slots whose ray meets the box's front face (|theta| < atan(0.15 / 1.2) = 7.1 deg,
        # away from its edges): the box at 1.2 / cos(theta), not the wall at 2 / cos(theta).
        inside = np.abs(angles) < math.radians(5.0)
        expected = scene.box_x / np.cos(angles[inside])
        np.testing.assert_allclose(out.ranges[inside], expected, atol=0.05 + 0.02 * 1.2)
        # Outside the camera's view (half angle atan(80 / 100) = 38.7 deg) the LiDAR's wall.
        outside = np.abs(angles) > math.radians(45.0)
        np.testing.assert_array_equal(out.ranges[outside], scene.lidar_ranges()[outside])


def test_depth_scan_has_the_lidar_grid_and_stamps(fused):
    _, output, _ = fused
    fused_scans = {t: msg for t, _, msg in _scans(output, '/scan_fused')}
    depth = _scans(output, '/scan_depth')
    assert len(depth) == SCANS - PASSED
    for time, _, msg in depth:
        assert msg.header.stamp == fused_scans[time].header.stamp
        assert len(msg.ranges) == Scene().readings


def test_output_is_readable_by_the_mcap_library(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.5), storage='sqlite3')
    fuse_bag(source, tmp_path / 'out', storage='mcap')
    originals = {(topic, t): raw for topic, t, raw in _read_all(source)}
    seen = 0
    fused = 0
    with (tmp_path / 'out' / 'out.mcap').open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            if channel.topic == '/scan_fused':
                fused += 1
                assert len(decoded.ranges) == Scene().readings
                assert decoded.header.frame_id == 'laser'
                continue
            if channel.topic == '/scan_depth':
                continue
            assert message.data == originals[channel.topic, message.log_time]
            seen += 1
    assert seen == len(originals)
    assert fused == 5


def test_ros1_input_is_converted_to_ros2(tmp_path):
    source = write_scene_bag(tmp_path / 'in.bag', Scene(duration=0.5), storage='ros1')
    report = fuse_bag(source, tmp_path / 'out')
    assert report.scans == report.scans_paired == 5
    noetic_messages = {}
    with AnyReader([source]) as reader:
        for c, t, raw in reader.messages():
            noetic_messages[c.topic, t] = reader.deserialize(raw, c.msgtype)
    with AnyReader([tmp_path / 'out']) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types['/tf_static'] == 'tf2_msgs/msg/TFMessage'
        count = 0
        for c, t, raw in reader.messages():
            if c.topic in {'/scan_fused', '/scan_depth'}:
                continue
            message = HUMBLE.deserialize_cdr(raw, c.msgtype)
            original = noetic_messages[c.topic, t]
            if c.topic == '/scan':
                np.testing.assert_array_equal(message.ranges, original.ranges)
                assert message.header.stamp == original.header.stamp
            elif c.topic == '/camera/depth/image_raw':
                np.testing.assert_array_equal(message.data, original.data)
            elif c.topic == '/camera/depth/camera_info':
                np.testing.assert_array_equal(message.k, original.K)
            count += 1
        assert count == len(noetic_messages)


def test_extrinsics_fall_back_to_parameters_with_a_warning(tmp_path, caplog):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3, publish_tf=False))
    with caplog.at_level(logging.WARNING, logger='scanfuse.ros.bag'):
        report = fuse_bag(source, tmp_path / 'out')
    # The scene's frames (tests/support/synthetic.py), named as missing.
    why = 'no laser or camera_depth_optical_frame on /tf_static or /tf yet'
    assert report.extrinsics_source == f'parameters (TF has neither sensor frame: {why})'
    assert f'extrinsics from the parameters (TF has neither sensor frame: {why})' in caplog.text


def test_tf_that_does_not_reach_base_frame_is_refused_naming_the_roots(tmp_path):
    # As a real PSENscan recording: laser_1_mount_link -> laser_1 -> laser_1_scan, no base_link.
    scene = Scene(duration=0.3, publish_tf=False)
    tree = [
        StampedTransform('laser_1_mount_link', 'laser_1', (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0)),
        StampedTransform('laser_1', 'laser', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
    ]
    messages = [
        ('/tf_static', TF_MESSAGE, scene.start_ns, tf_message_to_cdr(tree)),
        *scene_messages(scene),
    ]
    source = write_bag(tmp_path / 'in', messages)
    with pytest.raises(
        TransformError,
        match=r"TF does not connect base_frame 'base_link' .*TF roots: laser_1_mount_link; "
        r"base_frame 'laser_1_mount_link'\?.*use_tf: false",
    ):
        fuse_bag(source, tmp_path / 'out')
    assert not (tmp_path / 'out').exists()
    # The user's choice of the mounting parameters is respected.
    report = fuse_bag(source, tmp_path / 'out', config=FusionConfig(use_tf=False))
    assert report.extrinsics_source == 'parameters (use_tf is false)'


def test_require_tf_without_tf_is_an_error(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3, publish_tf=False))
    with pytest.raises(TransformError, match=r'--require-tf: no extrinsics from TF'):
        fuse_bag(source, tmp_path / 'out', require_tf=True)
    assert not (tmp_path / 'out').exists()


def test_use_tf_false_takes_the_parameters(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    report = fuse_bag(source, tmp_path / 'out', config=FusionConfig(use_tf=False))
    assert report.extrinsics_source == 'parameters (use_tf is false)'


def test_output_exists_is_an_error_unless_overwrite(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    fuse_bag(source, tmp_path / 'out', storage='sqlite3')
    with pytest.raises(BagError, match=r'out exists already; choose another path or pass'):
        fuse_bag(source, tmp_path / 'out')
    assert (tmp_path / 'out' / 'out.db3').exists()
    # A bag we wrote is replaced.
    fuse_bag(source, tmp_path / 'out', overwrite=True)
    assert (tmp_path / 'out' / 'out.mcap').exists()
    assert not (tmp_path / 'out' / 'out.db3').exists()
    # So is a single-file bag (scanfuse simulate writes those).
    single = tmp_path / 'single.mcap'
    shutil.copyfile(source / 'in.mcap', single)
    fuse_bag(source, single, overwrite=True)
    assert (single / 'single.mcap.mcap').exists()


def _not_a_bag(path: Path, kind: str) -> None:
    """Things --overwrite must leave alone, each with what the user keeps in it."""
    if kind == 'folder':
        path.mkdir()
        (path / 'keep.txt').write_text('mine')
    elif kind == 'bag_and_more':
        write_scene_bag(path, Scene(duration=0.2))
        (path / 'keep.txt').write_text('mine')
    elif kind == 'bag_with_subfolder':
        write_scene_bag(path, Scene(duration=0.2))
        (path / 'notes').mkdir()
    elif kind == 'metadata_only':
        path.mkdir()
        (path / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    elif kind == 'fake_mcap':
        path.mkdir()
        (path / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
        (path / 'out.mcap').write_text('not an mcap file')
    elif kind == 'other_yaml':
        write_scene_bag(path, Scene(duration=0.2))
        (path / 'metadata.yaml').write_text('my: settings\n')
    elif kind == 'text_file':
        path.write_text('mine')
    elif kind == 'symlink':
        (path.parent / 'real').mkdir()
        path.symlink_to(path.parent / 'real')


@pytest.mark.parametrize(
    ('kind', 'reason'),
    [
        ('folder', 'it has no metadata.yaml'),
        ('bag_and_more', 'keep.txt is not a .mcap or .db3 file'),
        ('bag_with_subfolder', 'notes is not a .mcap or .db3 file'),
        ('metadata_only', 'it holds no .mcap or .db3 file'),
        ('fake_mcap', r'out.mcap does not start like a \.mcap file'),
        ('other_yaml', 'its metadata.yaml is not rosbag2 metadata'),
        ('text_file', r'out is not a \.mcap or \.db3 file'),
        ('symlink', 'it is a symbolic link'),
    ],
)
def test_overwrite_replaces_only_a_bag(tmp_path, kind, reason):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.2))
    target = tmp_path / 'out'
    _not_a_bag(target, kind)
    before = sorted(p.name for p in target.iterdir()) if target.is_dir() else None
    with pytest.raises(BagError, match=rf'--overwrite replaces only a bag, and .*out is not one: '
                       rf'{reason}; remove it yourself or choose another output'):  # fmt: skip
        fuse_bag(source, target, overwrite=True)
    after = sorted(p.name for p in target.iterdir()) if target.is_dir() else None
    assert before == after
    assert not list(tmp_path.glob('.out.*'))


def test_output_names_up_to_the_filesystem_limit(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.2))
    limit = os.pathconf(tmp_path, 'PC_NAME_MAX')
    # The staging folder is '.' + NAME + '.' + 8 random characters + '.partial': 18 more bytes.
    longest = 'n' * (limit - 18)
    fuse_bag(source, tmp_path / longest)
    assert (tmp_path / longest / 'metadata.yaml').exists()
    with pytest.raises(
        BagError,
        match=rf'output name n{{40}}\.\.\. is {limit - 17} bytes long; this filesystem allows '
        rf'{limit} bytes per name and the staging folder adds 18: choose a name of at most '
        rf'{limit - 18} bytes',
    ):
        fuse_bag(source, tmp_path / ('n' * (limit - 17)))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(['in', longest])


def _corrupt_overflow_pages(db3: Path) -> None:
    """Point the overflow pages of the second half of the file past its end.

    A depth image (38 kB) does not fit a 4 kB b-tree page: SQLite keeps it in a chain of
    overflow pages, each starting with the 4-byte number of the next one (SQLite file format,
    section 1.6). B-tree pages start with their type (2, 5, 10 or 13), overflow pages with
    that page number, < 2**24 here, so a first byte 0. Opening the bag reads only b-tree pages;
    reading the images then meets a page number beyond the file: "database disk image is
    malformed".
    """
    data = bytearray(db3.read_bytes())
    page = 4096
    overflow = [k for k in range(1, len(data) // page) if data[k * page] == 0]
    for k in overflow[len(overflow) // 2 :]:
        data[k * page : k * page + 4] = b'\x7f\xff\xff\xff'
    db3.write_bytes(bytes(data))


def test_corrupt_sqlite_pages_are_a_bag_error_naming_the_last_good_message(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.5), storage='sqlite3')
    _corrupt_overflow_pages(source / 'in.db3')
    # rosbags reads sqlite3 bags with apsw; the corrupt page raises apsw.CorruptError mid-read.
    with pytest.raises(
        BagError,
        match=r'cannot read bag .*in after /\S+ message \d+ \(log time 1700000000\.\d{9} s.*\): '
        r'database disk image is malformed; is it complete and a bag\?',
    ) as caught:
        fuse_bag(source, tmp_path / 'out')
    assert type(caught.value.__cause__).__name__ == 'CorruptError'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in']


def _with_bad_scan(tmp_path: Path, index: int, damage) -> Path:
    messages = scene_messages(Scene(duration=0.5))
    scans = [i for i, (topic, *_) in enumerate(messages) if topic == '/scan']
    topic, msgtype, log_time, raw = messages[scans[index]]
    messages[scans[index]] = (topic, msgtype, log_time, damage(raw))
    return write_bag(tmp_path / 'in', messages)


# Scan 3 is stamped 0.3 s after the scene's start (1 700 000 000 s) and logged 10 ms later.
SCAN_3 = (
    r'/scan message 3 \(log time 1700000000\.310000000 s, header stamp 1700000000\.300000000 s\) '
    r'in .*in: cannot decode a sensor_msgs/msg/LaserScan from '
)


@pytest.mark.parametrize(
    ('damage', 'problem'),
    [
        (lambda raw: raw[:100], r'100 CDR bytes: a length field asks for more than the 100 bytes'),
        (lambda raw: raw + bytes(8), r'\d+ CDR bytes: \d+ bytes hold more than one sensor_msgs'),
    ],
)
def test_undecodable_scan_names_its_topic_index_stamp_and_what_is_wrong(tmp_path, damage, problem):
    source = _with_bad_scan(tmp_path, 3, damage)
    with pytest.raises(BagError, match='--strict: malformed ' + SCAN_3 + problem):
        fuse_bag(source, tmp_path / 'out', strict=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['in']
    # By default the scan is skipped by the fusion, copied through and listed.
    report = fuse_bag(source, tmp_path / 'out')
    (skipped,) = report.malformed
    assert skipped.topic == '/scan'
    assert re.match(SCAN_3.split(' in ', maxsplit=1)[0] + '$', skipped.where)
    assert re.match('cannot decode a sensor_msgs/msg/LaserScan from ' + problem, skipped.reason)
    assert report.scans == 4


def test_scan_that_is_not_cdr_says_so(tmp_path):
    source = _with_bad_scan(tmp_path, 3, lambda raw: b'\x01\x02' + raw[2:])
    # Without a CDR header the stamp cannot be read from the bytes: only the log time is named.
    with pytest.raises(
        BagError,
        match=r'/scan message 3 \(log time 1700000000\.310000000 s\) in .*: cannot decode a '
        r'sensor_msgs/msg/LaserScan from \d+ CDR bytes: it starts with 01 02, not a plain CDR '
        r'header \(00 01 little endian, 00 00 big endian\)',
    ):
        fuse_bag(source, tmp_path / 'out', strict=True)


def test_cdr_problem_words():
    assert cdr_problem(b'\x00', LASER_SCAN, ValueError('x')) == (
        '1 bytes are fewer than the 4-byte CDR header: the message is truncated'
    )
    assert 'is not UTF-8' in cdr_problem(
        b'\x00\x01\x00\x00', LASER_SCAN, ValueError("'utf-8' codec can't decode byte 0xff")
    )


def test_header_stamp_from_bytes():
    # CDR little endian: 00 01 00 00, sec = 5 (int32), nanosec = 7 (uint32).
    raw = b'\x00\x01\x00\x00' + (5).to_bytes(4, 'little') + (7).to_bytes(4, 'little')
    assert header_stamp_ns(raw, LASER_SCAN) == 5_000_000_007
    big = b'\x00\x00\x00\x00' + (5).to_bytes(4, 'big') + (7).to_bytes(4, 'big')
    assert header_stamp_ns(big, LASER_SCAN) == 5_000_000_007
    assert header_stamp_ns(raw, 'tf2_msgs/msg/TFMessage') is None  # no header first
    assert header_stamp_ns(raw[:11], LASER_SCAN) is None
    # ROS 1: seq (uint32) first, then sec and nsec, little endian.
    ros1 = (9).to_bytes(4, 'little') + (5).to_bytes(4, 'little') + (7).to_bytes(4, 'little')
    assert header_stamp_ns(ros1, IMAGE, is_cdr=False) == 5_000_000_007


def test_output_inside_input_is_refused(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    with pytest.raises(BagError, match=r'overlaps the input bag'):
        fuse_bag(source, source, overwrite=True)
    with pytest.raises(BagError, match=r'overlaps the input bag'):
        fuse_bag(source, source / 'out')


def test_missing_input_and_bad_storage(tmp_path):
    with pytest.raises(BagError, match=r'input bag .*nothing does not exist'):
        fuse_bag(tmp_path / 'nothing', tmp_path / 'out')
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    with pytest.raises(BagError, match=r"storage 'zip' is not supported; use one of mcap, sqlite3"):
        fuse_bag(source, tmp_path / 'out', storage='zip')
    with pytest.raises(BagError, match=r'folder .*missing of the output bag does not exist'):
        fuse_bag(source, tmp_path / 'missing' / 'out')


def test_missing_topic_lists_what_exists(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    with pytest.raises(
        BagError,
        match=r'LaserScan topic /nope is not in the bag; sensor_msgs/msg/LaserScan topics: '
        r'/scan \(sensor_msgs/msg/LaserScan\); all topics: /camera/depth/camera_info',
    ):
        fuse_bag(source, tmp_path / 'out', scan_topic='/nope')
    with pytest.raises(BagError, match=r'depth topic /scan is a sensor_msgs/msg/LaserScan'):
        fuse_bag(source, tmp_path / 'out', depth_topic='/scan')
    with pytest.raises(BagError, match=r'CameraInfo topic /scan is a sensor_msgs/msg/LaserScan'):
        fuse_bag(source, tmp_path / 'out', camera_info_topic='/scan')


def test_no_camera_info_is_an_error(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3, publish_camera_info=False))
    with pytest.raises(BagError, match=r'no CameraInfo topic \(sensor_msgs/msg/CameraInfo\)'):
        fuse_bag(source, tmp_path / 'out')


def test_several_scan_topics_need_a_choice(tmp_path):
    messages = scene_messages(Scene(duration=0.3))
    messages += [('/scan2', m, t, raw) for topic, m, t, raw in messages if topic == '/scan']
    source = write_bag(tmp_path / 'in', messages)
    with pytest.raises(
        BagError,
        match=r'several LaserScan topics in bag .*: /scan .*, /scan2 .*; choose one with --scan',
    ):
        fuse_bag(source, tmp_path / 'out', config=FusionConfig(scan_topic='/other'))
    report = fuse_bag(source, tmp_path / 'out', scan_topic='/scan2')
    assert report.topics.scan == '/scan2'


def test_depth_image_of_another_size_than_camera_info_is_skipped_and_listed(tmp_path):
    scene = Scene(duration=0.3)
    small = scene.camera.__class__.from_intrinsics(80, 60, 50, 50, 40, 30, frame_id='o')
    messages = [
        (topic, m, t, camera_to_cdr(small, stamp_ns=t) if topic.endswith('camera_info') else raw)
        for topic, m, t, raw in scene_messages(scene)
    ]
    source = write_bag(tmp_path / 'in', messages)
    report = fuse_bag(source, tmp_path / 'out')
    frames = sum(topic == '/camera/depth/image_raw' for topic, *_ in messages)
    assert len(report.malformed) == frames
    assert report.scans_paired == 0
    assert report.scans_passed_through == report.scans == 3
    first = report.malformed[0]
    assert first.topic == '/camera/depth/image_raw'
    assert 'is 160x120 but its CameraInfo says 80x60' in first.reason
    # Every input message is still in the output, and one /scan_fused per scan.
    assert report.messages_written == report.messages_read + report.scans


def test_strict_stops_at_the_first_malformed_message_naming_it(tmp_path):
    scene = Scene(duration=0.3)
    small = scene.camera.__class__.from_intrinsics(80, 60, 50, 50, 40, 30, frame_id='o')
    messages = [
        (topic, m, t, camera_to_cdr(small, stamp_ns=t) if topic.endswith('camera_info') else raw)
        for topic, m, t, raw in scene_messages(scene)
    ]
    source = write_bag(tmp_path / 'in', messages)
    with pytest.raises(
        BagError,
        match=r'--strict: malformed /camera/depth/image_raw message 0 \(log time \d+\.\d{9} s, '
        r'header stamp \d+\.\d{9} s\) in .*: .*is 160x120 but its CameraInfo says 80x60',
    ):
        fuse_bag(source, tmp_path / 'out', strict=True)
    assert not (tmp_path / 'out').exists()
    assert not list(tmp_path.glob('.out.*'))


def test_existing_fused_topic_in_input_is_an_error(tmp_path):
    messages = scene_messages(Scene(duration=0.3))
    messages += [('/scan_fused', m, t, raw) for topic, m, t, raw in messages if topic == '/scan']
    source = write_bag(tmp_path / 'in', messages)
    with pytest.raises(BagError, match=r'already has /scan_fused; set fused_topic'):
        fuse_bag(source, tmp_path / 'out')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_truncated_bag_is_a_bag_error(tmp_path, storage):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.5), storage=storage)
    (data,) = [p for p in source.iterdir() if p.suffix in {'.mcap', '.db3'}]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    with pytest.raises(BagError, match=r'cannot read bag .*in'):
        fuse_bag(source, tmp_path / 'out')
    assert not (tmp_path / 'out').exists()


def test_corrupt_single_file_is_a_bag_error(tmp_path):
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(b'\x89MCAP0\r\n' + b'\x00' * 100)
    with pytest.raises(BagError, match=r'cannot read bag .*junk\.mcap'):
        fuse_bag(junk, tmp_path / 'out')


def test_single_mcap_file_input(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    report = fuse_bag(source / 'in.mcap', tmp_path / 'out')
    assert report.scans == 3


def test_cli_bag_command(tmp_path, capsys):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    params = tmp_path / 'params.yaml'
    params.write_text(
        yaml.safe_dump({'scanfuse': {'ros__parameters': {'fused_topic': '/fused'}}}),
        encoding='utf-8',
    )
    argv = ['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]
    assert main([*argv, '--storage', 'sqlite3', '--no-depth-scan']) == 0
    assert 'scans paired with depth' in capsys.readouterr().out
    topics = {topic for topic, _, _ in _read_all(tmp_path / 'out')}
    assert '/fused' in topics
    assert '/scan_depth' not in topics
    assert (tmp_path / 'out' / 'out.db3').exists()
    assert main(argv) == 1
    assert 'exists already' in ' '.join(capsys.readouterr().err.split())
    assert main([*argv, '--overwrite']) == 0
    assert (tmp_path / 'out' / 'out.mcap').exists()


def test_storage_enum_values():
    assert [s.value for s in Storage] == ['mcap', 'sqlite3']


def _staging_like(parent: Path, name: str, *, lock: bool = True, extra: str | None = None) -> Path:
    """A folder as a run of `fuse_bag` to `parent/name` leaves it: lock, name/name.mcap."""
    folder = parent / f'.{name}.abcd_123.partial'
    (folder / name).mkdir(parents=True)
    (folder / name / f'{name}.mcap').write_bytes(b'\x89MCAP0\r\n')
    if lock:
        (folder / '.lock').touch()
    if extra is not None:
        (folder / extra).write_text('mine')
    return folder


def test_sweep_removes_only_stale_staging_folders_of_our_naming(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.2))
    work = tmp_path / 'work'
    work.mkdir()
    stale = _staging_like(work, 'a')  # its lock is free: the run that made it is gone
    live = _staging_like(work, 'b')  # locked below, as a running fuse_bag holds it
    foreign = _staging_like(work, 'c', extra='notes.txt')  # something we never write
    old_unlocked = _staging_like(work, 'd', lock=False)  # an earlier version's leftover
    hour_ago = wall_clock() - 3600
    for path in [old_unlocked, *old_unlocked.rglob('*')]:
        os.utime(path, (hour_ago, hour_ago))
    fresh_unlocked = _staging_like(work, 'e', lock=False)  # mkdtemp done, lock not yet made
    other_names = [work / '.f.partial', work / '.g.abc.partial', work / 'h.abcd_123.partial']
    for folder in other_names:
        (folder / 'x').mkdir(parents=True)
    link = work / '.i.abcd_123.partial'
    link.symlink_to(stale)
    with (live / '.lock').open('rb') as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fuse_bag(source, work / 'out')
        fuse_bag(source, work / 'out2')  # a second sweep sees the same: nothing more to take
    left = sorted(p.name for p in work.iterdir())
    kept = [live, foreign, fresh_unlocked, *other_names, link]
    assert left == sorted([p.name for p in kept] + ['out', 'out2'])
    assert (foreign / 'notes.txt').read_text() == 'mine'


def test_with_odometry_the_bag_gets_the_memory_and_the_instantaneous_scan(tmp_path):
    scene = Scene(duration=1.0)
    odometry = [
        (
            '/odom',
            ODOMETRY,
            stamp + 5_000_000,
            odometry_to_cdr(OdometrySample(stamp, 'odom', 'base_link', PlanarPose(0, 0, 0))),
        )
        for stamp in range(scene.start_ns, scene.start_ns + 1_100_000_000, 20_000_000)
    ]
    messages = sorted([*scene_messages(scene), *odometry], key=lambda m: m[2])
    source = write_bag(tmp_path / 'in', messages)
    report = fuse_bag(source, tmp_path / 'out')
    assert report.scans_compensated == report.scans_paired > 0
    written = {}
    with AnyReader([tmp_path / 'out']) as reader:
        for connection, _, raw in reader.messages():
            written.setdefault(connection.topic, []).append(
                scan_from_cdr(raw) if 'scan' in connection.topic else raw
            )
    assert len(written['/scan_memory']) == len(written['/scan_fused_instant']) == report.scans
    # The robot stands still: the memory holds the box where the camera sees it now.
    last_memory = written['/scan_memory'][-1]
    index = round(-last_memory.angle_min / last_memory.angle_increment)
    assert np.nanmin(last_memory.ranges[index - 1 : index + 2]) == pytest.approx(1.2, abs=0.02)
    fused, instant = written['/scan_fused'][-1], written['/scan_fused_instant'][-1]
    assert np.nanmin(fused.ranges[index - 1 : index + 2]) == pytest.approx(
        np.nanmin(instant.ranges[index - 1 : index + 2]), abs=0.02
    )


def _rear_scans(scene: Scene) -> list[tuple[str, str, int, bytes]]:
    """A second LiDAR 0.5 m behind the base, facing back, seeing a wall 1.0 m behind it."""
    count = 181
    increment = math.pi / (count - 1)
    angles = -math.pi / 2 + increment * np.arange(count)
    ranges = (1.0 / np.cos(angles)).astype(np.float32)
    ranges[np.abs(angles) > math.radians(60)] = np.inf
    out = []
    for stamp in scene.scan_stamps():
        scan = Scan(
            angle_min=-math.pi / 2,
            angle_max=math.pi / 2,
            angle_increment=increment,
            range_min=0.05,
            range_max=10.0,
            ranges=ranges,
            frame_id='rear_laser',
            stamp_ns=stamp - 20_000_000,
        )
        out.append(('/rear/scan', LASER_SCAN, stamp - 15_000_000, scan_to_cdr(scan)))
    return out


def test_a_second_lidar_named_as_a_source_lands_in_the_fused_scan(tmp_path):
    scene = Scene(duration=0.5, publish_tf=False)
    messages = sorted([*scene_messages(scene), *_rear_scans(scene)], key=lambda m: m[2])
    source = write_bag(tmp_path / 'in', messages)
    config = FusionConfig.from_dict(
        {
            'use_tf': False,
            'lidars': ['front', 'rear'],
            'front': {'topic': '/scan', 'z': 0.3},
            'rear': {'topic': '/rear/scan', 'x': -0.5, 'z': 0.3, 'yaw': math.pi},
            'camera_x': 0.1,
        }
    )
    report = fuse_bag(source, tmp_path / 'out', config=config)
    assert report.topics.sources == (('/rear/scan', 'rear', LASER_SCAN),)
    with AnyReader([tmp_path / 'out']) as reader:
        fused = [scan_from_cdr(raw) for c, _, raw in reader.messages() if c.topic == '/scan_fused']
    # The front LiDAR's grid (270 degrees) reaches behind to +-135 degrees; straight behind
    # it, the rear wall is 1.5 m from the front LiDAR at the base origin (0.5 + 1.0).
    last = fused[-1]
    slot = int(last.grid.slot_of(np.array([math.radians(130.0)]))[0])
    # Wall x = -1.5 in the base frame, seen from the origin at 130 degrees: 1.5 / cos(50 deg);
    # the rear LiDAR sees that point 61 degrees off its axis, past its 60: nothing there.
    assert not np.isfinite(last.ranges[slot])
    slot = int(last.grid.slot_of(np.array([math.radians(-135.0)]))[0])
    # At -135 degrees: the point (-1.5, -1.5) is 56 degrees off the rear LiDAR's axis.
    assert last.ranges[slot] == pytest.approx(1.5 / math.cos(math.radians(45.0)), abs=0.02)


def test_sensors_nobody_named_are_listed_in_the_report(tmp_path):
    scene = Scene(duration=0.3)
    messages = sorted([*scene_messages(scene), *_rear_scans(scene)], key=lambda m: m[2])
    report = fuse_bag(write_bag(tmp_path / 'in', messages), tmp_path / 'out')
    assert report.topics.scan == '/scan'
    assert report.topics.unused == (('/rear/scan', LASER_SCAN),)
    rows = {str(r) for r in report.table().columns[1]._cells}
    assert any('/rear/scan (LaserScan): name it to fuse it' in row for row in rows)


def test_a_named_source_missing_from_the_bag_is_an_error(tmp_path):
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.3))
    config = FusionConfig.from_dict(
        {'lidars': ['front', 'rear'], 'front': {'topic': '/scan'}, 'rear': {'topic': '/rear/scan'}}
    )
    with pytest.raises(BagError, match=r'source rear: topic /rear/scan is not in the bag'):
        fuse_bag(source, tmp_path / 'out', config=config)
