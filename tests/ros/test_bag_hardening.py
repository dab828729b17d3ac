"""Regression tests of issue 26 through `scanfuse bag` (the CLI on bags written into
tmp_path, as tests/ros/test_bag.py does)."""

from __future__ import annotations

import contextlib
import hashlib
import math
import re
import sqlite3
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from scanfuse.cli import main
from scanfuse.config import FusionConfig
from scanfuse.frames import StampedTransform
from scanfuse.ros.messages import (
    CAMERA_INFO,
    LASER_SCAN,
    TF_MESSAGE,
    camera_to_cdr,
    camera_to_msg,
    scan_from_msg,
    scan_to_cdr,
    serialize,
    tf_message_to_msg,
    typestore,
)
from tests.support.synthetic import Scene, scene_messages, write_bag, write_scene_bag


def params_file(tmp_path, **values):
    path = tmp_path / 'params.yaml'
    path.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}), encoding='utf-8')
    return path


def read_scans(path, topic):
    store = typestore()
    with AnyReader([path]) as reader:
        wanted = [c for c in reader.connections if c.topic == topic]
        return [
            scan_from_msg(store.deserialize_cdr(raw, LASER_SCAN))
            for _, _, raw in reader.messages(connections=wanted)
        ]


def test_odd_scans_are_listed_as_malformed_and_every_other_scan_is_fused(tmp_path, capsys):
    """Issue 26.7: a scan with angle_min -1e12 (here the last, released by the end-of-bag
    flush), a denormal increment and a NaN time_increment, with full_circle: ValueError or
    OverflowError from the stream, and `scanfuse bag` discarded the whole output. Now each is
    skipped and listed; every other scan is fused onto the 360-degree grid."""
    store = typestore()
    messages = scene_messages(Scene(duration=1.0))
    scans = [i for i, (topic, *_) in enumerate(messages) if topic == '/scan']
    odd = {
        scans[3]: {'angle_increment': 1e-40},  # a float32 denormal
        scans[6]: {'time_increment': math.nan},
        scans[-1]: {'angle_min': -1e12},
    }
    for index, changes in odd.items():
        topic, msgtype, log_time, raw = messages[index]
        scan = replace(scan_from_msg(store.deserialize_cdr(raw, LASER_SCAN)), **changes)
        messages[index] = (topic, msgtype, log_time, scan_to_cdr(scan, store))
    source = write_bag(tmp_path / 'in', messages)
    params = params_file(tmp_path, full_circle=True, use_tf=True)
    assert main(['bag', str(source), str(tmp_path / 'out'), '--params', str(params)]) == 0
    assert re.search(r'malformed messages skipped\W+3\b', capsys.readouterr().out)
    fused = read_scans(tmp_path / 'out', '/scan_fused')
    assert len(fused) == len(scans) - len(odd)
    increment = fused[0].angle_increment
    assert all(len(scan) == math.floor(2 * math.pi / increment + 1e-9) for scan in fused)
    assert all(np.isfinite(scan.ranges).any() for scan in fused)


def test_one_bad_tf_message_among_good_odometry_is_skipped_and_listed(tmp_path, capsys):
    """Issue 26.8: a single odom -> base_link transform with a NaN quaternion among 200 good
    ones refused the whole bag; now it is skipped and listed, as a bad /odom message is, and
    the scans are fused with the TF odometry of the others."""
    scene = Scene(duration=1.0)
    messages = scene_messages(scene)
    store = typestore()
    odometry = []
    for k in range(200):
        stamp = scene.start_ns + k * 5_000_000
        transform = StampedTransform('odom', 'base_link', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        message = tf_message_to_msg([replace(transform, stamp_ns=stamp)], store)
        if k == 100:
            rotation = message.transforms[0].transform.rotation
            rotation.x = rotation.y = rotation.z = rotation.w = math.nan
        odometry.append(('/tf', TF_MESSAGE, stamp, serialize(message, TF_MESSAGE, store)))
    source = write_bag(tmp_path / 'in', sorted(messages + odometry, key=lambda m: m[2]))
    assert main(['bag', str(source), str(tmp_path / 'out')]) == 0
    out = capsys.readouterr().out
    assert re.search(r'malformed messages skipped\W+1\b', out)
    assert re.search(r'skipped: /tf\W+/tf message 100 ', out)
    assert re.search(r'scans motion-compensated\W+10\b', out)
    fused = read_scans(tmp_path / 'out', '/scan_fused')
    assert len(fused) == len(scene.scan_stamps())


def _digest(path):
    files = sorted(p for p in path.rglob('*') if p.is_file())
    return hashlib.sha256(b''.join(p.read_bytes() for p in files)).hexdigest()


@pytest.mark.parametrize(
    ('damage', 'problem'),
    [
        ("UPDATE messages SET data = 'hello' WHERE id = 5", 'its data is str, not bytes'),
        ('UPDATE messages SET timestamp = -5 WHERE id = 5', 'its log time is -5 ns'),
    ],
    ids=['text-data', 'negative-timestamp'],
)
def test_a_db3_bag_with_text_data_or_a_negative_timestamp_is_one_clean_line(
    tmp_path, capsys, damage, problem
):
    """Issue 26.9: a db3 whose data column holds TEXT, or whose timestamp is negative, ended
    `scanfuse bag` with a traceback (TypeError, OverflowError); now one line, exit 1, the
    input untouched and no output."""
    source = write_scene_bag(tmp_path / 'in', Scene(duration=0.5), storage='sqlite3')
    (database,) = source.glob('*.db3')
    with contextlib.closing(sqlite3.connect(database)) as connection:
        connection.execute(damage)
        connection.commit()
    before = _digest(source)
    assert main(['bag', str(source), str(tmp_path / 'out')]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: cannot read bag ')
    assert problem in ' '.join(err.split())
    assert 'Traceback' not in err
    assert _digest(source) == before
    assert not (tmp_path / 'out').exists()
    assert not list(tmp_path.glob('.out.*'))


def test_a_camera_info_describing_a_giant_image_is_malformed_before_any_table(tmp_path):
    """Issue 26.2: a CameraInfo's width and height size the obstacle method's per-pixel
    tables, built when it arrives (100 000 x 100 000: 80 GB asked). The node's adapter
    counts it as malformed and allocates nothing for it; the scene's own camera still works."""
    from scanfuse.ros.live import LiveFusion

    scene = Scene(duration=0.3)
    store = typestore()
    live = LiveFusion(FusionConfig(use_tf=False), store=store)
    message = camera_to_msg(scene.camera, stamp_ns=scene.start_ns, store=store)
    message.width = message.height = 100_000
    live.on_scan(scene_scan_cdr(scene, store), 0.0)
    tracemalloc.start()
    try:
        live.on_camera_info(serialize(message, CAMERA_INFO, store), 0.01)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20
    assert live.stream.camera is None
    assert live.malformed == {'camera info': 1}
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=scene.start_ns, store=store), 0.02)
    assert live.stream.camera is not None
    assert (live.stream.camera.width, live.stream.camera.height) == (160, 120)


def scene_scan_cdr(scene: Scene, store) -> bytes:
    """The scene's first LiDAR scan as the node receives it."""
    return next(raw for topic, _, _, raw in scene_messages(scene) if topic == '/scan')


def test_the_nodes_fallback_pass_through_publishes_a_zero_as_nan():
    """Issue 26.5: when the node meets an unexpected error it publishes the LiDAR scan as it
    came (`LiveFusion.passthrough`); that too keeps the README's promise: a Hokuyo's 0.0 is
    NaN, and a scan without one goes out byte for byte."""
    from scanfuse.ros.live import LiveFusion

    store = typestore()
    live = LiveFusion(FusionConfig(), store=store)
    raw = scene_scan_cdr(Scene(duration=0.3), store)
    assert live.passthrough(raw) == raw
    scan = scan_from_msg(store.deserialize_cdr(raw, LASER_SCAN))
    ranges = scan.ranges.copy()
    ranges[::7] = 0.0
    hokuyo = scan_to_cdr(replace(scan, range_min=0.0, ranges=ranges), store)
    published = scan_from_msg(store.deserialize_cdr(live.passthrough(hokuyo), LASER_SCAN))
    assert np.isnan(published.ranges[::7]).all()
    finite = np.isfinite(published.ranges)
    assert np.all(published.ranges[finite] > 0.0)
    np.testing.assert_array_equal(published.ranges[finite], ranges[finite])
