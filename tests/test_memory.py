"""Obstacle memory through the stream, on hand-worked geometry.

A robot (camera 0.4 m up, pitched 15 degrees; LiDAR at its centre) stands at the origin.
A box whose front face is 1.5 m ahead is seen at yaw 0. The LiDAR's plane passes over it:
its scans are empty (+Inf) throughout, so whatever the fused scan holds of the box comes
from the camera or from the memory.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.errors import InputError
from scanfuse.memory import MemorySettings, ObstacleMemory, Placement
from scanfuse.motion import PlanarPose
from scanfuse.scan import AngleGrid, Scan
from scanfuse.scan_matching import Refusal
from scanfuse.stream import FusionStream
from scanfuse.transforms import Transform
from tests.support.render import (
    Box,
    camera_in_world,
    depth_image,
    ground_depth,
    millimetres,
    square_room_ranges,
    tilted_room_ranges,
)

NS = 1_000_000_000
CAMERA = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')
HEIGHT, PITCH = 0.4, math.radians(15.0)
BOX = Box(1.5, 1.7, -0.1, 0.1, 0.2)
NEAR_BOX = Box(1.0, 1.1, -0.3, 0.3, 0.45)  # hides BOX from the camera
READINGS = 720  # half a degree


def config(**changes) -> FusionConfig:
    values = {
        'use_tf': False,
        'camera_height': HEIGHT,
        'camera_pitch': PITCH,
        'lidar_height': 0.3,
        'obstacle_min_points': 1,
        # Each box is shown from its first frame: far readings' confirmation by the next
        # frame has its own tests (tests/test_far_confirm.py).
        'far_confirm_range': 0.0,
        **changes,
    }
    return FusionConfig(**values)


def lidar(stamp_ns: int) -> Scan:
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - 2 * math.pi / READINGS,
        angle_increment=2 * math.pi / READINGS,
        range_min=0.05,
        range_max=10.0,
        ranges=np.full(READINGS, np.inf, dtype=np.float32),
        frame_id='laser',
        stamp_ns=stamp_ns,
    )


class Robot:
    """Feeds a stream as a robot would: odometry at 50 Hz, a frame 20 ms before each scan."""

    def __init__(self, stream: FusionStream, world: list[Box]):
        self.stream = stream
        self.world = world
        self.pose = PlanarPose(0.0, 0.0, 0.0)
        self.now = NS
        stream.add_camera_info(CAMERA)
        stream.add_odometry(self.now, self.pose)

    def move_to(self, pose: PlanarPose, seconds: float) -> None:
        """Odometry of a smooth move to `pose` over `seconds` (50 Hz)."""
        start, steps = self.pose, max(1, round(seconds * 50))
        turn = math.remainder(pose.yaw - start.yaw, 2 * math.pi)
        for k in range(1, steps + 1):
            f = k / steps
            self.now += NS // 50
            self.pose = PlanarPose(
                start.x + (pose.x - start.x) * f,
                start.y + (pose.y - start.y) * f,
                start.yaw + turn * f,
            )
            self.stream.add_odometry(self.now, self.pose)

    def render(self, view: Transform) -> np.ndarray:
        return depth_image(CAMERA, view, self.world)

    def scan(self, *, camera: bool = True, odometry: PlanarPose | None = None):
        """One depth frame (20 ms old, same pose: the robot stands) and one LiDAR scan;
        `odometry`: what odometry says, when not the robot's pose (after a reset)."""
        self.now += NS // 50
        self.stream.add_odometry(self.now, self.pose if odometry is None else odometry)
        if camera:
            view = camera_in_world(
                self.pose.x, self.pose.y, self.pose.yaw, height=HEIGHT, pitch=PITCH
            )
            depth = self.render(view)
            self.stream.add_depth(self.now - 20_000_000, depth, self.now - 5_000_000)
        (out,) = self.stream.add_scan(lidar(self.now), None, self.now + 1_000_000)
        return out


def reading_at(scan: Scan, bearing: float) -> tuple[float, int]:
    """Nearest range within one slot of `bearing`, and the slot it is in."""
    grid = scan.grid
    slot = int(grid.slot_of(np.array([bearing]))[0])
    window = [(slot + k) % len(scan) for k in (-1, 0, 1)]
    values = scan.ranges[window]
    best = int(np.nanargmin(np.where(np.isfinite(values), values, np.inf)))
    return float(values[best]), window[best]


def box_front_range() -> float:
    return BOX.x_min  # straight ahead, the front face's nearest point


def test_a_box_stays_behind_the_robot_after_a_half_turn_and_the_lidar_never_clears_it():
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    seen = robot.scan()
    assert reading_at(seen.fused, 0.0)[0] == pytest.approx(box_front_range(), abs=0.02)
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)  # 1.57 rad/s in place
    for _ in range(5):  # the LiDAR passes over it, scan after scan
        behind = robot.scan()
    value, slot = reading_at(behind.fused, math.pi)
    assert value == pytest.approx(box_front_range(), abs=0.02)
    expected_slot = int(behind.fused.grid.slot_of(np.array([math.pi]))[0])
    assert min(abs(slot - expected_slot), READINGS - abs(slot - expected_slot)) <= 1
    assert behind.instant is not None or behind.passed is not None
    instant = behind.instant if behind.instant is not None else behind.lidar
    assert not np.isfinite(reading_at(instant, math.pi)[0])  # the camera alone has nothing there
    assert np.isfinite(behind.memory_scan.ranges).any()


def test_a_remembered_box_is_drawn_from_where_the_lidar_stands_on_a_body_pitched_up_a_ramp():
    # Seen level, the box is remembered 1.5 m ahead; the robot turns its back to it. Then
    # the base pitches nose up 7.1 degrees (a 1:8 ramp, as the IMU says): the LiDAR, 0.3 m
    # up the body, leans back 0.3 sin(7.1 deg) = 3.7 cm towards the box, which lies that
    # much nearer to it.
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)
    for _ in range(2):  # level, looking away
        level = robot.scan()
    assert reading_at(level.fused, math.pi)[0] == pytest.approx(box_front_range(), abs=0.005)
    slope = math.atan(1 / 8)
    for _ in range(2):
        stream.add_imu(robot.now + NS // 50, Transform.from_rpy(0.0, -slope, 0.0).rotation,
                       'base_link')  # fmt: skip
        pitched = robot.scan(camera=False)
    value = reading_at(pitched.fused, math.pi)[0]
    assert value == pytest.approx(box_front_range() - 0.3 * math.sin(slope), abs=0.005)


def test_a_box_is_remembered_where_its_pixels_are_not_where_a_coarse_slot_centres_its_edge():
    # An output grid of 2 degree slots: the one centred 4 degrees left spans 3 to 5. The
    # box's corners stand at atan(0.0812 / 1.5) = 3.1 degrees either side: the slot holds
    # a sliver of the box's face and reads it, but its centre line passes the box. Set at
    # that line, the reading would stand 1.5 (tan 4 - tan 3.1 deg) = 2.4 cm beside the box;
    # seen later from beside it, a slot the box does not reach. Its pixels lie on the box.
    half_width = 1.5 * math.tan(math.radians(3.1))
    box = Box(1.5, 1.7, -half_width, half_width, 0.2)
    stream = FusionStream(config(angle_increment=math.radians(2.0)))
    robot = Robot(stream, [box])
    robot.scan()
    x, y = stream.memory.points()
    assert x.size > 0
    outside = np.maximum.reduce([box.x_min - x, x - box.x_max, np.abs(y) - half_width])
    assert outside.max() <= 0.005


class SpeckRobot(Robot):
    """An empty floor with one pixel (the image's centre column, row 180) at 0.8 of its
    depth: along the ray from a camera 0.4 m up, a point 0.2 x 0.4 = 8 cm above the floor,
    in the slab, alone: stereo noise lifting one pixel of the floor."""

    def render(self, view: Transform) -> np.ndarray:
        depth = super().render(view)
        depth[180, 160] = round(0.8 * int(depth[180, 160]))
        return depth


def test_a_reading_of_one_stray_pixel_is_shown_but_not_remembered():
    stream = FusionStream(config())
    robot = SpeckRobot(stream, [])
    seen = robot.scan()
    live = seen.instant if seen.instant is not None else seen.fused
    assert np.isfinite(live.ranges).sum() == 1  # the speck's slot, from the camera
    # Its neighbours disagree with it by 25 %, so it is no pixel the memory takes, and no
    # pixel stands for its slot's reading.
    assert len(stream.memory) == 0


class LedgeRobot(Robot):
    """The floor ends 1.2 m ahead of the start: beyond it lies 0.4 m lower (a loading dock)."""

    EDGE = 1.2

    def render(self, view: Transform) -> np.ndarray:
        pieces = [(-math.inf, self.EDGE, 0.0, 0.0), (self.EDGE, math.inf, -0.4, 0.0)]
        return millimetres(ground_depth(CAMERA, view, pieces))


def test_a_ledge_seen_ahead_is_remembered_behind_though_no_slab_pixel_stands_there():
    stream = FusionStream(config())
    robot = LedgeRobot(stream, [])
    ahead = reading_at(robot.scan().fused, 0.0)[0]
    # The line of sight of the first pixel beyond the edge crosses the floor's plane at
    # the edge or a little past it.
    assert LedgeRobot.EDGE - 0.02 <= ahead <= LedgeRobot.EDGE + 0.15
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)
    for _ in range(5):
        behind = robot.scan()
    assert reading_at(behind.fused, math.pi)[0] == pytest.approx(ahead, abs=0.03)


def test_the_camera_looking_at_the_empty_place_clears_it_within_one_frame():
    world = [BOX]
    stream = FusionStream(config())
    robot = Robot(stream, world)
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)
    robot.scan()
    world.clear()  # someone takes the box away while the robot looks elsewhere
    assert np.isfinite(reading_at(robot.scan().fused, math.pi)[0])  # still remembered
    robot.move_to(PlanarPose(0.0, 0.0, 0.0), 2.0)
    back = robot.scan()  # the first frame that sees the place
    assert not reading_at(back.fused, 0.0)[0] < 2.0
    assert len(stream.memory) == 0
    assert stream.counts.memory_cleared > 0


def test_a_point_hidden_behind_a_nearer_obstacle_is_not_cleared():
    world = [BOX]
    stream = FusionStream(config())
    robot = Robot(stream, world)
    robot.scan()
    world.append(NEAR_BOX)
    world.remove(BOX)  # gone, but the camera cannot see that: NEAR_BOX hides the place
    robot.scan()
    x, _ = stream.memory.points()
    assert (np.abs(x - BOX.x_min) < 0.05).any()  # the far box's points are still remembered
    assert (np.abs(x - NEAR_BOX.x_min) < 0.05).any()


def test_points_older_than_memory_time_are_forgotten():
    stream = FusionStream(config(memory_time=5.0))
    robot = Robot(stream, [BOX])
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)
    assert np.isfinite(reading_at(robot.scan().fused, math.pi)[0])
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 4.0)  # standing, 6 s after it was seen
    late = robot.scan()
    assert not np.isfinite(reading_at(late.fused, math.pi)[0])
    assert len(stream.memory) == 0


def test_time_standing_still_does_not_age_the_memory_when_memory_ages_while_stopped_is_off():
    stream = FusionStream(config(memory_time=5.0, memory_ages_while_stopped=False))
    robot = Robot(stream, [BOX])
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)  # turning: these 2 s count
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 30.0)  # held still 30 s: they do not
    held = robot.scan()
    assert reading_at(held.fused, math.pi)[0] == pytest.approx(box_front_range(), abs=0.02)
    robot.move_to(PlanarPose(-0.3, 0.0, math.pi), 4.0)  # driving on: 2 + 4 s > 5 s
    robot.scan()
    assert len(stream.memory) == 0


def test_points_beyond_memory_radius_are_forgotten():
    stream = FusionStream(config(memory_radius=2.0))
    robot = Robot(stream, [BOX])
    robot.scan()
    robot.move_to(PlanarPose(0.0, 0.0, math.pi), 2.0)
    robot.move_to(PlanarPose(-0.6, 0.0, math.pi), 1.0)  # 2.1 m from the box's front face
    out = robot.scan(camera=False)
    assert len(stream.memory) == 0
    assert out.memory_scan is not None
    assert not np.isfinite(out.memory_scan.ranges).any()


def test_without_odometry_there_is_no_memory():
    stream = FusionStream(config())
    stream.add_camera_info(CAMERA)
    view = camera_in_world(0.0, 0.0, 0.0, height=HEIGHT, pitch=PITCH)
    stream.add_depth(NS, depth_image(CAMERA, view, [BOX]), NS)
    (out,) = stream.add_scan(lidar(NS + 10_000_000), None, NS + 10_000_000)
    assert out.memory_scan is None
    assert len(stream.memory) == 0


def test_frozen_odometry_freezes_the_memory_then_drops_it_after_the_timeout():
    stream = FusionStream(config(memory_odometry_timeout=1.0, max_odometry_extrapolation=0.1))
    robot = Robot(stream, [BOX])
    robot.scan()
    assert len(stream.memory) > 0
    remembered = len(stream.memory)
    # Odometry stops; scans go on (the camera too).
    for k in range(2, 7):  # past max_odometry_extrapolation
        stamp = robot.now + k * NS // 10
        out = stream.add_scan(lidar(stamp), None, stamp)[0]
        assert out.memory_scan is None  # not placed: frozen
    assert len(stream.memory) == remembered
    late = robot.now + 2 * NS
    stream.add_scan(lidar(late), None, late)
    assert len(stream.memory) == 0
    assert stream.counts.memory_dropped == 1


def test_an_odometry_jump_clears_the_memory():
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan()
    assert len(stream.memory) > 0
    robot.now += NS // 50
    robot.pose = PlanarPose(10.0, 0.0, 0.0)  # a reset: 10 m in 20 ms
    stream.add_odometry(robot.now, robot.pose)
    robot.world.clear()
    robot.scan(camera=False)
    assert len(stream.memory) == 0
    assert stream.counts.memory_dropped == 1


def test_memory_off_at_run_time_drops_it_and_on_again_starts_empty():
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan()
    assert len(stream.memory) > 0
    stream.reconfigure(config(memory=False))
    assert stream.memory is None
    out = robot.scan()
    assert out.memory_scan is None
    stream.reconfigure(config(memory=True))
    assert len(stream.memory) == 0
    stream.reconfigure(config(memory=True, memory_time=30.0))  # the store is kept
    robot.scan()
    kept = len(stream.memory)
    stream.reconfigure(config(memory=True, memory_time=10.0))
    assert len(stream.memory) == kept


def test_the_store_is_bounded_by_its_grid_whatever_is_added():
    memory = ObstacleMemory(MemorySettings(radius=1.0, cell=0.05))
    rng = np.random.default_rng(1)
    for stamp in range(50):
        x, y = rng.uniform(-50, 50, 10_000), rng.uniform(-50, 50, 10_000)
        memory.add(x, y, stamp, robot=(0.0, 0.0))
    assert len(memory) <= MemorySettings(radius=1.0, cell=0.05).side ** 2
    memory.scan(
        Placement.of(PlanarPose(0.0, 0.0, 0.0), Transform()),
        AngleGrid(-math.pi, 0.01, 628),
        robot=(0.0, 0.0),
        now_ns=50,
    )
    x, y = memory.points()
    assert np.all(np.hypot(x, y) <= 1.0)


def test_nan_points_are_not_remembered():
    memory = ObstacleMemory()
    memory.add(np.array([np.nan, 1.0]), np.array([0.0, np.inf]), 0, robot=(0.0, 0.0))
    assert len(memory) == 0


def test_projection_of_a_remembered_point_from_an_upside_down_lidar_is_mirrored():
    memory = ObstacleMemory()
    memory.add(np.array([0.0]), np.array([1.0]), 0, robot=(0.0, 0.0))  # 1 m to the base's left
    grid = AngleGrid(-math.pi, 2 * math.pi / 360, 360)
    here = {'robot': (0.0, 0.0), 'now_ns': 0}
    upright = memory.scan(Placement.of(PlanarPose(0.0, 0.0, 0.0), Transform()), grid, **here)
    flipped = memory.scan(
        Placement.of(PlanarPose(0.0, 0.0, 0.0), Transform.from_rpy(math.pi, 0.0, 0.0)),
        grid,
        **here,
    )
    left = int(grid.slot_of(np.array([math.pi / 2]))[0])
    right = int(grid.slot_of(np.array([-math.pi / 2]))[0])
    assert upright[left] == pytest.approx(1.0)
    assert flipped[right] == pytest.approx(1.0)  # its y axis points right


def test_bad_memory_settings_are_errors():
    with pytest.raises(InputError, match='memory radius must be a positive finite number'):
        MemorySettings(radius=math.nan)
    with pytest.raises(InputError, match='use a larger memory_cell'):
        MemorySettings(radius=100.0, cell=0.01)


# ------------------------------------------------------------ drifting wheel odometry

ROOM_OFFSET = (0.4, -0.3)  # the robot in the room of walls x, y = +-3 m (off its centre)
OVER_COUNT = 1.03  # wheel slip: odometry reports 3 % more turn than the robot made


class DriftingRobot(Robot):
    """Turns in place while its wheel odometry over-counts the turn; its LiDAR (10 Hz, the
    robot's true heading) sees the room's walls, 0.3 m up, over the box. `turning_pitch`:
    the base's pitch while it turns, as its IMU says and its LiDAR's plane shows (0: level,
    no IMU)."""

    def __init__(self, stream: FusionStream, world: list[Box], turning_pitch: float = 0.0):
        super().__init__(stream, world)
        self.true_yaw = 0.0
        self.turning_pitch = turning_pitch

    def room_scan(self) -> Scan:
        empty = lidar(self.now)
        if self.turning_pitch:
            tilt = Transform.from_rpy(0.0, self.turning_pitch, 0.0).rotation_matrix
            base = (*ROOM_OFFSET, self.true_yaw)
            ranges = tilted_room_ranges(base, tilt, empty.angles(), height=0.3, half=3.0)
        else:
            ranges = square_room_ranges(ROOM_OFFSET, self.true_yaw, empty.angles(), half=3.0)
        return empty.with_ranges(ranges.astype(np.float32))

    def turn_to(self, yaw: float, seconds: float) -> None:
        start, steps = self.true_yaw, round(seconds * 50)
        for k in range(1, steps + 1):
            self.now += NS // 50
            self.true_yaw = start + (yaw - start) * k / steps
            self.pose = PlanarPose(0.0, 0.0, self.true_yaw * OVER_COUNT)
            self.stream.add_odometry(self.now, self.pose)
            if self.turning_pitch:
                tilt = Transform.from_rpy(0.0, self.turning_pitch, 0.0)
                self.stream.add_imu(self.now, tilt.rotation, 'base_link')
            if k % 5 == 0:  # the camera looks away from the box: only the LiDAR matters
                self.stream.add_scan(self.room_scan(), None, self.now + 1_000_000)

    def scan(self, *, camera: bool = True):
        self.now += NS // 50
        self.stream.add_odometry(self.now, self.pose)
        if camera:
            view = camera_in_world(0.0, 0.0, self.true_yaw, height=HEIGHT, pitch=PITCH)
            depth = depth_image(CAMERA, view, self.world)
            self.stream.add_depth(self.now - 20_000_000, depth, self.now - 5_000_000)
        (out,) = self.stream.add_scan(self.room_scan(), None, self.now + 1_000_000)
        return out


def remembered_bearing(scan: Scan) -> float:
    """Circular mean bearing of the remembered slots (the box's, symmetric about its centre)."""
    angles = scan.angles()[np.isfinite(scan.ranges)]
    return math.atan2(np.sin(angles).mean(), np.cos(angles).mean())


def turned_half_way(**changes) -> tuple[FusionStream, object]:
    stream = FusionStream(config(**changes))
    robot = DriftingRobot(stream, [BOX])
    seen = robot.scan()
    assert reading_at(seen.fused, 0.0)[0] == pytest.approx(box_front_range(), abs=0.02)
    robot.turn_to(math.pi, 2.0)  # 1.57 rad/s in place; odometry says 1.03 pi
    for _ in range(3):
        behind = robot.scan()
    return stream, behind


def test_scan_matching_keeps_the_box_at_its_true_bearing_when_odometry_over_counts_a_half_turn():
    stream, behind = turned_half_way()
    value, slot = reading_at(behind.fused, math.pi)
    assert value == pytest.approx(box_front_range(), abs=0.02)
    expected_slot = int(behind.fused.grid.slot_of(np.array([math.pi]))[0])
    assert min(abs(slot - expected_slot), READINGS - abs(slot - expected_slot)) <= 1
    increment = 2 * math.pi / READINGS
    offset = math.remainder(remembered_bearing(behind.memory_scan) - math.pi, 2 * math.pi)
    assert abs(offset) <= increment
    assert stream.counts.drift_matched >= 20  # every scan of the turn matched
    assert stream.counts.drift_refused == 0


def test_a_lidar_tilted_on_a_ramp_is_matched_levelled_by_the_imu_and_the_box_stays_put():
    # The same turn on a 1:8 ramp (the base pitched 7.1 degrees, as the IMU says): the
    # LiDAR's plane meets the floor behind and slices the walls higher ahead; levelled by
    # the IMU's pitch, every scan of the turn is matched as on the level.
    stream = FusionStream(config())
    robot = DriftingRobot(stream, [BOX], turning_pitch=-math.atan(1 / 8))
    robot.scan()
    robot.turn_to(math.pi, 2.0)
    behind = robot.scan(camera=False)
    assert stream.counts.drift_matched >= 20
    assert Refusal.TILTED not in stream.drift.refused
    offset = math.remainder(remembered_bearing(behind.memory_scan) - math.pi, 2 * math.pi)
    assert abs(offset) <= 2 * 2 * math.pi / READINGS


def test_a_lidar_tilted_beyond_levelling_is_not_matched_and_the_memory_follows_odometry():
    # Pitched 15 degrees (beyond `max_levelled_tilt`, 12): not matched, even levelled.
    stream = FusionStream(config())
    robot = DriftingRobot(stream, [BOX], turning_pitch=-math.radians(15.0))
    robot.scan()
    robot.turn_to(math.pi, 2.0)
    behind = robot.scan(camera=False)
    assert stream.counts.drift_matched == 0
    assert stream.drift.refused[Refusal.TILTED] >= 20  # every scan of the turn
    offset = math.remainder(remembered_bearing(behind.memory_scan) - math.pi, 2 * math.pi)
    assert offset == pytest.approx(-0.03 * math.pi, abs=2 * 2 * math.pi / READINGS)


def test_the_first_level_scan_after_a_tilted_turn_puts_the_memory_back_on_the_walls():
    # Level, the box ahead is remembered; then the same turn pitched 15 degrees (not
    # matched: the memory follows odometry's 3 % over-count), and one thing taken on the way
    # (1 m straight ahead at the end of the turn, where odometry's heading puts it).
    stream = FusionStream(config())
    robot = DriftingRobot(stream, [BOX], turning_pitch=0.0)
    robot.scan()
    robot.turning_pitch = -math.radians(15.0)
    robot.turn_to(math.pi, 2.0)
    assert stream.counts.drift_matched == 0
    heading = math.pi * OVER_COUNT
    memory = stream.memory
    ahead_then = (np.array([math.cos(heading)]), np.array([math.sin(heading)]))
    memory.add(*ahead_then, robot.now, robot=(0.0, 0.0))
    # Level again (the IMU says so): matched against the scan before the turn, the
    # correction takes out the whole over-count, and what the memory took meanwhile moves
    # with it.
    robot.turning_pitch = 0.0
    for _ in range(2):  # the first scan's output leaves with the second
        stream.add_imu(robot.now + NS // 50, Transform().rotation, 'base_link')
        behind = robot.scan(camera=False)
    assert stream.drift.anchored == 1
    assert stream.drift.correction.yaw == pytest.approx(-0.03 * math.pi, abs=0.002)
    offset = math.remainder(remembered_bearing(behind.memory_scan) - math.pi, 2 * math.pi)
    assert abs(offset) <= 2 * 2 * math.pi / READINGS  # the box, taken before: where it is
    x, y = memory.points()
    ahead = np.hypot(x + 1.0, y) < 0.01  # 1 m ahead of the robot, which faces -x
    assert np.count_nonzero(ahead) == 1


def test_without_scan_matching_the_box_is_off_by_the_odometry_s_over_count():
    _, behind = turned_half_way(memory_scan_matching=False)
    # Remembered at odom bearing 0; odometry's heading is 1.03 pi, so the box is drawn at
    # -1.03 pi = pi - 0.094 rad: 10.8 slots of half a degree short of where it is.
    expected = -0.03 * math.pi
    offset = math.remainder(remembered_bearing(behind.memory_scan) - math.pi, 2 * math.pi)
    assert offset == pytest.approx(expected, abs=2 * 2 * math.pi / READINGS)


def test_switching_scan_matching_at_run_time_drops_the_memory():
    stream = FusionStream(config())
    robot = DriftingRobot(stream, [BOX])
    robot.scan()
    assert len(stream.memory) > 0
    stream.reconfigure(config(memory_scan_matching=False))
    assert len(stream.memory) == 0
    assert stream.counts.memory_dropped == 1


def test_an_odometry_jump_resets_the_drift_correction_with_the_memory():
    stream, _ = turned_half_way()
    assert abs(stream.drift.correction.yaw) == pytest.approx(0.03 * math.pi, abs=0.005)
    now = stream.odometry.newest_ns + NS // 50
    stream.add_odometry(now, PlanarPose(10.0, 0.0, 0.0))  # a reset: 10 m in 20 ms
    stream.add_odometry(now + NS // 50, PlanarPose(10.0, 0.0, 0.0))
    stream.add_scan(lidar(now + NS // 50), None, now + NS // 50)
    assert len(stream.memory) == 0
    assert stream.drift.correction == PlanarPose(0.0, 0.0, 0.0)
