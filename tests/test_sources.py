"""Several LiDARs, cameras and point clouds into one scan, on hand-worked geometry."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.frames import StampedTransform
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.stream import FusionStream
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.render import Box, depth_image, square_room_ranges

NS = 1_000_000_000
HALF = 2.0  # the square room: walls at x = +-2 and y = +-2 around the base origin
CAMERA = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='front_optical')
PITCH = math.radians(15.0)


def lidar_scan(origin, yaw, count, fov, frame, stamp=NS, *, grid_fov=None):
    """A LiDAR at `origin` with heading `yaw` seeing the room over `fov` (NaN elsewhere)."""
    grid_fov = fov if grid_fov is None else grid_fov
    increment = grid_fov / count
    angle_min = -grid_fov / 2
    angles = angle_min + increment * np.arange(count)
    ranges = square_room_ranges(origin, yaw, angles, HALF)
    ranges[np.abs(angles) > fov / 2] = np.nan
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (count - 1),
        angle_increment=increment,
        range_min=0.05,
        range_max=20.0,
        ranges=ranges.astype(np.float32),
        frame_id=frame,
        stamp_ns=stamp,
    )


def two_lidars(**changes) -> FusionConfig:
    values = {
        'use_tf': False,
        'memory': False,
        'lidars': ['front', 'rear'],
        'front': {'topic': '/front/scan', 'x': 0.3, 'y': 0.2, 'z': 0.2, 'yaw': math.pi / 4},
        'rear': {'topic': '/rear/scan', 'x': -0.3, 'y': -0.2, 'z': 0.2, 'yaw': -3 * math.pi / 4},
        **changes,
    }
    return FusionConfig.from_dict(values)


def test_two_lidars_at_opposite_corners_give_one_scan_true_from_the_output_origin():
    stream: FusionStream[int] = FusionStream(two_lidars())
    fov = math.radians(270)
    front_origin, front_yaw = (0.3, 0.2), math.pi / 4
    rear_origin, rear_yaw = (-0.3, -0.2), -3 * math.pi / 4
    # The output is the front LiDAR's 0.1-degree 360-degree grid; it sees 270 degrees.
    front = lidar_scan(front_origin, front_yaw, 3600, fov, 'front', grid_fov=2 * math.pi)
    rear = lidar_scan(rear_origin, rear_yaw, 5400, fov, 'rear')
    assert stream.add_scan(rear, 0, NS, source='rear') == []
    (out,) = stream.add_scan(front, 1, NS + 1)
    truth = square_room_ranges(front_origin, front_yaw, front.angles(), HALF)
    assert out.fused is not None
    assert np.isfinite(out.fused.ranges).all()  # the rear LiDAR fills the front one's gap
    np.testing.assert_allclose(out.fused.ranges, truth, atol=0.01)
    assert stream.sources.counts.used == {'rear': 1}


def test_full_circle_puts_a_270_degree_front_lidar_on_360_degrees_the_rear_one_fills():
    stream: FusionStream[int] = FusionStream(two_lidars(full_circle=True))
    fov = math.radians(270)
    front = lidar_scan((0.3, 0.2), math.pi / 4, 1080, fov, 'front')  # 0.25-degree steps
    rear = lidar_scan((-0.3, -0.2), -3 * math.pi / 4, 1080, fov, 'rear')
    stream.add_scan(rear, 0, NS, source='rear')
    (out,) = stream.add_scan(front, 1, NS + 1)
    assert out.fused is not None
    assert len(out.fused) == 1440  # 360 / 0.25
    truth = square_room_ranges((0.3, 0.2), math.pi / 4, out.fused.angles(), HALF)
    assert np.isfinite(out.fused.ranges).all()
    np.testing.assert_allclose(out.fused.ranges, truth, atol=0.01)
    # Without the rear LiDAR the front one's 90-degree blind sector stays empty (NaN).
    alone: FusionStream[int] = FusionStream(two_lidars(full_circle=True))
    (solo,) = alone.add_scan(front, 1, NS + 1)
    assert solo.fused is not None
    assert int(np.isnan(solo.fused.ranges).sum()) == 1440 - 1080


def test_a_source_that_never_arrives_is_passed_over_and_counted():
    stream: FusionStream[int] = FusionStream(two_lidars())
    front = lidar_scan((0.3, 0.2), math.pi / 4, 360, math.radians(270), 'front')
    (out,) = stream.add_scan(front, 1, NS)
    assert out.fused is None  # the front LiDAR alone, unchanged
    assert stream.sources.counts.missing == {'rear': 1}


def test_a_stale_source_beyond_its_max_time_offset_is_not_used():
    config = two_lidars(rear={'topic': '/rear/scan', 'x': -0.3, 'max_time_offset': 0.05})
    stream: FusionStream[int] = FusionStream(config)
    rear = lidar_scan((-0.3, 0.0), 0.0, 360, math.radians(270), 'rear', stamp=NS)
    stream.add_scan(rear, 0, NS, source='rear')
    front = lidar_scan(
        (0.3, 0.2), math.pi / 4, 360, math.radians(270), 'front', stamp=NS + NS // 10
    )
    (out,) = stream.add_scan(front, 1, NS + NS // 10)
    assert out.fused is None
    assert stream.sources.counts.missing == {'rear': 1}


# ------------------------------------------------------------------ cameras and clouds

BOX_AHEAD = Box(1.5, 1.7, -0.1, 0.1, 0.2)
BOX_BEHIND = Box(-1.7, -1.5, -0.1, 0.1, 0.2)


def base_lidar(stamp=NS, count=720) -> Scan:
    increment = 2 * math.pi / count
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - increment,
        angle_increment=increment,
        range_min=0.05,
        range_max=10.0,
        ranges=np.full(count, np.inf, dtype=np.float32),
        frame_id='laser',
        stamp_ns=stamp,
    )


def camera_pose(yaw: float) -> Transform:
    return Transform.from_rpy(0.0, PITCH, yaw, (0.0, 0.0, 0.4)) @ BODY_TO_OPTICAL


def reading(scan: Scan, bearing: float) -> float:
    slot = int(scan.grid.slot_of(np.array([bearing]))[0])
    window = scan.ranges[[(slot + k) % len(scan) for k in (-1, 0, 1)]]
    return float(np.where(np.isfinite(window), window, np.inf).min())  # inf: nothing there


def front_and_rear_cameras(**changes) -> FusionConfig:
    values = {
        'use_tf': False,
        'memory': False,
        'far_confirm_range': 0.0,  # each box shown from its first frame: test_far_confirm.py
        'obstacle_min_points': 1,
        'lidar_height': 0.3,
        'cameras': ['front_depth', 'rear_depth'],
        'front_depth': {
            'depth_topic': '/front/depth',
            'camera_info_topic': '/front/info',
            'z': 0.4,
            'pitch': PITCH,
        },
        'rear_depth': {
            'depth_topic': '/rear/depth',
            'camera_info_topic': '/rear/info',
            'z': 0.4,
            'pitch': PITCH,
            'yaw': math.pi,
        },
        **changes,
    }
    return FusionConfig.from_dict(values)


def test_a_rear_cameras_obstacle_lands_at_bearing_pi():
    stream: FusionStream[int] = FusionStream(front_and_rear_cameras())
    rear_camera = CameraModel.from_intrinsics(
        320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='rear_optical'
    )
    stream.add_camera_info(CAMERA)
    stream.add_camera_info(rear_camera, source='rear_depth')
    stream.add_depth(
        NS - 10, depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD]), NS, 'front_optical'
    )
    stream.add_depth(
        NS - 20,
        depth_image(rear_camera, camera_pose(math.pi), [BOX_BEHIND]),
        NS,
        'rear_optical',
        source='rear_depth',
    )
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is not None
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.02)  # the front camera's box
    assert reading(out.fused, math.pi) == pytest.approx(1.5, abs=0.02)  # the rear camera's
    assert reading(out.depth_scan, math.pi) == pytest.approx(1.5, abs=0.02)


def test_the_rear_camera_clears_the_memory_once_it_sees_the_place_free():
    # The rear camera's box (1.5 m behind) enters the memory; taken away, the next rear frame
    # sees the floor where it stood and the memory forgets it, as the first camera's would.
    stream: FusionStream[int] = FusionStream(front_and_rear_cameras(memory=True))
    rear_camera = CameraModel.from_intrinsics(
        320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='rear_optical'
    )
    stream.add_camera_info(CAMERA)
    stream.add_camera_info(rear_camera, source='rear_depth')

    def step(k: int, behind: list[Box]):
        now = NS + k * NS // 10
        for stamp in (now - NS // 20, now + NS // 500):  # the robot stands at the origin
            stream.add_odometry(stamp, PlanarPose(0.0, 0.0, 0.0))
        front = depth_image(CAMERA, camera_pose(0.0), [])
        stream.add_depth(now - 10, front, now, 'front_optical')
        rear = depth_image(rear_camera, camera_pose(math.pi), behind)
        stream.add_depth(now - 20, rear, now, 'rear_optical', source='rear_depth')
        (out,) = stream.add_scan(base_lidar(stamp=now), k, now + 1)
        return out

    first = step(0, [BOX_BEHIND])
    assert reading(first.fused, math.pi) == pytest.approx(1.5, abs=0.02)
    assert reading(first.memory_scan, math.pi) == pytest.approx(1.5, abs=0.02)
    second = step(1, [])
    assert not reading(second.fused, math.pi) < 2.0
    assert stream.memory is not None
    assert len(stream.memory) == 0
    assert stream.counts.memory_cleared > 0


def back_projected(depth_mm: np.ndarray, camera: CameraModel) -> np.ndarray:
    """The depth image's pixels as points in its optical frame (x right, y down, z ahead)."""
    x_n, y_n = (np.asarray(c, dtype=np.float64) for c in camera.normalized_coordinates)
    z = depth_mm.astype(np.float64) / 1000.0
    keep = z > 0
    return np.stack([x_n[keep] * z[keep], y_n[keep] * z[keep], z[keep]], axis=1)


def cloud_config(**changes) -> FusionConfig:
    values = {
        'use_tf': False,
        'memory': False,
        'lidar_height': 0.3,
        'camera_height': 0.4,
        'camera_pitch': PITCH,
        'obstacle_min_points': 1,
        'clouds': ['points'],
        'points': {'topic': '/points'},
        **changes,
    }
    return FusionConfig.from_dict(values)


def test_a_cloud_of_the_scene_gives_the_scan_its_depth_image_gives():
    depth = depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD])
    by_camera: FusionStream[int] = FusionStream(cloud_config())
    by_camera.add_camera_info(CAMERA)
    by_camera.add_depth(NS - 10, depth, NS, 'front_optical')
    (camera_out,) = by_camera.add_scan(base_lidar(), 1, NS + 1)
    # The same pixels as a cloud in the optical frame, placed by the same mounting (TF).
    by_cloud: FusionStream[int] = FusionStream(cloud_config(use_tf=True))
    optical = camera_pose(0.0)
    by_cloud.add_transforms(
        [
            StampedTransform('base_link', 'laser', (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0)),
            StampedTransform('base_link', 'cloud_optical', optical.translation, optical.rotation),
        ],
        static=True,
    )
    points = back_projected(depth, CAMERA)
    by_cloud.add_cloud(NS - 10, points, NS, 'cloud_optical', 'points')
    (cloud_out,) = by_cloud.add_scan(base_lidar(), 1, NS + 1)
    camera_ranges, cloud_ranges = camera_out.fused.ranges, cloud_out.fused.ranges
    obstacle = np.isfinite(camera_ranges)
    assert obstacle.sum() >= 10
    assert np.array_equal(obstacle, np.isfinite(cloud_ranges))
    np.testing.assert_allclose(cloud_ranges[obstacle], camera_ranges[obstacle], atol=0.005)


def test_a_cloud_in_a_frame_turned_90_degrees_is_placed_by_its_mounting():
    # The cloud frame is the base frame turned +90 degrees about z: a point 1.5 m ahead of
    # the robot is at (0, -1.5) in it.
    stream: FusionStream[int] = FusionStream(
        cloud_config(points={'topic': '/points', 'yaw': math.pi / 2})
    )
    ys = np.linspace(-0.1, 0.1, 21)
    zs = np.linspace(0.05, 0.2, 6)
    front_face = np.array([(-y, -1.5, z) for y in ys for z in zs])
    stream.add_cloud(NS, front_face, NS, 'cloud', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)
    assert not reading(out.fused, -math.pi / 2) < 5.0


def test_cloud_points_outside_the_slab_are_ignored():
    stream: FusionStream[int] = FusionStream(cloud_config())
    overhang = np.array([(1.5, 0.0, 1.2), (1.5, 0.05, 1.3)])  # a table top above the robot
    floor = np.array([(1.0, 0.0, 0.0)])
    stream.add_cloud(NS, np.vstack([overhang, floor]), NS, 'base_link', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is None  # nothing added


# ------------------------------------------------------------------ an upside-down LiDAR


def test_an_upside_down_lidar_by_parameters_gives_the_scan_tf_gives():
    left_box = Box(1.4, 1.6, 0.4, 0.6, 0.2)  # ahead and to the left of the robot
    depth = depth_image(CAMERA, camera_pose(0.0), [left_box])
    common = {
        'memory': False,
        'camera_height': 0.4,
        'camera_pitch': PITCH,
        'lidar_height': 0.3,
        'obstacle_min_points': 1,
    }
    by_params: FusionStream[int] = FusionStream(
        FusionConfig(use_tf=False, lidar_roll=math.pi, **common)
    )
    by_tf: FusionStream[int] = FusionStream(FusionConfig(use_tf=True, **common))
    flipped = Transform.from_rpy(math.pi, 0.0, 0.0, (0.0, 0.0, 0.3))
    by_tf.add_transforms(
        [
            StampedTransform('base_link', 'laser', flipped.translation, flipped.rotation),
            StampedTransform(
                'base_link',
                'front_optical',
                camera_pose(0.0).translation,
                camera_pose(0.0).rotation,
            ),
        ],
        static=True,
    )
    outs = []
    for stream in (by_params, by_tf):
        stream.add_camera_info(CAMERA)
        stream.add_depth(NS - 10, depth, NS, 'front_optical')
        outs.append(stream.add_scan(base_lidar(), 1, NS + 1)[0].fused)
    np.testing.assert_array_equal(outs[0].ranges, outs[1].ranges)
    # Seen from the upside-down scanner the box is on its right: a negative bearing.
    bearing = math.atan2(0.5, 1.4)
    assert reading(outs[0], -bearing) == pytest.approx(math.hypot(1.4, 0.5), abs=0.05)
    assert not reading(outs[0], bearing) < 5.0


# ------------------------------------------------------------------ configuration


def test_sources_come_nested_or_dotted_and_the_first_fills_the_one_source_parameters():
    nested = two_lidars()
    dotted = FusionConfig.from_dict(
        {
            'use_tf': False,
            'memory': False,
            'lidars': ['front', 'rear'],
            'front.topic': '/front/scan',
            'front.x': 0.3,
            'front.y': 0.2,
            'front.z': 0.2,
            'front.yaw': math.pi / 4,
            'rear.topic': '/rear/scan',
            'rear.x': -0.3,
            'rear.y': -0.2,
            'rear.z': 0.2,
            'rear.yaw': -3 * math.pi / 4,
        }
    )
    assert nested == dotted
    assert (nested.scan_topic, nested.lidar_x, nested.lidar_height) == ('/front/scan', 0.3, 0.2)
    assert nested.lidar_yaw == pytest.approx(math.pi / 4)
    round_trip = FusionConfig.from_dict(nested.to_ros_params()['scanfuse']['ros__parameters'])
    assert round_trip == nested


def test_a_section_nobody_lists_is_an_error():
    with pytest.raises(ConfigError, match=r'source sections rear are not listed'):
        FusionConfig.from_dict(
            {'lidars': ['front'], 'front': {'topic': '/a'}, 'rear': {'topic': '/b'}}
        )


def test_two_sources_on_one_topic_is_an_error():
    with pytest.raises(ConfigError, match=r'two sources listen on /scan'):
        FusionConfig.from_dict(
            {'lidars': ['a', 'b'], 'a': {'topic': '/scan'}, 'b': {'topic': '/scan'}}
        )


def test_a_source_without_its_topic_is_an_error():
    with pytest.raises(ConfigError, match=r'sources\.clouds\.0\.topic'):
        FusionConfig.from_dict({'clouds': ['livox'], 'livox': {'min_height': 0.1}})


# ------------------------------------------------------------------ fragmented LiDARs

FRAGMENTS = (500, 500, 500, 500, 500, 250)  # a PSENscan revolution: 2750 readings
STEP = math.radians(0.1)


def fragments(revolution: int, start_ns: int) -> list[Scan]:
    """One revolution of 275 degrees in six pieces, 5 ms apart, of a wall 2 m around."""
    pieces, first = [], -math.radians(137.5)
    for index, count in enumerate(FRAGMENTS):
        angle_min = first + STEP * sum(FRAGMENTS[:index])
        ranges = np.full(count, 2.0 + 0.01 * revolution, dtype=np.float32)
        pieces.append(
            Scan(
                angle_min=angle_min,
                angle_max=angle_min + STEP * (count - 1),
                angle_increment=STEP,
                range_min=0.05,
                range_max=10.0,
                ranges=ranges,
                frame_id='laser',
                stamp_ns=start_ns + index * 5_000_000,
            )
        )
    return pieces


def depth_stream(**changes) -> FusionStream[int]:
    config = FusionConfig(
        use_tf=False,
        memory=False,
        camera_height=0.4,
        camera_pitch=PITCH,
        lidar_height=0.3,
        obstacle_min_points=1,
        **changes,
    )
    stream: FusionStream[int] = FusionStream(config)
    stream.add_camera_info(CAMERA)
    stream.add_depth(NS, depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD]), NS, 'front_optical')
    return stream


def test_six_fragments_assembled_equal_the_fragments_fused_one_by_one_side_by_side():
    one_by_one = depth_stream()
    separate = [
        one_by_one.add_scan(piece, k, NS + k)[0] for k, piece in enumerate(fragments(0, NS))
    ]
    assert [len(out.fused or out.lidar) for out in separate] == list(FRAGMENTS)
    side_by_side = np.concatenate([(out.fused or out.lidar).ranges for out in separate])

    assembling = depth_stream(assemble_fragments=True)
    outs = []
    for revolution in range(2):
        for k, piece in enumerate(fragments(revolution, NS + revolution * 30_000_000)):
            outs += assembling.add_scan(piece, 10 * revolution + k, NS + 1000 * revolution + k)
    # The first revolution is known complete when the second starts; the second, once the
    # first taught the count, with its own last piece.
    assert [out.token for out in outs] == [5, 15]
    first = outs[0].fused
    assert len(first) == sum(FRAGMENTS)
    assert first.angle_min == fragments(0, NS)[0].angle_min
    assert first.stamp_ns == NS
    np.testing.assert_array_equal(first.ranges, side_by_side)
    assert reading(first, 0.0) == pytest.approx(1.5, abs=0.02)  # the camera's box


def test_a_revolution_missing_a_fragment_is_padded_to_the_learned_count():
    stream = depth_stream(assemble_fragments=True, fragment_timeout=0.05)
    outs = []
    for k, piece in enumerate(fragments(0, NS)):
        outs += stream.add_scan(piece, k, NS + k)
    second = fragments(1, NS + 30_000_000)
    del second[3]  # lost on the wire
    for k, piece in enumerate(second):
        outs += stream.add_scan(piece, 10 + k, NS + 1000 + k)
    outs += stream.add_scan(fragments(2, NS + 60_000_000)[0], 20, NS + 2000)
    assert len(outs) == 3  # [0..5], then [0, 1, 2] and [4, 5] of the gapped revolution
    for out in outs:
        scan = out.fused or out.lidar
        assert len(scan) == sum(FRAGMENTS)  # slam_toolbox sees one reading count
        assert scan.angle_min == pytest.approx(fragments(0, NS)[0].angle_min)
    gapped = np.stack([o.lidar.ranges for o in outs[1:]])
    missing = slice(sum(FRAGMENTS[:3]), sum(FRAGMENTS[:4]))
    assert np.isnan(gapped[:, missing]).all()  # the LiDAR has nothing for the lost piece
    assert stream.assembler.padded == 2


# ------------------------------------------------------------------ bad input


def test_a_source_frame_unknown_to_tf_takes_its_mounting_parameters():
    config = cloud_config(use_tf=True, points={'topic': '/points', 'yaw': math.pi / 2})
    stream: FusionStream[int] = FusionStream(config)
    stream.add_transforms(
        [StampedTransform('base_link', 'laser', (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0))],
        static=True,
    )
    ys, zs = np.linspace(-0.1, 0.1, 21), np.linspace(0.05, 0.2, 6)
    stream.add_cloud(NS, np.array([(-y, -1.5, z) for y in ys for z in zs]), NS, 'livox', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)


def test_a_source_frame_tf_cannot_relate_to_the_base_is_passed_over_and_counted():
    stream: FusionStream[int] = FusionStream(cloud_config(use_tf=True))
    stream.add_transforms(
        [
            StampedTransform('base_link', 'laser', (0.0, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0)),
            StampedTransform('sensor_mount', 'livox', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
        ],
        static=True,
    )
    stream.add_cloud(NS, np.array([(1.5, 0.0, 0.1)] * 20), NS, 'livox', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is None  # the LiDAR goes on alone
    assert stream.sources.counts.no_mounting == {'points': 1}


def test_clock_skew_between_sources_leaves_the_skewed_one_out_and_the_scan_coming():
    stream: FusionStream[int] = FusionStream(two_lidars())
    fov = math.radians(270)
    for k in range(5):
        stamp = NS + k * NS // 10
        skewed = lidar_scan((-0.3, -0.2), -3 * math.pi / 4, 360, fov, 'rear', stamp=stamp + 5 * NS)
        stream.add_scan(skewed, 0, stamp, source='rear')
        front = lidar_scan((0.3, 0.2), math.pi / 4, 360, fov, 'front', stamp=stamp)
        (out,) = stream.add_scan(front, k, stamp + 1)
        assert out.token == k
    assert stream.sources.counts.missing == {'rear': 5}
    assert stream.sources.counts.used == {}


def test_a_cloud_without_xyz_or_with_a_short_point_step_is_a_message_error():
    from scanfuse.errors import MessageError
    from scanfuse.ros.messages import (
        POINT_CLOUD,
        cloud_from_cdr,
        cloud_to_cdr,
        deserialize,
        serialize,
        typestore,
    )

    raw = cloud_to_cdr(np.ones((4, 3)), frame_id='c', stamp_ns=1)
    message = deserialize(raw, POINT_CLOUD)
    store = typestore()
    no_z = type(message)(**{**message.__dict__, 'fields': message.fields[:2]})
    with pytest.raises(MessageError, match=r'has no z field .*needs x, y and z'):
        cloud_from_cdr(serialize(no_z, POINT_CLOUD, store))
    short = type(message)(**{**message.__dict__, 'point_step': 8, 'row_step': 32})
    with pytest.raises(
        MessageError, match=r'field z at offset 8 does not fit in a point_step of 8'
    ):
        cloud_from_cdr(serialize(short, POINT_CLOUD, store))
    truncated = type(message)(**{**message.__dict__, 'data': message.data[:20]})
    with pytest.raises(MessageError, match=r'needs 64 bytes, got 20'):
        cloud_from_cdr(serialize(truncated, POINT_CLOUD, store))


def test_float64_and_organized_clouds_decode_and_nan_points_are_skipped():
    from scanfuse.ros.messages import cloud_from_cdr, cloud_to_cdr

    points = np.array([[1.0, 2.0, 3.0], [np.nan, 0.0, 0.0]])
    decoded = cloud_from_cdr(cloud_to_cdr(points, frame_id='c', stamp_ns=7, dtype='f8'))
    np.testing.assert_array_equal(decoded.points[0], [1.0, 2.0, 3.0])
    stream: FusionStream[int] = FusionStream(cloud_config())
    stream.add_cloud(NS, np.array([[np.nan, 0.0, 0.1], [1.5, 0.0, 0.1]]), NS, 'base_link', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)


def test_the_shipped_several_sensors_example_loads_with_every_source():
    from tests.support import REPOSITORY

    config = FusionConfig.from_ros_params(REPOSITORY / 'examples' / 'scanfuse_multi.yaml')
    sources = config.sources
    assert [s.name for s in sources.lidars] == ['front', 'rear']
    assert [s.name for s in sources.cameras] == ['front_depth', 'rear_depth']
    assert [s.name for s in sources.clouds] == ['livox']
    # The first LiDAR and camera are the primary pair, in the one-source parameters too.
    assert config.scan_topic == '/front/scan'
    assert config.depth_topic == '/front_camera/depth/image_rect_raw'
    assert (config.camera_x, config.camera_height) == (0.4, 0.45)
    assert sources.cameras[1].min_obstacle_height == 0.05
    stream: FusionStream[int] = FusionStream(config)
    # Every camera adds to an output by one rule; only the triggering LiDAR is no contributor.
    assert set(stream.sources.names) == {'rear', 'front_depth', 'rear_depth', 'livox'}


def test_what_a_second_lidar_sees_is_not_remembered_from_the_rear_camera():
    # The rear camera sees the box 1.5 m behind. The first LiDAR reads nothing there (its
    # blind side); a rear LiDAR (at the base, facing back) reads the box's face at 1.5 m in
    # every slot the face spans: some LiDAR sees it now, so the memory keeps none of it.
    # Without that reading the same frame is remembered (the test above).
    def config(rear_sees: bool) -> tuple[FusionStream[int], Scan]:
        values = {
            'lidars': ['main', 'rear'],
            'main': {'topic': '/scan', 'z': 0.3},
            'rear': {'topic': '/rear/scan', 'z': 0.3, 'yaw': math.pi},
        }
        stream: FusionStream[int] = FusionStream(front_and_rear_cameras(memory=True, **values))
        rear = base_lidar().with_ranges(np.full(720, np.inf, np.float32))
        angles = rear.angles()
        face = (np.cos(angles) > 0) & (np.abs(np.tan(angles)) * 1.5 <= BOX_BEHIND.y_max)
        if rear_sees:
            ranges = np.where(face, 1.5 / np.cos(angles), np.inf).astype(np.float32)
            rear = rear.with_ranges(ranges)
        return stream, replace(rear, frame_id='rear_laser')

    kept = []
    for rear_sees in (True, False):
        stream, rear_scan = config(rear_sees)
        rear_camera = CameraModel.from_intrinsics(
            320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='rear_optical'
        )
        stream.add_camera_info(CAMERA)
        stream.add_camera_info(rear_camera, source='rear_depth')
        for stamp in (NS - NS // 20, NS + NS // 500):
            stream.add_odometry(stamp, PlanarPose(0.0, 0.0, 0.0))
        stream.add_depth(NS - 10, depth_image(CAMERA, camera_pose(0.0), []), NS, 'front_optical')
        rear_depth = depth_image(rear_camera, camera_pose(math.pi), [BOX_BEHIND])
        stream.add_depth(NS - 20, rear_depth, NS, 'rear_optical', source='rear_depth')
        stream.add_scan(rear_scan, 0, NS, source='rear')
        (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
        assert reading(out.fused, math.pi) == pytest.approx(1.5, abs=0.02)  # seen either way
        assert stream.memory is not None
        kept.append(len(stream.memory))
    assert kept[0] == 0
    assert kept[1] > 0


# ------------------------------------------------------------------ every camera alike

REAR_CAMERA = replace(CAMERA, frame_id='rear_optical')


def both_cameras_fused(order: list[str]) -> Scan:
    """One scan fused with the front camera's box ahead and the rear camera's box behind,
    the cameras listed in `order` and fed by name only."""
    stream: FusionStream[int] = FusionStream(front_and_rear_cameras(cameras=order))
    stream.add_camera_info(CAMERA, source='front_depth')
    stream.add_camera_info(REAR_CAMERA, source='rear_depth')
    front = depth_image(CAMERA, camera_pose(0.0), [BOX_AHEAD])
    rear = depth_image(REAR_CAMERA, camera_pose(math.pi), [BOX_BEHIND])
    stream.add_depth(NS - 10, front, NS, 'front_optical', source='front_depth')
    stream.add_depth(NS - 20, rear, NS, 'rear_optical', source='rear_depth')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.passed is None
    assert out.fused is not None
    return out.fused


def test_the_camera_listed_first_is_no_different_from_the_others():
    # The same frames, the cameras listed either way round: the same scan, both boxes at
    # 1.5 m (their near faces, ahead and behind).
    first = both_cameras_fused(['front_depth', 'rear_depth'])
    swapped = both_cameras_fused(['rear_depth', 'front_depth'])
    np.testing.assert_array_equal(first.ranges, swapped.ranges)
    assert reading(first, 0.0) == pytest.approx(1.5, abs=0.02)
    assert reading(first, math.pi) == pytest.approx(1.5, abs=0.02)


def test_a_scan_waits_for_every_camera_and_takes_each_ones_nearest_frame():
    # The rear camera's frame 10 ms before the scan shows the box behind; its next frame,
    # 40 ms after the scan, shows it gone. The scan waits for that frame (frames come in
    # stamp order: no later one can be nearer), then takes the nearer one: the box. A rule
    # of "the freshest frame" would have taken the later, empty one.
    stream: FusionStream[int] = FusionStream(front_and_rear_cameras(), pair_wait=1.0)
    stream.add_camera_info(CAMERA)
    stream.add_camera_info(REAR_CAMERA, source='rear_depth')
    stream.add_depth(NS + 5, depth_image(CAMERA, camera_pose(0.0), []), NS, 'front_optical')
    with_box = depth_image(REAR_CAMERA, camera_pose(math.pi), [BOX_BEHIND])
    stream.add_depth(NS - 10, with_box, NS, 'rear_optical', source='rear_depth')
    assert stream.add_scan(base_lidar(), 1, NS + 1) == []  # the rear camera has no later frame
    empty = depth_image(REAR_CAMERA, camera_pose(math.pi), [])
    (out,) = stream.add_depth(NS + 40_000_000, empty, NS + 2, 'rear_optical', source='rear_depth')
    assert out.token == 1
    assert out.fused is not None
    assert reading(out.fused, math.pi) == pytest.approx(1.5, abs=0.02)
    assert reading(out.fused, 0.0) == math.inf  # the front camera's frame: nothing ahead
