"""The live node's decisions (`LiveFusion`) and parameters, without DDS.

Messages are the CDR bytes of a synthetic scene (`tests.support.synthetic`): a
wall at x = 2 m that the LiDAR sees and a 0.2 m high box whose front face is at
x = 1.2 m, below the LiDAR's plane, that only the camera sees. The LiDAR is at
the base origin, so straight ahead the fused range must be 1.2 m (the box) and
the LiDAR's own 2.0 m (the wall). Time advances as the messages' log times.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.ros.bag import fuse_bag
from scanfuse.ros.live import Level, LiveFusion, State
from scanfuse.ros.messages import (
    camera_to_cdr,
    depth_to_cdr,
    scan_from_cdr,
    typestore,
)
from scanfuse.ros.params import (
    NESTED,
    SCAN_ROW_CENTRE,
    all_param_specs,
    check_change,
    config_from_ros,
    fusion_param_specs,
)
from tests.support import REPOSITORY
from tests.support.malformed import garbage_messages
from tests.support.synthetic import Scene, scene_messages, write_bag

EXAMPLES = REPOSITORY / 'examples'
BOX = 1.2  # metres straight ahead: the box's front face
WALL = 2.0  # metres straight ahead: the wall in the LiDAR's plane
TOLERANCE = 0.02  # millimetre depth quantisation and pixel spacing at 1.2 m


def ahead(raw: bytes) -> float:
    """Smallest range of the two slots either side of angle 0 (360 readings over 1.5 pi)."""
    scan = scan_from_cdr(raw)
    index = round(-scan.angle_min / scan.angle_increment)
    return float(np.nanmin(scan.ranges[index - 1 : index + 2]))


def feed(live: LiveFusion, messages, *, until: float | None = None):
    """Give `live` every message at its log time; (log time s, output) of what it publishes."""
    start = messages[0][2]
    out = []
    for topic, _, log_time, raw in messages:
        now = (log_time - start) / 1e9
        if until is not None and now > until:
            break
        out.extend((now, o) for o in live.on_tick(now))
        if topic == '/scan':
            out.extend((now, o) for o in live.on_scan(raw, now))
        elif topic == '/camera/depth/image_raw':
            out.extend((now, o) for o in live.on_depth(raw, now))
        elif topic == '/camera/depth/camera_info':
            live.on_camera_info(raw, now)
        elif topic == '/tf_static':
            live.on_tf(raw, static=True)
    return out


def lidar_bytes(messages) -> dict[int, bytes]:
    return {scan_from_cdr(raw).stamp_ns: raw for topic, _, _, raw in messages if topic == '/scan'}


def test_live_fusion_equals_the_bag_processor(tmp_path):
    scene = Scene(duration=2.0)
    messages = scene_messages(scene)
    bag = write_bag(tmp_path / 'in.mcap', messages)
    fuse_bag(bag, tmp_path / 'out', config=FusionConfig())
    with AnyReader([tmp_path / 'out']) as reader:
        fused_topic = [c for c in reader.connections if c.topic == '/scan_fused']
        offline = {
            scan_from_cdr(raw).stamp_ns: bytes(raw)
            for _, _, raw in reader.messages(connections=fused_topic)
        }
    live = LiveFusion(FusionConfig(), pair_wait=0.1)
    outputs = feed(live, messages)
    outputs.extend((99.0, o) for o in live.on_tick(99.0))
    first_info = min(t for topic, _, t, _ in messages if topic.endswith('camera_info'))
    compared = 0
    for _, output in outputs:
        stamp = scan_from_cdr(output.fused).stamp_ns
        if stamp >= first_info:  # before the first CameraInfo the live node cannot fuse
            assert output.fused == offline[stamp]
            compared += 1
    assert compared == len([s for s in offline if s >= first_info])
    assert live.extrinsics_source.startswith('TF')


def test_fused_is_the_box_and_never_farther_than_the_lidar():
    messages = scene_messages(Scene(duration=1.0))
    lidar = lidar_bytes(messages)
    outputs = feed(LiveFusion(FusionConfig()), messages)
    fused = [o for _, o in outputs if o.with_camera]
    assert fused
    for output in fused:
        assert ahead(output.fused) == pytest.approx(BOX, abs=TOLERANCE)
        ranges = scan_from_cdr(output.fused).ranges
        original = scan_from_cdr(lidar[scan_from_cdr(output.fused).stamp_ns]).ranges
        finite = np.isfinite(original)
        assert np.all(ranges[finite] <= original[finite])


def test_camera_dropout_passes_the_lidar_through_and_recovers():
    config = FusionConfig()
    scene = Scene(duration=3.0, depth_gap=(1.0, 2.0))
    messages = scene_messages(scene)
    lidar = lidar_bytes(messages)
    start = messages[0][2]
    last_before = max(s for s in scene.depth_stamps() if s < start + 1e9)
    first_after = min(s for s in scene.depth_stamps() if s >= start + 2e9)
    live = LiveFusion(config)
    outputs = feed(live, messages)
    silent_from = (last_before - start) / 1e9 + scene.log_delay * 3 + config.camera_timeout
    for now, output in outputs:
        stamp = scan_from_cdr(output.fused).stamp_ns
        if silent_from < now < 2.0:
            assert output.fused == lidar[stamp]  # byte for byte the LiDAR's own scan
        if stamp > first_after + 0.1e9:
            assert output.with_camera
            assert ahead(output.fused) == pytest.approx(BOX, abs=TOLERANCE)
    assert any(silent_from < now < 2.0 for now, _ in outputs)


def test_health_warns_while_the_camera_is_silent_and_recovers():
    config = FusionConfig(camera_timeout=0.5)
    messages = scene_messages(Scene(duration=3.0, depth_gap=(1.0, 2.0)))
    live = LiveFusion(config)
    feed(live, messages, until=0.9)
    assert live.health(0.9).level is Level.OK
    feed(live, messages, until=1.7)
    health = live.health(1.7)
    assert (health.level, health.state) == (Level.WARN, State.PASS_THROUGH)
    feed(live, messages)
    # The report at 2.9 s covers the silence up to 2.0 s; the one after it is fusing only.
    assert live.health(2.9).level is Level.WARN
    assert live.health(3.0).level is Level.OK


def test_without_camera_info_the_lidar_passes_through_and_warns_once(caplog):
    messages = scene_messages(Scene(duration=2.0, publish_camera_info=False))
    lidar = lidar_bytes(messages)
    live = LiveFusion(FusionConfig())
    with caplog.at_level(logging.WARNING, logger='scanfuse'):
        outputs = feed(live, messages)
    assert len(outputs) == len(lidar)
    for _, output in outputs:
        assert output.fused == lidar[scan_from_cdr(output.fused).stamp_ns]
    warnings = [r for r in caplog.records if 'no CameraInfo' in r.getMessage()]
    assert len(warnings) == 1  # throttled: one per 5 s
    health = live.health(2.0)
    assert (health.level, health.state) == (Level.WARN, State.NO_CAMERA_INFO)


def test_lidar_silent_publishes_nothing_and_reports_error():
    messages = [m for m in scene_messages(Scene(duration=1.0)) if m[0] != '/scan']
    live = LiveFusion(FusionConfig(), lidar_timeout=1.0)
    assert feed(live, messages) == []
    health = live.health(1.5)
    assert (health.level, health.state) == (Level.ERROR, State.NO_LIDAR)


def test_malformed_messages_are_counted_logged_once_and_survived(caplog):
    store = typestore()
    scene = Scene(duration=1.0)
    messages = scene_messages(scene)
    live = LiveFusion(FusionConfig())
    feed(live, messages, until=0.5)
    wrong_size = depth_to_cdr(
        np.zeros((10, 10), dtype=np.uint16), frame_id='cam', stamp_ns=1, store=store
    )
    uncalibrated = scene.camera.__class__.from_intrinsics(
        10, 10, 1.0, 1.0, 4.5, 4.5, frame_id='cam'
    )
    bad_info = bytearray(camera_to_cdr(uncalibrated, stamp_ns=1, store=store))
    with caplog.at_level(logging.WARNING, logger='scanfuse'):
        for _ in range(3):
            for _, raw in garbage_messages():
                assert live.on_depth(raw, 0.6) == []
            assert live.on_depth(wrong_size, 0.6) == []
            assert live.on_scan(b'\x00\x01\x00\x00garbage', 0.6) == []
            live.on_camera_info(bytes(bad_info[:40]), 0.6)
    assert live.malformed == {'depth image': 9, 'scan': 3, 'camera info': 3}
    logged = [r.getMessage() for r in caplog.records if 'malformed' in r.getMessage()]
    assert len(logged) == 3
    after = feed(live, messages)
    assert any(o.with_camera for _, o in after)  # still fusing afterwards


def test_a_run_time_parameter_change_takes_effect():
    messages = scene_messages(Scene(duration=1.0))
    live = LiveFusion(FusionConfig())
    before = [o for _, o in feed(live, messages, until=0.5) if o.with_camera]
    assert ahead(before[-1].fused) == pytest.approx(BOX, abs=TOLERANCE)
    # Collision slab above the 0.2 m box: only the wall remains.
    live.reconfigure(FusionConfig(min_obstacle_height=0.25))
    after = [o for _, o in feed(live, messages) if o.with_camera]
    assert ahead(after[-1].fused) == pytest.approx(WALL, abs=TOLERANCE)


# ---------------------------------------------------------------- parameters


def test_every_fusion_setting_is_a_declared_parameter_with_a_description():
    specs = {spec.name: spec for spec in all_param_specs(FusionConfig())}
    assert set(FusionConfig.model_fields) - NESTED <= set(specs)  # sources: per-source names
    assert {'pair_wait', 'lidar_timeout'} <= set(specs)
    for spec in specs.values():
        assert spec.description
    assert specs['method'].choices == ('row', 'obstacle')
    assert specs['camera_pitch'].value_range == (-2 * math.pi, 2 * math.pi)
    assert specs['scan_row'].default == SCAN_ROW_CENTRE
    assert specs['scan_topic'].start_up_only
    assert not specs['min_obstacle_height'].start_up_only


def test_ros_values_round_trip_to_the_config():
    config = FusionConfig(scan_row=42, method='row', camera_x=0.25)
    values = {spec.name: spec.default for spec in fusion_param_specs(config)}
    assert config_from_ros(values) == config
    values['scan_row'] = SCAN_ROW_CENTRE
    assert config_from_ros(values).scan_row is None
    values['camera_x'] = 1  # an integer given to a double parameter (`-p camera_x:=1`)
    assert config_from_ros(values).camera_x == 1.0


def current_values() -> dict:
    return {spec.name: spec.default for spec in all_param_specs(FusionConfig())}


def test_safe_changes_are_accepted():
    assert check_change(current_values(), {'min_obstacle_height': 0.25, 'pair_wait': 0.05}) is None


def test_topic_changes_are_rejected_with_a_reason():
    reason = check_change(current_values(), {'scan_topic': '/other'})
    assert reason is not None
    assert 'scan_topic can only be set at start-up' in reason
    assert check_change(current_values(), {'scan_topic': '/scan'}) is None  # unchanged


def test_inconsistent_changes_are_rejected_with_a_reason():
    reason = check_change(current_values(), {'range_min': 20.0})
    assert reason is not None
    assert 'range_min (20.0) must be smaller than range_max' in reason
    reason = check_change(current_values(), {'pair_wait': 5.0})
    assert reason is not None
    assert 'pair_wait must be in [0.0, 1.0]' in reason


def test_config_from_ros_raises_config_error():
    values = current_values()
    values['method'] = 'magic'
    with pytest.raises(ConfigError, match='method'):
        config_from_ros(values)


# ---------------------------------------------------------------- examples


def test_example_parameter_file_names_declared_parameters():
    declared = {spec.name for spec in all_param_specs(FusionConfig())}
    for name in ('scanfuse_robot.yaml', 'scanfuse.yaml'):
        document = yaml.safe_load((EXAMPLES / name).read_text(encoding='utf-8'))
        params = document['scanfuse']['ros__parameters']
        assert set(params) <= declared, name


def test_repeated_camera_info_is_decoded_once_and_a_new_calibration_is_taken_up():
    scene = Scene()
    live = LiveFusion(FusionConfig(use_tf=False))
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=1), 0.0)
    first = live.stream.camera
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=2), 0.1)
    assert live.stream.camera is first  # same calibration, new stamp: the model is kept
    recalibrated = CameraModel.from_intrinsics(
        scene.width,
        scene.height,
        2 * scene.focal,
        2 * scene.focal,
        10.0,
        20.0,
        frame_id=scene.camera.frame_id,
    )
    live.on_camera_info(camera_to_cdr(recalibrated, stamp_ns=3), 0.2)
    assert live.stream.camera is not None
    assert (live.stream.camera.fx, live.stream.camera.cx, live.stream.camera.cy) == (
        2 * scene.focal,
        10.0,
        20.0,
    )


def test_a_camera_gap_between_two_reports_is_reported_by_the_next_one():
    # The gap (1.0 to 2.0 s, camera_timeout 0.3 s) opens and closes between the reports at
    # 0.9 s and 2.5 s: the report at 2.5 s must still say WARN, whatever the timer's phase.
    config = FusionConfig(camera_timeout=0.3)
    messages = scene_messages(Scene(duration=3.0, depth_gap=(1.0, 2.0)))
    live = LiveFusion(config)
    feed(live, messages, until=0.9)
    assert live.health(0.9).level is Level.OK
    feed(live, messages, until=2.5)
    health = live.health(2.5)
    assert (health.level, health.state) == (Level.WARN, State.PASS_THROUGH)
    assert live.health(2.6).level is Level.OK  # the window after it saw only fused scans


def test_health_reports_the_memory_s_scan_matches():
    # The synthetic scene has no odometry: no memory, so nothing is matched or refused.
    messages = scene_messages(Scene(duration=1.0))
    live = LiveFusion(FusionConfig())
    feed(live, messages)
    assert live.health(1.0).values['memory scan matches (accepted / refused)'] == '0 / 0'
