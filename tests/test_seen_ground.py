"""LiDAR readings on the ground the camera sees (`scanfuse.seen_ground`), through the stream.

The robot stands on a flat floor in a room of walls at x, y = +-3 m, its body pitched nose
down by 7.1 degrees (braking hard at the foot of a 1:8 ramp; the IMU says so). Its LiDAR,
0.3 m up the body, sweeps the floor ahead: a beam at bearing a meets it at
0.3 cos(t) / (sin(t) cos(a)) = 2.4 m / cos(a). The camera (0.4 m up, pitched 15 degrees on
the body) sees that floor.
"""

from __future__ import annotations

import math

import numpy as np

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.convert.ground import GroundPlane
from scanfuse.memory import lens_and_depth, profile_arrays
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.seen_ground import SEEN_MARGIN, _on_ground_loop, on_seen_ground
from scanfuse.stream import FusionStream
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.render import Box, depth_image, tilted_room_ranges

NS = 1_000_000_000
CAMERA = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')
HEIGHT, PITCH = 0.4, math.radians(15.0)
LIDAR_HEIGHT = 0.3
SLOPE = math.atan(1 / 8)
READINGS = 720
FLOOR_AHEAD = LIDAR_HEIGHT * math.cos(SLOPE) / math.sin(SLOPE)  # 2.4 m
POST = Box(1.5, 1.6, -0.15, 0.15, 1.0)  # 1.5 m ahead, 0.3 m wide, 1 m tall
TILT = Transform.from_rpy(0.0, SLOPE, 0.0)  # nose down


def lidar_scan(stamp_ns: int, *, post: bool = False) -> Scan:
    """The pitched LiDAR's scan of the room (and of `POST`'s front face)."""
    empty = Scan(
        angle_min=-math.pi,
        angle_max=math.pi - 2 * math.pi / READINGS,
        angle_increment=2 * math.pi / READINGS,
        range_min=0.05,
        range_max=10.0,
        ranges=np.zeros(READINGS, dtype=np.float32),
        frame_id='laser',
        stamp_ns=stamp_ns,
    )
    angles = empty.angles()
    tilt = TILT.rotation_matrix
    ranges = tilted_room_ranges((0.0, 0.0, 0.0), tilt, angles, height=LIDAR_HEIGHT, half=3.0)
    if post:
        origin = tilt @ np.array([0.0, 0.0, LIDAR_HEIGHT])
        beams = tilt @ np.vstack([np.cos(angles), np.sin(angles), np.zeros(angles.size)])
        with np.errstate(divide='ignore', invalid='ignore'):
            reach = (POST.x_min - origin[0]) / beams[0]
        y = origin[1] + reach * beams[1]
        hits = (reach > 0.0) & (np.abs(y) <= POST.y_max)
        ranges = np.where(hits, np.minimum(ranges, reach), ranges)
    return empty.with_ranges(ranges.astype(np.float32))


def pitched_output(*, post: bool = False):
    config = FusionConfig(
        use_tf=False, camera_height=HEIGHT, camera_pitch=PITCH, lidar_height=LIDAR_HEIGHT,
        obstacle_min_points=1, memory=False,
    )  # fmt: skip
    stream = FusionStream(config)
    stream.add_camera_info(CAMERA)
    view = TILT @ Transform.from_rpy(0.0, PITCH, 0.0, (0.0, 0.0, HEIGHT)) @ BODY_TO_OPTICAL
    depth = depth_image(CAMERA, view, [POST] if post else [])
    now = NS
    for _ in range(3):
        now += NS // 10
        stream.add_odometry(now, PlanarPose(0.0, 0.0, 0.0))
        stream.add_imu(now, TILT.rotation, 'base_link')
        stream.add_depth(now - 20_000_000, depth, now - 5_000_000)
        (out,) = stream.add_scan(lidar_scan(now, post=post), None, now + 1_000_000)
    return stream, out


def bearing_slots(scan: Scan, low: float, high: float) -> np.ndarray:
    angles = scan.angles()
    return np.flatnonzero((angles >= low) & (angles <= high))


def test_the_pitched_lidar_s_floor_ahead_is_dropped_where_the_camera_sees_the_floor():
    stream, out = pitched_output()
    fused = out.fused if out.fused is not None else out.lidar
    ahead = bearing_slots(fused, -math.radians(30.0), math.radians(30.0))
    # What the LiDAR read there was the floor, 2.4 m / cos(a) away:
    raw = lidar_scan(0).ranges[ahead]
    np.testing.assert_allclose(raw, FLOOR_AHEAD / np.cos(fused.angles()[ahead]), rtol=1e-5)
    # ... and the camera sees no obstacle there: no reading ahead.
    assert not np.isfinite(fused.ranges[ahead]).any()
    assert stream.counts.lidar_on_seen_ground >= len(ahead)
    # Behind, out of the camera's view, the beams rise to the back wall: kept, as measured.
    behind = bearing_slots(fused, math.radians(170.0), math.radians(180.0))
    np.testing.assert_allclose(fused.ranges[behind], lidar_scan(0).ranges[behind], rtol=1e-6)


def test_the_pitched_lidar_s_readings_of_a_post_above_the_slab_s_bottom_are_kept():
    # The plane meets the post 1.5 m ahead about 11 cm up: an obstacle, kept as measured;
    # beside it the floor is dropped as before.
    _, out = pitched_output(post=True)
    raw = lidar_scan(0, post=True)
    on_post = np.flatnonzero(np.abs(raw.ranges - 1.5) < 0.1)
    assert len(on_post) >= 20
    np.testing.assert_allclose(out.lidar.ranges[on_post], raw.ranges[on_post], rtol=1e-6)
    beside = bearing_slots(raw, math.radians(20.0), math.radians(30.0))
    assert not np.isfinite(out.lidar.ranges[beside]).any()


def test_a_point_above_the_slab_s_bottom_or_hidden_behind_a_nearer_pixel_is_kept():
    # A level camera 0.4 m up looking ahead (optical z forward, y down), the floor 0.4 m
    # below it; a flat floor image. Points 2 m ahead at heights 0, 2 cm (below the 3 cm
    # slab bottom), 5 cm (above it), 30 cm beneath it, and on the floor 3 m to the left (out
    # of the view).
    mounting = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, HEIGHT)) @ BODY_TO_OPTICAL
    plane = GroundPlane.of_mounting(mounting)
    depth = depth_image(CAMERA, mounting, [])
    base_points = np.array(
        [[2.0, 0.0, 0.0], [2.0, 0.0, 0.02], [2.0, 0.0, 0.05], [2.0, 0.0, -0.3], [2.0, 3.0, 0.0]]
    )
    optical = mounting.inverse().apply(base_points)
    found = on_seen_ground(
        optical, depth, CAMERA, plane, None, below=0.03, range_min=0.1, range_max=4.0
    )
    # The point beneath the floor is hidden (the floor's pixel lies nearer): kept too.
    assert found.tolist() == [True, True, False, False, False]
    hidden = depth_image(CAMERA, mounting, [Box(1.0, 1.1, -0.5, 0.5, 1.0)])  # a wall at 1 m
    found = on_seen_ground(
        optical[:1], hidden, CAMERA, plane, None, below=0.03, range_min=0.1, range_max=4.0
    )
    assert found.tolist() == [False]


def test_the_compiled_pass_matches_its_plain_loop_point_for_point():
    # `docs/architecture.md`: every kernel has its plain Python beside it, the same arithmetic.
    mounting = Transform.from_rpy(0.0, PITCH, 0.0, (0.0, 0.0, HEIGHT)) @ BODY_TO_OPTICAL
    plane = GroundPlane.of_mounting(mounting)
    depth = depth_image(CAMERA, mounting, [POST])
    rng = np.random.default_rng(7)
    base_points = np.column_stack(
        [rng.uniform(0.3, 4.0, 500), rng.uniform(-2.0, 2.0, 500), rng.uniform(-0.2, 0.4, 500)]
    )
    optical = np.ascontiguousarray(mounting.inverse().apply(base_points))
    compiled = on_seen_ground(
        optical, depth, CAMERA, plane, None, below=0.03, range_min=0.1, range_max=3.0
    )
    coefficients, pixels, scale = lens_and_depth(CAMERA, depth)
    plain = np.zeros(len(optical), dtype=np.bool_)
    found = _on_ground_loop(
        optical, CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy, coefficients, pixels, scale,
        0.1, 3.0, np.asarray(plane.normal), plane.offset, 0.03, np.asarray(SEEN_MARGIN), plain,
        *profile_arrays(None),
    )  # fmt: skip
    assert 20 <= found == int(plain.sum())  # some on the floor, not all
    assert found < len(optical)
    np.testing.assert_array_equal(compiled, plain)
