"""examples/nav2_scanfuse.yaml and examples/slam_toolbox_scanfuse.yaml agree with scanfuse.

Every topic, frame, range, height and timeout the two files name is checked against what
the node declares (its parameters' defaults) and what it publishes (the fused scans
`LiveFusion`, the node's core, makes of a synthetic scene whose LiDAR has the RPLIDAR A2's
range_max, the LiDAR of examples/scanfuse_robot.yaml). Nav2's and slam_toolbox's behaviour
quoted here is upstream's (Jazzy sources named in the files' comments).
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import yaml

from scanfuse.config import FusionConfig
from scanfuse.ros.live import LiveFusion
from scanfuse.ros.messages import scan_from_cdr
from scanfuse.ros.params import NodeSettings, all_param_specs, field_bounds
from tests.support import REPOSITORY
from tests.support.synthetic import Scene, scene_messages

EXAMPLES = REPOSITORY / 'examples'
NAV2 = yaml.safe_load((EXAMPLES / 'nav2_scanfuse.yaml').read_text(encoding='utf-8'))
SLAM = yaml.safe_load((EXAMPLES / 'slam_toolbox_scanfuse.yaml').read_text(encoding='utf-8'))
COSTMAPS = ('local_costmap', 'global_costmap')
# Keys that name a topic, frame, range, height or timeout.
NAMED = re.compile(r'topic|frame|range|height|timeout')


def declared(name: str):
    """The node's declared default of a parameter."""
    return {spec.name: spec.default for spec in all_param_specs(FusionConfig())}[name]


def costmap(name: str) -> dict:
    return NAV2[name][name]['ros__parameters']


def obstacle_source(name: str) -> dict:
    layer = costmap(name)['obstacle_layer']
    (source,) = layer['observation_sources'].split()  # Nav2 takes a space-separated string
    return layer[source]


def monitor() -> dict:
    return NAV2['collision_monitor']['ros__parameters']


def slam() -> dict:
    return SLAM['slam_toolbox']['ros__parameters']


def leaves(tree: dict, prefix: str = ''):
    for key, value in tree.items():
        path = f'{prefix}.{key}' if prefix else str(key)
        if isinstance(value, dict):
            yield from leaves(value, path)
        else:
            yield path, value


@pytest.fixture(scope='module')
def run():
    """What the node's core publishes for a scene seen by an RPLIDAR A2: fused and instant."""
    pytest.importorskip('mujoco')
    from scanfuse.sim.sensors import LIDARS  # MuJoCo-only module: imported after the skip

    scene = Scene(lidar_range_max=LIDARS['rplidar-a2'].range_max)
    live = LiveFusion(FusionConfig())
    messages = scene_messages(scene)
    start = messages[0][2]
    outputs = []
    for topic, _, log_time, raw in messages:
        now = (log_time - start) / 1e9
        if topic == '/scan':
            outputs.extend(live.on_scan(raw, now))
        elif topic == '/camera/depth/image_raw':
            outputs.extend(live.on_depth(raw, now))
        elif topic == '/camera/depth/camera_info':
            live.on_camera_info(raw, now)
        elif topic == '/tf_static':
            live.on_tf(raw, static=True)
    fused = [scan_from_cdr(o.fused) for o in outputs if o.with_camera]
    instant = [scan_from_cdr(o.instant) for o in outputs if o.with_camera and o.instant]
    assert fused, 'the scene gave no fused scan'
    return scene, fused, instant


@pytest.fixture(scope='module')
def published(run):
    """(scene, fused scans): what /scan_fused carries."""
    scene, fused, _ = run
    return scene, fused


@pytest.fixture(scope='module')
def instant(run):
    """The instantaneous scans (instant_topic): what slam_toolbox reads."""
    return run[2]


# ---------------------------------------------------------------- topics and frames


def test_every_consumer_reads_the_fused_topic():
    fused_topic = declared('fused_topic')
    for name in COSTMAPS:
        assert obstacle_source(name)['topic'] == fused_topic, name
        assert obstacle_source(name)['data_type'] == 'LaserScan', name
    sources = [monitor()[source] for source in monitor()['observation_sources']]
    assert [(s['type'], s['topic']) for s in sources] == [('scan', fused_topic)]


def test_slam_reads_the_scan_without_the_memory(instant):
    # The memory (on by default) goes to the costmaps; SLAM takes the instantaneous scan,
    # which the node publishes while the memory is on.
    assert declared('memory') is True
    assert slam()['scan_topic'] == declared('instant_topic') != declared('fused_topic')
    assert instant, 'the node published no instantaneous scan'


def test_frames_are_the_ones_scanfuse_uses(published):
    base, odom = declared('base_frame'), declared('odom_frame')
    for name in COSTMAPS:
        assert costmap(name)['robot_base_frame'] == base, name
        # No sensor_frame: Nav2 takes the scan's frame_id as the ray origin, and scanfuse
        # publishes in the LiDAR's frame.
        assert 'sensor_frame' not in obstacle_source(name), name
    assert costmap('local_costmap')['global_frame'] == odom
    assert costmap('global_costmap')['global_frame'] == slam()['map_frame']
    assert (monitor()['base_frame_id'], monitor()['odom_frame_id']) == (base, odom)
    assert (slam()['base_frame'], slam()['odom_frame']) == (base, odom)
    _, fused = published
    assert {scan.frame_id for scan in fused} == {'laser'}  # the scene's LiDAR frame


# ---------------------------------------------------------------- heights and ranges


def test_height_windows_keep_the_lidar_plane_and_are_scanfuses_slab():
    slab = (declared('min_obstacle_height'), declared('max_obstacle_height'))
    lidar_height = declared('lidar_height')
    # A LaserScan's points lie in the LiDAR's plane: at the LiDAR's height above the floor.
    assert slab[0] <= lidar_height <= slab[1]
    for name in COSTMAPS:
        layer = costmap(name)['obstacle_layer']
        source = obstacle_source(name)
        assert (layer['min_obstacle_height'], layer['max_obstacle_height']) == slab, name
        assert (source['min_obstacle_height'], source['max_obstacle_height']) == slab, name


def test_clearing_stops_at_the_camera_range_and_marking_inside_it():
    config = FusionConfig()
    # The camera reports up to range_max from itself; from the LiDAR's origin that reaches
    # at least range_max minus their horizontal distance (0 with the default mounting).
    offset = math.hypot(config.camera_x - config.lidar_x, config.camera_y - config.lidar_y)
    for name in COSTMAPS:
        source = obstacle_source(name)
        assert source['marking'] is True, name
        assert source['clearing'] is True, name
        assert 0.0 < source['raytrace_max_range'] <= declared('range_max') - offset, name
        assert source['obstacle_max_range'] < source['raytrace_max_range'], name
        # Remembered obstacles lie within memory_radius of the base origin: all are marked.
        reach = declared('memory_radius') + math.hypot(config.lidar_x, config.lidar_y)
        assert reach <= source['obstacle_max_range'], name
        assert source['obstacle_min_range'] == source['raytrace_min_range'] == 0.0, name
    # The local window holds a whole ray in every direction.
    local = costmap('local_costmap')
    ray = obstacle_source('local_costmap')['raytrace_max_range']
    assert min(local['width'], local['height']) / 2 >= ray


def test_free_rays_clear_and_are_never_marked(published):
    scene, fused = published
    ranges = np.concatenate([scan.ranges for scan in fused])
    assert np.isposinf(ranges).any()  # scanfuse does publish +Inf for free rays (REP-117)
    range_max = {scan.range_max for scan in fused}
    # merge_scans: the larger of the LiDAR's and the camera's limits.
    assert range_max == {max(scene.lidar_range_max, declared('range_max'))}
    for name in COSTMAPS:
        source = obstacle_source(name)
        assert source['inf_is_valid'] is True, name
        # Nav2 puts a +Inf reading at range_max - 1e-4 m: beyond marking, as far as clearing.
        assert min(range_max) - 1e-4 > source['obstacle_max_range'], name
        assert min(range_max) - 1e-4 >= source['raytrace_max_range'], name
    # And the box only the camera sees (1.2 m ahead) is within marking range.
    ahead = [float(np.nanmin(scan.ranges[np.abs(scan.angles()) < 0.02])) for scan in fused]
    assert max(ahead) == pytest.approx(scene.box_x, abs=0.02)
    assert max(ahead) < obstacle_source('local_costmap')['obstacle_max_range']


def test_slam_range_covers_the_camera_and_is_not_clipped(published, instant):
    scene, fused = published
    max_laser_range = slam()['max_laser_range']
    # Not below the camera's range_max (its far obstacles would be cut); not above the
    # scan's range_max (slam_toolbox would clip it with a warning).
    assert declared('range_max') <= max_laser_range <= min(scan.range_max for scan in instant)
    # The instantaneous scan has the fused scan's grid, frame and limits: one sensor to SLAM.
    assert {(len(s), s.frame_id, s.range_max) for s in instant} == {
        (scene.readings, 'laser', fused[0].range_max)
    }


def test_collision_monitor_keeps_the_fused_scan_however_long_the_node_waits():
    longest_wait = field_bounds(NodeSettings.model_fields['pair_wait']).high
    assert longest_wait is not None
    assert monitor()['source_timeout'] >= longest_wait
    assert monitor()['base_shift_correction'] is True


# ---------------------------------------------------------------- QoS


def test_the_fused_scan_qos_serves_every_consumer():
    pytest.importorskip('rclpy')
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        QoSCompatibility,
        QoSProfile,
        ReliabilityPolicy,
        qos_check_compatible,
    )

    from scanfuse.ros.node import OUTPUT_QOS

    assert OUTPUT_QOS.reliability is ReliabilityPolicy.RELIABLE
    assert OUTPUT_QOS.durability is DurabilityPolicy.VOLATILE

    def sensor_data(depth: int) -> QoSProfile:
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=depth,
            reliability=ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.VOLATILE,
        )

    subscribers = {
        'obstacle layer (SensorDataQoS(50))': sensor_data(50),
        'collision monitor (SensorDataQoS())': sensor_data(5),
        'slam_toolbox (rmw_qos_profile_sensor_data)': sensor_data(5),
        'RViz (reliable)': QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
    }
    for name, profile in subscribers.items():
        compatibility, reason = qos_check_compatible(OUTPUT_QOS, profile)
        assert compatibility is not QoSCompatibility.ERROR, f'{name}: {reason}'


# ---------------------------------------------------------------- nothing left unchecked

# What the tests above check, and what is Nav2's own business.
CHECKED = {
    *(
        f'{name}.{name}.ros__parameters.{key}'
        for name in COSTMAPS
        for key in (
            'global_frame',
            'robot_base_frame',
            'obstacle_layer.min_obstacle_height',
            'obstacle_layer.max_obstacle_height',
            'obstacle_layer.scan_fused.topic',
            'obstacle_layer.scan_fused.min_obstacle_height',
            'obstacle_layer.scan_fused.max_obstacle_height',
            'obstacle_layer.scan_fused.obstacle_max_range',
            'obstacle_layer.scan_fused.obstacle_min_range',
            'obstacle_layer.scan_fused.raytrace_max_range',
            'obstacle_layer.scan_fused.raytrace_min_range',
        )
    ),
    'local_costmap.local_costmap.ros__parameters.height',
    'collision_monitor.ros__parameters.base_frame_id',
    'collision_monitor.ros__parameters.odom_frame_id',
    'collision_monitor.ros__parameters.source_timeout',
    'collision_monitor.ros__parameters.scan_fused.topic',
    'slam_toolbox.ros__parameters.scan_topic',
    'slam_toolbox.ros__parameters.base_frame',
    'slam_toolbox.ros__parameters.odom_frame',
    'slam_toolbox.ros__parameters.map_frame',
    'slam_toolbox.ros__parameters.max_laser_range',
}
NOT_SCANFUSES = {
    'collision_monitor.ros__parameters.cmd_vel_in_topic',
    'collision_monitor.ros__parameters.cmd_vel_out_topic',
    'collision_monitor.ros__parameters.state_topic',
    'collision_monitor.ros__parameters.stop_pub_timeout',
    'collision_monitor.ros__parameters.StopCircle.polygon_pub_topic',
    'slam_toolbox.ros__parameters.transform_timeout',  # TF's timing, not scanfuse's
}


def test_every_topic_frame_range_height_and_timeout_named_is_checked():
    named = {
        path
        for document in (NAV2, SLAM)
        for path, _ in leaves(document)
        if NAMED.search(path.rsplit('.', 1)[-1])
    }
    assert named == CHECKED | NOT_SCANFUSES
