"""The ground driven over (issue 25): a pitched LiDAR plane's floor returns are dropped.

A robot drives 8 m over a level floor and then up a 1:8 ramp (the floor around where it set
off, which the trail also takes, is forgotten by then). Half-way up, its body pitched
nose-up by the ramp's 7.1 deg, the LiDAR's plane (0.30 m above the base) runs down behind
it and meets the level floor it came from. Where it meets it is worked out here from the
geometry alone; a wall's reading in the same direction, nearer, stands well above it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest

from scanfuse.motion import PlanarPose
from scanfuse.stream import FusionStream
from scanfuse.trail import MAX_STEP, GroundTrail, TrailSettings
from scanfuse.transforms import Transform
from tests.support.ground_scene import NS, config, lidar_scan

if TYPE_CHECKING:
    from scanfuse.scan import Scan

GRADE = 1.0 / 8.0
SLOPE = math.atan(GRADE)
FOOT = 1.0  # x where the ramp starts
START = -7.0
LIDAR_HEIGHT = 0.30
STEP = 0.035  # metres a scan: 0.35 m/s at 10 Hz
HALF_WIDTH = TrailSettings().half_width


def pitch_at(x: float) -> float:
    """The body's pitch (radians, nose-up positive) at x: the ramp's slope on it."""
    return SLOPE if x >= FOOT else 0.0


def tilt(pitch_up: float) -> np.ndarray:
    """Base to level: nose-up is a negative ROS pitch."""
    return Transform.from_rpy(0.0, -pitch_up, 0.0).rotation_matrix


def height_at(x: float) -> float:
    return max(x - FOOT, 0.0) * GRADE


def floor_hit(x: float, angle: float) -> float:
    """The range at which the ray at `angle` (base frame) of a LiDAR LIDAR_HEIGHT above a
    base at x, pitched nose-up by its ramp, meets the level floor z = 0 (inf: never)."""
    pitch = pitch_at(x)
    origin_z = height_at(x) + LIDAR_HEIGHT * math.cos(pitch)
    fall = -math.cos(angle) * math.sin(pitch)  # metres down per metre of range
    return origin_z / fall if fall > 0.0 else math.inf


def path() -> list[float]:
    return list(np.arange(START, FOOT + 1.0, STEP))


def driven_trail() -> GroundTrail:
    trail = GroundTrail()
    for x in path():
        trail.advance(PlanarPose(float(x), 0.0, 0.0), tilt(pitch_at(x)), 0)
    return trail


def lidar_point(x: float, angle: float, reach: float) -> np.ndarray:
    """The reading's point in the base frame (the LiDAR's frame lies LIDAR_HEIGHT above)."""
    return np.array([[reach * math.cos(angle), reach * math.sin(angle), LIDAR_HEIGHT]])


def test_the_floor_behind_a_robot_on_a_ramp_is_ground_and_a_wall_there_is_not():
    trail = driven_trail()
    x = path()[-1]
    pose, rotation = PlanarPose(float(x), 0.0, 0.0), tilt(pitch_at(x))
    for degrees in (180.0, 175.0, -176.0):  # within 0.3 m of the path
        angle = math.radians(degrees)
        reach = floor_hit(x, angle)
        assert 2.0 < reach < 4.0  # behind the ramp's foot, on the floor driven over
        assert trail.on_ground(lidar_point(x, angle, reach), pose, rotation).all()
        # A wall at 60 % of that range: the plane meets it 0.17 m or more above the floor.
        wall = lidar_point(x, angle, 0.6 * reach)
        assert not trail.on_ground(wall, pose, rotation).any()


def test_ground_beside_the_path_counts_only_within_the_half_width():
    trail = driven_trail()
    x = path()[-1]
    pose, rotation = PlanarPose(float(x), 0.0, 0.0), tilt(pitch_at(x))
    # The level floor 3 m behind, within and beyond the half width to the side.
    for side, expected in ((0.8 * HALF_WIDTH, True), (1.4 * HALF_WIDTH, False)):
        behind = np.array([[-3.0, side, 0.0]])  # level-frame offset from the base ...
        # ... in the base frame, down to the floor: z = -(height of the base).
        level = np.array([[-3.0, side, -height_at(x)]])
        base = level @ rotation  # level = R base, so base = R^T level
        assert trail.on_ground(base, pose, rotation)[0] == expected, behind


def test_the_floor_around_where_the_trail_began_is_ground_out_to_the_start_radius():
    # Parked on a level floor, then 1 m up a 1:8 ramp: a LiDAR pitched by it meets the floor
    # behind where the robot set off, which it never drove over.
    radius = TrailSettings().start_radius

    def trail_from(settings: TrailSettings) -> GroundTrail:
        trail = GroundTrail(settings)
        for x in np.arange(FOOT - 0.5, FOOT + 1.0, STEP):
            trail.advance(PlanarPose(float(x), 0.0, 0.0), tilt(pitch_at(x)), 0)
        return trail

    x = float(np.arange(FOOT - 0.5, FOOT + 1.0, STEP)[-1])
    pose, rotation = PlanarPose(x, 0.0, 0.0), tilt(pitch_at(x))

    def on_ground(trail: GroundTrail, behind_start: float, aside: float, up: float) -> bool:
        level = np.array([[FOOT - 0.5 - behind_start - x, aside, up - height_at(x)]])
        return bool(trail.on_ground(level @ rotation, pose, rotation)[0])

    trail = trail_from(TrailSettings())
    assert on_ground(trail, 0.8 * radius - 0.5, 0.3 * radius, 0.0)
    assert not on_ground(trail, 0.8 * radius - 0.5, 0.3 * radius, 0.2)  # 20 cm up: a box
    assert not on_ground(trail, 1.1 * radius, 0.0, 0.0)  # beyond the radius: not known
    narrow = trail_from(TrailSettings(start_radius=0.0))  # the half width alone
    assert not on_ground(narrow, 0.8 * radius - 0.5, 0.3 * radius, 0.0)


def test_an_odometry_jump_or_reset_forgets_the_trail():
    trail = driven_trail()
    x = path()[-1]
    point = lidar_point(x, math.pi, floor_hit(x, math.pi))
    rotation = tilt(pitch_at(x))
    jumped = PlanarPose(x + 2.0 * MAX_STEP, 0.0, 0.0)
    trail.advance(jumped, rotation, 0)
    assert not trail.on_ground(point, jumped, rotation).any()
    trail = driven_trail()
    pose = PlanarPose(float(x), 0.0, 0.0)
    trail.advance(pose, rotation, 1)  # a new odometry segment
    assert not trail.on_ground(point, pose, rotation).any()


def scan_at(x: float, stamp_ns: int) -> Scan:
    """The LiDAR's scan at x: a wall 3 m ahead, the floor behind where the plane meets it."""
    empty = lidar_scan(stamp_ns)
    angles = empty.angles()
    ranges = np.array([floor_hit(x, float(a)) for a in angles])
    ahead = np.cos(angles) > 0.5
    ranges[ahead] = 3.0 / np.cos(angles[ahead])
    ranges[ranges > 9.0] = np.inf
    return empty.with_ranges(ranges.astype(np.float32))


def drive(*, imu: bool = True, **changes: object) -> tuple[Scan, Scan, FusionStream[int]]:
    """A LiDAR-only stream fed the drive at 10 Hz (odometry, IMU); the last scan as sent
    and as published."""
    stream: FusionStream[int] = FusionStream(
        config(lidar_height=LIDAR_HEIGHT, deskew=False, **changes)
    )
    out = sent = None
    for index, x in enumerate(path()):
        stamp = (index + 1) * NS // 10
        stream.add_odometry(stamp, PlanarPose(float(x), 0.0, 0.0))
        if imu:
            pitch = Transform.from_rpy(0.0, -pitch_at(x), 0.0).rotation
            stream.add_imu(stamp, pitch, 'base_link')
        sent = scan_at(float(x), stamp)
        (out,) = stream.add_scan(sent, index, stamp + 1)
    assert out is not None
    assert sent is not None
    published = out.fused if out.fused is not None else out.lidar
    return sent, published, stream


def test_the_stream_drops_the_floor_behind_and_keeps_the_wall_ahead():
    sent, published, stream = drive()
    angles = sent.angles()
    floor = np.isfinite(sent.ranges) & (np.cos(angles) < 0.0)
    aside = np.abs(sent.ranges * np.sin(angles))  # metres from the path driven
    on_path = floor & (aside < 0.9 * HALF_WIDTH)
    off_path = floor & (aside > 1.1 * HALF_WIDTH)
    wall = np.cos(angles) > 0.5
    assert on_path.sum() > 10
    assert off_path.sum() > 10
    assert np.isnan(published.ranges[on_path]).all()
    # Floor farther aside than the trail's half width is not known: it stays.
    np.testing.assert_array_equal(published.ranges[off_path], sent.ranges[off_path])
    np.testing.assert_array_equal(published.ranges[wall], sent.ranges[wall])
    assert stream.counts.lidar_on_ground >= on_path.sum()


@pytest.mark.parametrize(
    ('changes', 'imu'), [({'ground_trail': False}, True), ({}, False)], ids=['off', 'no IMU']
)
def test_without_the_trail_or_an_imu_the_floor_behind_stays(changes, imu):
    sent, published, stream = drive(imu=imu, **changes)
    np.testing.assert_array_equal(published.ranges, sent.ranges)
    assert stream.counts.lidar_on_ground == 0


SAG = math.radians(2.3)  # a sprung body's extra pitch up a 1:8 ramp, on its suspension


def sagging_trail(settings: TrailSettings | None = None) -> tuple[GroundTrail, float]:
    """The drive of `driven_trail` 1.5 m up the ramp, the body pitched SAG more than the
    ramp on it: the height the trail sums climbs faster than the ramp (5.9 cm in 1.5 m)."""
    trail = GroundTrail(settings)
    xs = list(np.arange(START, FOOT + 1.5, STEP))
    for x in xs:
        pitch = pitch_at(x) + (SAG if x >= FOOT else 0.0)
        trail.advance(PlanarPose(float(x), 0.0, 0.0), tilt(pitch), 0)
    return trail, float(xs[-1])


def test_a_sagging_bodys_height_drift_is_read_off_the_floor_its_lidar_meets():
    x_end = sagging_trail()[1]
    pitch = SLOPE + SAG  # the body's (and the LiDAR plane's) true pitch
    rotation = tilt(pitch)
    pose = PlanarPose(x_end, 0.0, 0.0)
    # Where the plane meets the level floor behind (worked from the geometry: the LiDAR
    # LIDAR_HEIGHT up the body, at height_at(x_end) above the floor; world = R base).
    lidar_z = height_at(x_end) + LIDAR_HEIGHT * math.cos(pitch)
    angles = np.radians(np.arange(166.0, 194.5, 0.5))  # behind, within the half width
    fall = -np.cos(angles) * math.sin(pitch)
    reach = lidar_z / fall
    floor = np.stack(
        [reach * np.cos(angles), reach * np.sin(angles), np.full_like(reach, LIDAR_HEIGHT)], 1
    )
    assert np.all(np.abs(floor[:, 1]) < 0.9 * HALF_WIDTH)
    # A wall across the path 1.2 m behind: the plane meets it 0.25 m above the ramp under
    # it (0.48 - 1.2 sin(pitch) - 0.036 m), more than the most drift and the tolerance.
    wall = np.array([[-1.2, 0.0, LIDAR_HEIGHT]])
    # Summed with the sagging pitch the base's height runs ahead of the ramp's by 1.5 m of
    # the two slopes' difference (5.9 cm): a floor reading stands that high above its cell,
    # beyond the tolerance (the trail with no drift allowed, below, finds none of them).
    trail, _ = sagging_trail()
    found = trail.on_ground(np.vstack([floor, wall]), pose, rotation)
    assert found[:-1].all()
    assert not found[-1]
    # One reading alone does not show the drift; with no drift allowed, none is the floor.
    assert not trail.on_ground(floor[:1], pose, rotation).any()
    fixed, _ = sagging_trail(TrailSettings(max_drift=0.0))
    assert not fixed.on_ground(floor, pose, rotation).any()
