"""Regression tests of issue 26 through the stream's API: what named sources, clouds,
fragments and pass-through publish from a driver's error values and odd scans."""

from __future__ import annotations

import logging
import math
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError, InputError
from scanfuse.frames import StampedTransform
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.stream import FusionStream
from tests.support.render import depth_image, square_room_ranges
from tests.test_sources import (
    BOX_AHEAD,
    BOX_BEHIND,
    CAMERA,
    HALF,
    NS,
    PITCH,
    base_lidar,
    camera_pose,
    cloud_config,
    front_and_rear_cameras,
    lidar_scan,
    reading,
    two_lidars,
)

FRONT, FRONT_YAW = (0.3, 0.2), math.pi / 4
REAR, REAR_YAW = (-0.3, -0.2), -3 * math.pi / 4


def test_a_second_lidars_zero_no_return_is_not_an_obstacle_at_its_mount():
    """Issue 26.3: a rear LiDAR publishing range_min 0 and 0.0 for a failed return (a
    Hokuyo) put an obstacle at its own mount, 0.72 m behind the front one; its 0.0 is no
    reading, as the first LiDAR's is."""
    stream: FusionStream[int] = FusionStream(two_lidars())
    fov = math.radians(270)
    front = lidar_scan(FRONT, FRONT_YAW, 3600, fov, 'front', grid_fov=2 * math.pi)
    rear = lidar_scan(REAR, REAR_YAW, 5400, fov, 'rear')
    ranges = rear.ranges.copy()
    ranges[::10] = 0.0  # every tenth return failed
    rear = replace(rear, range_min=0.0, ranges=ranges)
    stream.add_scan(rear, 0, NS, source='rear')
    (out,) = stream.add_scan(front, 1, NS + 1)
    assert out.fused is not None
    truth = square_room_ranges(FRONT, FRONT_YAW, front.angles(), HALF)
    # The rear LiDAR still fills the front one's gap (its other nine readings in ten).
    assert np.isfinite(out.fused.ranges).all()
    np.testing.assert_allclose(out.fused.ranges, truth, atol=0.01)


def test_a_clouds_zero_points_are_no_returns_dropped_and_counted():
    """Issue 26.4: Ouster, Hesai and Livox drivers write (0, 0, 0) for a beam with no return;
    those points made an obstacle at the cloud sensor's own mount (here 0.5 m behind the
    LiDAR, its height inside the slab)."""
    config = cloud_config(points={'topic': '/points', 'x': -0.5, 'z': 0.3})
    stream: FusionStream[int] = FusionStream(config)
    ys = np.linspace(-0.1, 0.1, 21)
    heights = np.linspace(0.05, 0.2, 6)
    # A box face 1.5 m ahead of the base: x 2.0 m and z (height - 0.3) m in the cloud's frame.
    face = np.array([(2.0, y, h - 0.3) for y in ys for h in heights])
    no_return = np.zeros((500, 3))
    stream.add_cloud(NS, np.vstack([no_return, face, no_return]), NS, 'livox', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is not None
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)
    assert reading(out.fused, math.pi) == math.inf  # nothing behind: no obstacle at 0.5 m
    assert np.nanmin(out.fused.ranges) == pytest.approx(1.5, abs=0.01)
    assert stream.sources.counts.no_return == {'points': 1000}


def hokuyo_scan(stamp=NS, *, angle_min=-0.75 * math.pi, count=540, increment=None):
    """A 270-degree scan with range_min 0 (as a Hokuyo URG publishes it): a wall 2 m away,
    and 0.0 for every ninth return that failed."""
    increment = 1.5 * math.pi / count if increment is None else increment
    ranges = np.full(count, 2.0, dtype=np.float32)
    ranges[::9] = 0.0
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (count - 1),
        angle_increment=increment,
        range_min=0.0,
        range_max=30.0,
        ranges=ranges,
        time_increment=1e-5,
        frame_id='laser',
        stamp_ns=stamp,
    )


def published(out, token_scan: Scan) -> Scan:
    """What an adapter publishes for `out`: the fused scan, else the LiDAR's own message."""
    return token_scan if out.fused is None else out.fused


@pytest.mark.parametrize(
    'changes',
    [{}, {'full_circle': True}, {'assemble_fragments': True}],
    ids=['pass-through', 'full_circle', 'fragments'],
)
def test_a_passed_through_scan_publishes_a_zero_as_nan(changes):
    """Issue 26.5: the README promises a Hokuyo's 0.0 is published as NaN; passed through
    (no camera), the scan kept its zeros: republished as they came, or rebuilt with them
    (full_circle, fragments). Every published finite reading lies inside its limits and is
    positive."""
    stream: FusionStream[Scan] = FusionStream(FusionConfig(memory=False, **changes))
    out = []
    if changes.get('assemble_fragments'):
        # Three fragments of 180 readings each, one revolution of 270 degrees, twice.
        for turn in range(2):
            for piece in range(3):
                whole = hokuyo_scan(stamp=NS * (turn + 1) + piece * 1000)
                start = piece * 180
                fragment = replace(
                    whole,
                    angle_min=whole.angle_min + start * whole.angle_increment,
                    angle_max=whole.angle_min + (start + 179) * whole.angle_increment,
                    ranges=whole.ranges[start : start + 180],
                )
                out += stream.add_scan(fragment, fragment, NS * (turn + 1) + piece * 1000)
        out += stream.finish()
    else:
        scan = hokuyo_scan()
        out = stream.add_scan(scan, scan, NS)
    assert out
    for output in out:
        scan = published(output, output.token)
        finite = np.isfinite(scan.ranges)
        assert finite.sum() >= 400
        assert np.all(scan.ranges[finite] > 0.0)
        assert np.all(scan.ranges[finite] >= scan.range_min)
        assert np.all(scan.ranges[finite] <= scan.range_max)
        np.testing.assert_array_equal(scan.ranges[finite], 2.0)


def test_a_passed_through_scan_without_error_values_keeps_its_own_bytes():
    """Issue 26.5: only a scan that holds a driver's error value is published anew."""
    scan = replace(hokuyo_scan(), ranges=np.full(540, 2.0, dtype=np.float32))
    stream: FusionStream[Scan] = FusionStream(FusionConfig(memory=False))
    (out,) = stream.add_scan(scan, scan, NS)
    assert out.fused is None  # the adapter republishes the message as it came


def moving_stream(**changes) -> FusionStream[int]:
    """Memory on, with odometry of a robot driving at 0.2 m/s."""
    stream: FusionStream[int] = FusionStream(FusionConfig(**changes))
    for k in range(30):
        stream.add_odometry(k * NS // 10, PlanarPose(0.02 * k, 0.0, 0.0))
    return stream


@pytest.mark.parametrize(
    ('changes', 'problem'),
    [
        ({'angle_increment': 1e-6}, r'makes 6.28e\+06 readings a turn \(at most 131072\)'),
        ({'angle_increment': 5e-324}, 'readings a turn'),
        ({'angle_increment': 13.0}, 'is more than a turn'),
        ({'angle_min': -1e12}, 'not both within'),
        ({'time_increment': math.nan}, 'time_increment nan s'),
        ({'time_increment': math.inf}, 'time_increment inf s'),
    ],
)
def test_a_scan_whose_numbers_would_size_allocations_is_refused_where_it_enters(changes, problem):
    """Issues 26.2 and 26.7: an increment of 1e-7 made the memory projection and full_circle
    allocate 3 * 2 pi / increment values per scan (1.4 GB; 1e-9 was OOM-killed); a huge
    angle_min, a denormal or over-a-turn increment, a NaN time_increment raised ValueError,
    OverflowError or ZeroDivisionError from the middle of the stream. Each is refused at
    add_scan (InputError), nothing is allocated for it, and the stream goes on."""
    stream = moving_stream(full_circle=True)
    good = hokuyo_scan(stamp=NS)
    odd = replace(good, stamp_ns=NS + NS // 10, **changes)
    odd = replace(odd, angle_max=odd.angle_min + odd.angle_increment * (len(odd) - 1))
    tracemalloc.start()
    try:
        with pytest.raises(InputError, match=problem):
            stream.add_scan(odd, 1, NS + NS // 10)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20  # bytes: no grid of the odd scan's size
    out = stream.add_scan(good, 0, NS)
    out += stream.add_scan(replace(good, stamp_ns=2 * NS // 10 + NS), 2, NS + 2 * NS // 10)
    out += stream.finish()
    assert [o.token for o in out] == [0, 2]
    assert all(len(o.lidar) == 720 for o in out)  # 360 degrees of 0.5-degree readings


def test_the_memory_scan_publishes_no_reading_below_its_range_min():
    """Issue 26.12: after the robot pushed into a shelf, /scan_memory held readings below its
    own range_min (4 mm against 0.05 m); REP-117: a published finite reading lies in its
    limits. The box's front face 1.5 m ahead is remembered, then the robot drives to 3 cm
    short of it without the camera: the face's middle is nearer than range_min, its ends
    (0.1 m to the sides) are not."""
    from tests.test_memory import BOX, Robot, config

    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan()
    robot.move_to(PlanarPose(BOX.x_min - 0.03, 0.0, 0.0), 3.0)
    out = robot.scan(camera=False)
    memory = out.memory_scan
    assert memory is not None
    finite = np.isfinite(memory.ranges)
    assert finite.any()  # the face's ends
    assert np.all(memory.ranges[finite] >= memory.range_min)
    assert np.all(memory.ranges[finite] <= memory.range_max)
    assert out.fused is not None
    fused = np.isfinite(out.fused.ranges)
    assert np.all(out.fused.ranges[fused] >= out.fused.range_min)


@pytest.mark.parametrize(
    'points',
    [
        np.array([[1.5, 0.0], [1.5, 0.05], [1.5, 0.1]]),  # N x 2
        np.array([[1.5, 0.0, 0.1, 7.0], [1.5, 0.05, 0.1, 7.0]]),  # N x 4: intensity too
        np.array([1.5, 0.0, 0.1, 1.5, 0.05, 0.1]),  # 1-D
        np.array([['1.5', '0.0', '0.1']]),  # text
    ],
    ids=['n-by-2', 'n-by-4', 'flat', 'text'],
)
def test_add_cloud_refuses_anything_but_n_by_3_at_the_call(points):
    """Issue 26.12: add_cloud accepted N x 2, N x 4 and 1-D arrays and a later scan
    reshaped them into wrong points (or raised from the middle of fusion); now the call
    refuses them and the next scans fuse what is good."""
    stream: FusionStream[int] = FusionStream(cloud_config())
    with pytest.raises(InputError, match=r'points must be an N x 3 array of real x, y, z'):
        stream.add_cloud(NS, points, NS, 'base_link', 'points')
    face = np.array([(1.5, y, 0.1) for y in np.linspace(-0.1, 0.1, 21)])
    stream.add_cloud(NS, face, NS, 'base_link', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is not None
    assert np.nanmin(out.fused.ranges) == pytest.approx(1.5, abs=0.01)
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)


def test_finish_flushes_the_last_partial_revolution_of_fragments():
    """Issue 26.12: finish() never gave out the fragment assembler's revolution begun, so a
    bag's last fragments never reached /scan_fused. Two whole revolutions of three
    fragments, then two fragments of a third: three scans, the last padded with NaN."""
    stream: FusionStream[int] = FusionStream(FusionConfig(memory=False, assemble_fragments=True))
    out = []
    for turn in range(3):
        for piece in range(3 if turn < 2 else 2):
            whole = hokuyo_scan(stamp=NS * (turn + 1) + piece * 1000)
            start = piece * 180
            fragment = replace(
                whole,
                angle_min=whole.angle_min + start * whole.angle_increment,
                angle_max=whole.angle_min + (start + 179) * whole.angle_increment,
                ranges=whole.ranges[start : start + 180],
            )
            out += stream.add_scan(fragment, 10 * turn + piece, NS * (turn + 1) + piece * 1000)
    assert [o.token for o in out] == [2, 12]
    out += stream.finish()
    assert [o.token for o in out] == [2, 12, 21]
    last = out[-1].lidar
    assert len(last) == 540
    assert last.angle_min == pytest.approx(-0.75 * math.pi)
    assert np.isnan(last.ranges[360:]).all()  # the third fragment never came
    np.testing.assert_array_equal(last.ranges[:360][np.isfinite(last.ranges[:360])], 2.0)


def test_odometry_on_both_odom_and_tf_is_taken_from_the_first_and_says_which(caplog):
    """Issue 26.12: a recording with both /odom and TF odom -> base_link (one estimate,
    published twice) made the node warn "odometry out of order" in 2 of 3 replays: over DDS
    the two arrive interleaved, TF's sample of 20 ms ago after /odom's of now."""
    stream: FusionStream[int] = FusionStream(FusionConfig())
    caplog.set_level(logging.INFO, logger='scanfuse')
    for k in range(50):
        stamp = NS + k * 20_000_000
        pose = PlanarPose(0.004 * k, 0.0, 0.0)
        stream.add_odometry(stamp, pose)
        if k:  # TF's sample of the previous instant arrives after /odom's of this one
            previous = StampedTransform(
                'odom', 'base_link', (0.004 * (k - 1), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                stamp_ns=stamp - 20_000_000,
            )  # fmt: skip
            stream.add_transforms([previous], static=False)
    assert stream.odometry.out_of_order == 0
    assert 'out of order' not in caplog.text
    assert stream.odometry_source == '/odom'
    assert stream.counts.odometry_ignored == 49
    assert 'odometry taken from /odom; TF odom -> base_link carries it too' in caplog.text
    assert len(stream.odometry) == 50


def one_named_camera(**section) -> FusionConfig:
    """One named camera (the first: it pairs with the LiDAR) 0.4 m up, with `section`."""
    return FusionConfig.from_dict(
        {
            'use_tf': False,
            'memory': False,
            'obstacle_min_points': 1,
            'lidar_height': 0.3,
            'cameras': ['front_depth'],
            'front_depth': {
                'depth_topic': '/front/depth',
                'camera_info_topic': '/front/info',
                'z': 0.4,
                'pitch': PITCH,
                **section,
            },
        }
    )


def front_box_reading(config: FusionConfig, frame_age_ns: int = 10) -> float:
    """What the fused scan reads straight ahead, where a 0.2 m high box stands 1.5 m off."""
    stream: FusionStream[int] = FusionStream(config)
    stream.add_camera_info(CAMERA)
    depth = depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD])
    stream.add_depth(NS - frame_age_ns, depth, NS, 'front_optical')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    return math.inf if out.fused is None else reading(out.fused, 0.0)


def test_the_first_named_cameras_own_section_settings_hold_for_it():
    """Issue 26.6: the first named camera's own min_obstacle_height, max_obstacle_height and
    max_time_offset were ignored (the global ones held); a second camera's were not. The box
    (0.2 m high) is an obstacle in the default slab, none above a slab bottom of 0.25 m, and
    a frame 50 ms old pairs only within a window of more."""
    assert front_box_reading(one_named_camera()) == pytest.approx(1.5, abs=0.02)
    assert front_box_reading(one_named_camera(min_obstacle_height=0.25)) == math.inf
    late = 50_000_000
    assert front_box_reading(one_named_camera(), late) == pytest.approx(1.5, abs=0.02)
    assert front_box_reading(one_named_camera(max_time_offset=0.02), late) == math.inf


@pytest.mark.parametrize(
    ('section', 'values'),
    [
        ({'min_obstacle_height': 0.4, 'max_obstacle_height': 0.1}, (0.4, 0.1)),
        ({'min_obstacle_height': 0.6}, (0.6, 0.5)),  # above the global top
    ],
)
def test_an_inverted_own_slab_is_refused(section, values):
    """Issue 26.6: a camera's (or cloud's) own slab upside down was accepted."""
    low, high = values
    with pytest.raises(
        ConfigError, match=rf'source front_depth: its slab bottom \({low}\) must be below its '
        rf'top \({high}\)',
    ):  # fmt: skip
        one_named_camera(**section)
    with pytest.raises(ConfigError, match=r'source points: its slab bottom \(0.3\)'):
        cloud_config(points={'topic': '/points', 'min_height': 0.3, 'max_height': 0.2})


def test_a_parameter_change_mid_revolution_keeps_the_fragments_and_the_reading_count():
    """Issue 26.1 (every run-time change applies): a change of any parameter made a new
    fragment assembler, so the revolution begun was lost and the learned reading count
    forgotten (slam_toolbox refuses a scan whose count changes)."""
    config = FusionConfig(memory=False, assemble_fragments=True)
    stream: FusionStream[int] = FusionStream(config)
    out = []
    for turn in range(3):
        for piece in range(3):
            if (turn, piece) == (1, 1):
                stream.reconfigure(config.with_changes(min_obstacle_height=0.1))
            if (turn, piece) == (2, 1):
                stream.reconfigure(config.with_changes(assemble_fragments=False))
                break
            whole = hokuyo_scan(stamp=NS * (turn + 1) + piece * 1000)
            start = piece * 180
            fragment = replace(
                whole,
                angle_min=whole.angle_min + start * whole.angle_increment,
                angle_max=whole.angle_min + (start + 179) * whole.angle_increment,
                ranges=whole.ranges[start : start + 180],
            )
            out += stream.add_scan(fragment, 10 * turn + piece, NS * (turn + 1) + piece * 1000)
    out += stream.finish()
    # The last revolution's first fragment, begun before assembly stopped, is not lost.
    assert [o.token for o in out] == [2, 12, 20]
    assert [len(o.lidar) for o in out] == [540, 540, 540]


def test_the_first_cameras_own_window_is_its_own_not_the_other_sources_default():
    """Issue 26.6: the first camera's max_time_offset holds for it alone; a second camera
    without one keeps the global window (0.1 s), so its frame 50 ms old still counts."""
    front = {'depth_topic': '/front/depth', 'camera_info_topic': '/front/info', 'z': 0.4}
    config = front_and_rear_cameras(front_depth={**front, 'pitch': PITCH, 'max_time_offset': 0.02})
    stream: FusionStream[int] = FusionStream(config)
    rear_camera = replace(CAMERA, frame_id='rear_optical')
    stream.add_camera_info(CAMERA)
    stream.add_camera_info(rear_camera, source='rear_depth')
    late = 50_000_000
    front_depth = depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD])
    stream.add_depth(NS - late, front_depth, NS, 'front_optical')
    rear_depth = depth_image(rear_camera, camera_pose(math.pi), [BOX_BEHIND])
    stream.add_depth(NS - late, rear_depth, NS, 'rear_optical', source='rear_depth')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.passed is not None  # the front frame is beyond the front camera's 20 ms
    assert out.fused is not None
    assert reading(out.fused, math.pi) == pytest.approx(1.5, abs=0.02)  # the rear's 100 ms
    assert reading(out.fused, 0.0) == math.inf
