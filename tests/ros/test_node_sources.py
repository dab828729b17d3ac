"""The live node's adapter (`LiveFusion`) with named sources, its hot path and its health.

No DDS: CDR bytes of the synthetic scene (`tests.support.synthetic`) are fed at their log
times. The scene: a wall at x = 2 m the front LiDAR sees, a box at 1.2 m only the camera
sees; a rear LiDAR (yaw pi at the base origin) sees a back wall at x = -1.5 m.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from scanfuse.config import FusionConfig
from scanfuse.ros.live import Level, LiveFusion, State
from scanfuse.ros.messages import (
    CAMERA_INFO,
    camera_to_cdr,
    depth_to_cdr,
    scan_from_cdr,
    scan_to_cdr,
    typestore,
)
from scanfuse.ros.params import config_from_ros, source_list_spec, source_param_specs
from scanfuse.scan import Scan
from scanfuse.sources import LidarSource
from tests.support import REPOSITORY
from tests.support.synthetic import REAR_TOPIC, Scene, scene_messages, two_lidar_messages

BOX = 1.2
BACK_WALL = 1.5
TWO_LIDARS = {
    'lidars': ['front', 'rear'],
    'front': {'topic': '/scan', 'z': 0.3},
    'rear': {'topic': REAR_TOPIC, 'z': 0.3, 'yaw': math.pi},
}


def feed(live: LiveFusion, messages, *, sources: dict[str, str] | None = None):
    """Every message at its log time (s from the first); the outputs published."""
    sources = sources or {}
    start = messages[0][2]
    out = []
    for topic, _, log_time, raw in messages:
        now = (log_time - start) / 1e9
        out += live.on_tick(now)
        if topic in sources:
            out += live.on_scan(raw, now, source=sources[topic])
        elif topic == '/scan':
            out += live.on_scan(raw, now)
        elif topic == '/camera/depth/image_raw':
            out += live.on_depth(raw, now)
        elif topic == '/camera/depth/camera_info':
            live.on_camera_info(raw, now)
        elif topic == '/tf_static':
            live.on_tf(raw, static=True)
    return out


def bearings(scan: Scan) -> np.ndarray:
    return scan.angle_min + scan.angle_increment * np.arange(len(scan))


def test_a_second_lidar_reading_reaches_the_fused_scan():
    scene = Scene(duration=1.0)
    live = LiveFusion(FusionConfig.from_dict(TWO_LIDARS))
    outputs = feed(
        live, two_lidar_messages(scene, back_wall=BACK_WALL), sources={REAR_TOPIC: 'rear'}
    )
    fused = [scan_from_cdr(o.fused) for o in outputs if o.with_camera]
    assert len(fused) >= 5
    half = scene.angle_increment / 2
    for scan in fused:
        b = bearings(scan)
        # Behind the LiDAR's side (108 to 133 degrees, either side) only the rear LiDAR sees
        # the back wall: r = 1.5 / |cos(bearing)| for a point within half a slot of b, and
        # |cos| grows with |b| there, so r lies between the values at b -+ half a slot.
        behind = (np.abs(b) >= 0.6 * math.pi) & (np.abs(b) <= 0.74 * math.pi)
        near = BACK_WALL / np.abs(np.cos(np.abs(b[behind]) + half))
        far = BACK_WALL / np.abs(np.cos(np.abs(b[behind]) - half))
        ranges = scan.ranges[behind]
        assert np.all((ranges >= near - 1e-3) & (ranges <= far + 1e-3))
        ahead = round(-scan.angle_min / scan.angle_increment)
        assert np.nanmin(scan.ranges[ahead - 1 : ahead + 2]) == pytest.approx(BOX, abs=0.02)
    values = live.health(2.0).values
    assert values['source rear'].startswith(f'used {len(outputs)},')


def test_a_named_source_that_never_arrives_is_reported():
    scene = Scene(duration=1.0)
    live = LiveFusion(FusionConfig.from_dict(TWO_LIDARS))
    outputs = feed(live, scene_messages(scene))  # no rear scans at all
    assert outputs
    health = live.health(1.0)
    assert (health.level, health.state) == (Level.WARN, State.SOURCE_MISSING)
    assert 'rear' in health.message
    assert health.values['source rear'] == f'used 0, missing {len(outputs)}, no mounting 0'


def test_source_parameters_come_from_the_source_models():
    lists = source_list_spec('lidars', [])
    assert (lists.name, lists.default, lists.start_up_only) == ('lidars', [], True)
    specs = {spec.name: spec for spec in source_param_specs('lidars', 'rear', None)}
    fields = set(LidarSource.model_fields) - {'name'}
    assert set(specs) == {f'rear.{field}' for field in fields}
    assert specs['rear.topic'].default == ''  # required: the config says so when unset
    assert specs['rear.topic'].start_up_only
    assert (
        specs['rear.max_time_offset'].default == LidarSource.model_fields['max_time_offset'].default
    )
    assert specs['rear.yaw'].bounds.inclusive == (-2 * math.pi, 2 * math.pi)
    assert specs['rear.yaw'].description == LidarSource.model_fields['yaw'].description
    camera = {spec.name: spec for spec in source_param_specs('cameras', 'back', None)}
    assert camera['back.min_obstacle_height'].default is None  # unset: the global slab


def test_dotted_ros_values_make_the_named_sources():
    values = {
        'lidars': ['front', 'rear'],
        'cameras': [],
        'clouds': [],
        **{spec.name: spec.default for spec in source_param_specs('lidars', 'front', None)},
        **{spec.name: spec.default for spec in source_param_specs('lidars', 'rear', None)},
    }
    values.update({'front.topic': '/f', 'rear.topic': '/r', 'rear.yaw': 3.0})
    config = config_from_ros(values)
    assert config.scan_topic == '/f'
    assert [(s.name, s.topic, s.yaw) for s in config.sources.lidars] == [
        ('front', '/f', 0.0),
        ('rear', '/r', 3.0),
    ]
    del values['rear.topic']
    values['rear.topic'] = ''  # declared but never set
    with pytest.raises(Exception, match=r'lidars\.1\.topic: Field required'):
        config_from_ros(values)


# ---------------------------------------------------------------- hot path


def test_depth_pixels_reach_the_stream_without_a_copy():
    scene = Scene()
    live = LiveFusion(FusionConfig())
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=1), 0.0)
    raw = depth_to_cdr(scene.depth_mm(), frame_id=scene.camera.frame_id, stamp_ns=1)
    live.on_depth(raw, 0.0)
    kept = live.stream.sources.cameras['camera'].frames[-1].depth
    assert np.shares_memory(kept, np.frombuffer(raw, dtype=np.uint8))


def test_obstacle_tables_are_built_when_camera_info_arrives():
    scene = Scene()
    live = LiveFusion(FusionConfig(use_tf=False))
    lidar = Scan(
        angle_min=scene.angle_min,
        angle_max=scene.angle_min + scene.angle_increment * (scene.readings - 1),
        angle_increment=scene.angle_increment,
        range_min=0.05,
        range_max=10.0,
        ranges=scene.lidar_ranges(),
        frame_id='laser',
        stamp_ns=10,
    )
    # The scan passes through (no CameraInfo): its grid is now known.
    assert not live.on_scan(scan_to_cdr(lidar), 0.0)[0].with_camera
    assert live.stream.pipeline.cached[0] == 0
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=1), 0.01)
    assert live.stream.pipeline.cached[0] == 1  # before any depth frame or paired scan


@pytest.mark.parametrize(
    'output', [{'output_frame': 'base_link'}, {'full_circle': True}, {'angle_increment': 0.01}]
)
def test_obstacle_tables_are_built_for_the_output_frame_and_grid(output):
    # The tables built at CameraInfo are those the first fused scan uses: none is built then.
    scene = Scene(duration=0.5)
    live = LiveFusion(FusionConfig(use_tf=False, **output))
    messages = scene_messages(scene)
    first_scan = next(raw for topic, _, _, raw in messages if topic == '/scan')
    live.on_scan(first_scan, 0.0)
    info = next(raw for topic, _, _, raw in messages if topic == '/camera/depth/camera_info')
    live.on_camera_info(info, 0.01)
    assert live.stream.pipeline.cached[0] == 1
    outputs = feed(live, messages)
    assert any(o.with_camera for o in outputs)
    assert live.stream.pipeline.cached[0] == 1


# ---------------------------------------------------------------- health (issue 11)


def test_processing_slower_than_the_scan_period_is_reported():
    # Scans stamped 10 us apart: any fusion (a 160x120 image, 360 readings) takes longer
    # than 80 % of that period, so the node cannot keep up with such a LiDAR.
    scene = Scene()
    live = LiveFusion(FusionConfig(use_tf=False))
    live.on_camera_info(camera_to_cdr(scene.camera, stamp_ns=0), 0.0)
    live.on_depth(
        depth_to_cdr(scene.depth_mm(), frame_id=scene.camera.frame_id, stamp_ns=1_000_000), 0.0
    )
    base = Scan(
        angle_min=scene.angle_min,
        angle_max=scene.angle_min + scene.angle_increment * (scene.readings - 1),
        angle_increment=scene.angle_increment,
        range_min=0.05,
        range_max=10.0,
        ranges=scene.lidar_ranges(),
        frame_id='laser',
    )
    fused = 0
    for i in range(20):
        raw = scan_to_cdr(base.with_ranges(base.ranges, stamp_ns=1_000_000 + 10_000 * i))
        fused += sum(o.with_camera for o in live.on_scan(raw, 0.001 * i))
    assert fused == 20
    health = live.health(0.03)
    assert (health.level, health.state) == (Level.WARN, State.TOO_SLOW)
    assert 'processing too slow' in health.message
    assert 'at a scan period of 0.0 ms' in health.message


def test_camera_info_with_nan_distortion_is_reported_as_unusable():
    scene = Scene(duration=1.0)
    store = typestore()
    good = camera_to_cdr(scene.camera, stamp_ns=1, store=store)
    message = store.deserialize_cdr(good, CAMERA_INFO)
    message.d = np.array([math.nan, 0.0, 0.0, 0.0, 0.0])
    nan_info = bytes(store.serialize_cdr(message, CAMERA_INFO))
    messages = [
        (topic, kind, log, nan_info if topic.endswith('camera_info') else raw)
        for topic, kind, log, raw in scene_messages(scene)
    ]
    live = LiveFusion(FusionConfig())
    outputs = feed(live, messages)
    lidar = {scan_from_cdr(raw).stamp_ns: raw for t, _, _, raw in messages if t == '/scan'}
    assert outputs
    for output in outputs:  # the camera contributes nothing: each LiDAR scan as it came
        assert not output.with_camera
        assert output.fused == lidar[scan_from_cdr(output.fused).stamp_ns]
    health = live.health(1.0)
    assert (health.level, health.state) == (Level.WARN, State.CAMERA_UNUSABLE)
    assert 'the camera contributes nothing' in health.message
    assert 'distortion' in health.message
    # A usable calibration afterwards: the warning goes with it.
    live.on_camera_info(good, 1.1)
    assert live.health(1.2).state is not State.CAMERA_UNUSABLE


def test_warm_up_loads_the_cloud_kernel_for_both_coordinate_types_only_with_a_cloud():
    # In a fresh interpreter, so no earlier test has run the kernel: after warm_up the node
    # with a cloud source has it ready for float32 and float64 clouds; one without has not.
    script = (
        'import sys\n'
        'from scanfuse.config import FusionConfig\n'
        'from scanfuse.ros.live import LiveFusion\n'
        'from scanfuse.convert import cloud_kernel\n'
        'config = FusionConfig.from_ros_params(sys.argv[1]) if sys.argv[1] else FusionConfig()\n'
        'LiveFusion(config).warm_up()\n'
        'print(len(cloud_kernel.cloud_ranges.signatures))\n'
    )
    counts = []
    for params in (str(REPOSITORY / 'examples' / 'scanfuse_multi.yaml'), ''):
        done = subprocess.run(
            [sys.executable, '-c', script, params],
            capture_output=True,
            text=True,
            cwd=REPOSITORY,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        counts.append(int(done.stdout.split()[-1]))
    assert counts[0] >= 2
    assert counts[1] == 0
