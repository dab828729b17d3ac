"""Obstacle memory's store on hand-worked geometry: which points it keeps, how it draws them.

The sensor sits at the origin of the odometry frame facing +x unless a test says
otherwise; cells are 2.5 cm, so cell (i, j) spans [0.025 i, 0.025 (i + 1)) in x and the
same in y.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanfuse.camera import CameraModel
from scanfuse.errors import InputError
from scanfuse.memory import (
    OWN_WIDTH,
    MemorySettings,
    ObstacleMemory,
    Placement,
    nearest_pixels,
    not_nearer_than,
    slab_points,
    unseen_by,
    worth_remembering,
)
from scanfuse.motion import PlanarPose
from scanfuse.scan import AngleGrid, Scan
from scanfuse.stream import FusionStream
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.render import camera_in_world, depth_image
from tests.test_memory import BOX, CAMERA, HEIGHT, NS, PITCH, Robot, config, lidar

SLOTS = 3600  # a tenth of a degree
GRID = AngleGrid(-math.pi, 2 * math.pi / SLOTS, SLOTS)
AT_ORIGIN = Placement.of(PlanarPose(0.0, 0.0, 0.0), Transform())
ORIGIN = (0.0, 0.0)  # the robot, odometry frame
HERE = {'robot': ORIGIN, 'now_ns': 0}


def at_degrees(ranges: np.ndarray, degrees: float) -> float:
    return float(ranges[int(GRID.slot_of(np.array([math.radians(degrees)]))[0])])


def test_two_neighbouring_cells_are_drawn_as_the_line_between_them_at_the_nearer_range():
    memory = ObstacleMemory()
    # Cells (40, 0) and (40, 1): north neighbours, at bearings 0.716 and 2.148 degrees.
    memory.add(np.array([1.0, 1.0]), np.array([0.0125, 0.0375]), 0, robot=ORIGIN)
    ranges = memory.scan(AT_ORIGIN, GRID, **HERE)
    nearer = math.hypot(1.0, 0.0125)
    assert at_degrees(ranges, 1.4) == pytest.approx(nearer, abs=1e-6)  # between the two
    # Beyond the ends only the points' own width: a quarter cell (0.18 degrees at 1 m).
    own = math.degrees(OWN_WIDTH * 0.0125 / 1.0)
    assert at_degrees(ranges, 2.148 + own - 0.1) == pytest.approx(math.hypot(1, 0.0375), abs=1e-6)
    assert math.isnan(at_degrees(ranges, 2.148 + own + 0.15))
    assert math.isnan(at_degrees(ranges, 0.716 - own - 0.15))


def test_a_lone_point_does_not_overhang_into_the_free_slot_beside_it():
    memory = ObstacleMemory()
    memory.add(np.array([1.0]), np.array([0.0125]), 0, robot=ORIGIN)  # 0.716 degrees
    ranges = memory.scan(AT_ORIGIN, GRID, **HERE)
    assert at_degrees(ranges, 0.716) == pytest.approx(math.hypot(1.0, 0.0125), abs=1e-6)
    # Widened by half a cell either side it would reach 0.716 + 0.716 = 1.43 degrees.
    assert math.isnan(at_degrees(ranges, 1.2))
    assert np.count_nonzero(np.isfinite(ranges)) <= 5


def test_a_filled_area_reads_its_near_border_whatever_is_inside():
    memory = ObstacleMemory()
    # A 5 x 5 block of cell centres, its near column at x = 1.0125 m.
    xs, ys = np.meshgrid(1.0125 + 0.025 * np.arange(5), 0.025 * np.arange(-2, 3))
    memory.add(xs.ravel(), ys.ravel(), 0, robot=ORIGIN)
    ranges = memory.scan(AT_ORIGIN, GRID, **HERE)
    assert at_degrees(ranges, 0.0) == pytest.approx(1.0125, abs=1e-6)
    # The block spans atan(0.05 / 1.0125) = 2.83 degrees either side of the axis.
    # There the nearer end of the near column's last line: (1.0125, 0.025).
    assert at_degrees(ranges, 2.5) == pytest.approx(math.hypot(1.0125, 0.025), abs=1e-6)
    assert math.isnan(at_degrees(ranges, 3.5))


def test_a_line_across_the_wrap_of_the_grid_is_drawn_across_it():
    memory = ObstacleMemory()
    # Behind the sensor: cells (-40, -1) and (-40, 0) straddle the bearing +-180 degrees.
    memory.add(np.array([-0.9875, -0.9875]), np.array([-0.0125, 0.0125]), 0, robot=ORIGIN)
    ranges = memory.scan(AT_ORIGIN, GRID, **HERE)
    r = math.hypot(0.9875, 0.0125)
    assert ranges[0] == pytest.approx(r, abs=1e-6)  # slot 0 is centred on -180 degrees
    assert ranges[SLOTS - 1] == pytest.approx(r, abs=1e-6)
    assert np.count_nonzero(np.isfinite(ranges)) < 30  # not the whole turn


def test_only_cells_that_enough_pixels_fall_in_are_remembered():
    memory = ObstacleMemory()
    x = np.array([1.001, 1.002, 1.003, 1.051, 1.052, np.nan])
    y = np.array([0.001, 0.002, 0.003, 0.001, 0.002, 0.0])
    assert (
        memory.add_dense(x, y, 0, min_count=3, robot=ORIGIN) == 1
    )  # three in cell (40, 0), two in (42, 0)
    kept_x, kept_y = memory.points()
    # The mean of the three points of cell (40, 0), not the pair's of (42, 0).
    assert kept_x.tolist() == pytest.approx([1.002], abs=1e-12)
    assert kept_y.tolist() == pytest.approx([0.002], abs=1e-12)


# A 4 x 3 pixel camera 0.2 m up, looking along +x: pixel (u, v) has the ray
# x_n = (u - 1.5) / 100, y_n = (v - 1) / 100, so at depth 1 m its point is
# (1, -x_n, 0.2 - y_n) in the odometry frame: heights 0.21, 0.20, 0.19 by row.
TINY = CameraModel.from_intrinsics(4, 3, 100.0, 100.0, 1.5, 1.0)
LOOKING_AHEAD = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, 0.2)) @ BODY_TO_OPTICAL


def test_slab_points_are_the_pixels_inside_the_slab_and_the_range_limits():
    depth = np.full((3, 4), 1000, dtype=np.uint16)  # 1 m
    depth[0, 0] = 0  # no return
    depth[1, 3] = 4000  # beyond range_max
    x, y = slab_points(depth, TINY, LOOKING_AHEAD, slab=(0.195, 0.5), range_min=0.2, range_max=3.0)
    # Rows 0 and 1 (heights 0.21 and 0.20) are in the slab, row 2 (0.19) is not; two
    # pixels of them are invalid.
    assert x.size == 6
    np.testing.assert_allclose(x, 1.0, atol=1e-6)
    np.testing.assert_allclose(
        sorted(y), sorted([0.005, -0.005, -0.015, 0.015, 0.005, -0.005]), atol=1e-6
    )


def test_slab_points_raise_the_slab_bottom_by_each_pixels_height_noise():
    # Height 0.2 - y_n Z: a point of row 0 gains a_z = 0.01 m per metre of depth, row 1
    # none (a level ray). The bottom rises by 2 |a_z| Z^2: to 0.215 for row 0 at 1 m (its
    # 0.21 is out), and not at all for row 1 (its 0.20 stays in).
    depth = np.full((3, 4), 1000, dtype=np.uint16)
    depth[1, 3] = 4000  # beyond range_max
    x, y = slab_points(
        depth, TINY, LOOKING_AHEAD, slab=(0.195, 0.5), range_min=0.2, range_max=3.0,
        bottom_noise=2.0,
    )  # fmt: skip
    np.testing.assert_allclose(x, 1.0, atol=1e-6)
    np.testing.assert_allclose(sorted(y), sorted([0.015, 0.005, -0.005]), atol=1e-6)


def test_slab_points_of_a_float_image_skip_nan():
    depth = np.full((3, 4), np.nan, dtype=np.float32)
    depth[0, 1] = 2.0  # x_n = -0.005: at (2, 0.01, 0.2 + 0.02)
    x, y = slab_points(depth, TINY, LOOKING_AHEAD, slab=(0.03, 0.5), range_min=0.2, range_max=3.0)
    np.testing.assert_allclose(x, [2.0], atol=1e-6)
    np.testing.assert_allclose(y, [0.01], atol=1e-6)


def test_slab_points_that_disagree_with_a_horizontal_neighbour_are_left_out():
    depth = np.full((3, 4), 1000, dtype=np.uint16)
    depth[0, 2] = 1030  # 3 % behind its neighbours: more than 2 % apart
    depth[1, 0] = 0  # no return beside pixel (1, 1)
    depth[1, 3] = 1015  # 1.5 % behind pixel (1, 2): within 2 %
    x, y = slab_points(
        depth, TINY, LOOKING_AHEAD, slab=(0.195, 0.5), range_min=0.2, range_max=3.0,
        agreement=0.02,
    )  # fmt: skip
    # Columns 0 and 3 have one neighbour each; row 0's middle pixels each have the 1.03 m
    # one beside (or are it); (1, 1) has the empty pixel beside it. Left: (1, 2), at
    # x_n = 0.005, the point (1, -0.005).
    np.testing.assert_allclose(x, [1.0], atol=1e-6)
    np.testing.assert_allclose(y, [-0.005], atol=1e-6)
    everything = slab_points(
        depth, TINY, LOOKING_AHEAD, slab=(0.195, 0.5), range_min=0.2, range_max=3.0
    )
    assert everything[0].size == 7  # without it: rows 0 and 1 but the empty pixel


def test_slab_points_refuse_a_negative_agreement():
    depth = np.full((3, 4), 1000, dtype=np.uint16)
    with pytest.raises(InputError, match=r'agreement must be a share >= 0, got -0\.1'):
        slab_points(
            depth, TINY, LOOKING_AHEAD, slab=(0.0, 0.5), range_min=0.2, range_max=3.0,
            agreement=-0.1,
        )  # fmt: skip


# Four 90-degree slots centred on -180, -90, 0 and 90 degrees.
QUARTERS = Scan(
    -math.pi, math.pi / 2, math.pi / 2, 0.1, 10.0, np.array([np.inf, np.nan, 1.0, 2.0], np.float32)
)
POINTS = (np.array([1.5, 0.5, 0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0, -1.0, 0.0]))


def test_what_the_lidar_sees_at_or_before_a_point_is_not_for_the_memory():
    unseen = unseen_by(*POINTS, QUARTERS, AT_ORIGIN, (0.05, 0.02))
    # (1.5, 0): the LiDAR reads 1.0 in front of it. (0.5, 0): 1.0 lies beyond 0.5 * 1.02 +
    # 0.05. (0, 1): 2.0 beyond. (0, -1): NaN, no reading. (-1, 0): +Inf, nothing seen.
    assert unseen.tolist() == [False, True, True, True, True]


def test_pixels_nearer_than_the_obstacle_reading_of_their_slot_are_noise():
    behind = not_nearer_than(*POINTS, QUARTERS, AT_ORIGIN)
    # Only (1.5, 0) lies at or behind a finite reading (1.0) of its slot.
    assert behind.tolist() == [True, False, False, False, False]


def test_worth_remembering_is_behind_the_depth_reading_and_unseen_by_the_lidar():
    # Depth scan: 0.8 m behind (slot 0), 1.2 m ahead (slot 2); LiDAR: QUARTERS (+Inf behind,
    # 1.0 ahead). (1.5, 0) lies behind 1.2 but the LiDAR sees 1.0 before it; (-1, 0) lies
    # behind 0.8 where the LiDAR sees nothing: kept; (-0.5, 0) is nearer than 0.8; (0, 1) has
    # no depth reading in its slot.
    depth = QUARTERS.with_ranges(np.array([0.8, np.nan, 1.2, np.nan], np.float32))
    x, y = np.array([1.5, -1.0, -0.5, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])
    both = worth_remembering(x, y, depth, QUARTERS, AT_ORIGIN, (0.05, 0.02))
    assert both.tolist() == [False, True, False, False]
    apart = not_nearer_than(x, y, depth, AT_ORIGIN) & unseen_by(
        x, y, QUARTERS, AT_ORIGIN, (0.05, 0.02)
    )
    assert both.tolist() == apart.tolist()
    # On another grid (the LiDAR's 8 slots) the same points, the same answer.
    eighths = Scan(-math.pi, 3 * math.pi / 4, math.pi / 4, 0.1, 10.0,
                   np.array([np.inf] * 4 + [1.0] * 2 + [2.0] * 2, np.float32))  # fmt: skip
    assert worth_remembering(x, y, depth, eighths, AT_ORIGIN, (0.05, 0.02)).tolist() == [
        False, True, False, False,
    ]  # fmt: skip


def test_a_box_top_seen_from_above_is_remembered_as_far_as_its_far_edge():
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan()
    x, y = stream.memory.points()
    # The camera (0.4 m up) sees the 0.2 m box's front face and its top back to x = 1.7:
    # the depth scan alone has only the face at 1.5.
    assert x.size > 0
    assert x.max() > 1.65
    assert np.all((x >= BOX.x_min - 0.03) & (x <= BOX.x_max + 0.03))
    assert np.all((y >= BOX.y_min - 0.03) & (y <= BOX.y_max + 0.03))


def test_a_box_the_lidar_sees_is_not_remembered():
    stream = FusionStream(config())
    robot = Robot(stream, [BOX])
    robot.scan(camera=False)  # odometry and CameraInfo in; then a frame and a LiDAR scan
    # that reads the box's front face (x = 1.5) in every slot the face spans.
    empty = lidar(0)
    angles = empty.angles()
    face = (np.cos(angles) > 0) & (np.abs(np.tan(angles)) * BOX.x_min <= BOX.y_max)
    ranges = np.where(face, BOX.x_min / np.cos(angles), np.inf).astype(np.float32)
    robot.now += NS // 50
    stream.add_odometry(robot.now, robot.pose)
    view = camera_in_world(0.0, 0.0, 0.0, height=HEIGHT, pitch=PITCH)
    stream.add_depth(robot.now - 20_000_000, depth_image(CAMERA, view, [BOX]), robot.now)
    (out,) = stream.add_scan(lidar(robot.now).with_ranges(ranges), None, robot.now + 1_000_000)
    assert out.depth_scan is not None
    assert np.isfinite(out.depth_scan.ranges).any()
    # The face and the top behind it lie at or beyond the LiDAR's reading of their slot.
    assert len(stream.memory) == 0


def test_settings_side_covers_the_radius():
    assert MemorySettings(radius=2.0, cell=0.025).side == 162


def test_a_scan_adds_its_kept_in_range_readings_at_their_place_in_odom():
    memory = ObstacleMemory()
    # Four slots at -180, -90, 0 and 90 degrees, seen from a LiDAR at (1, 2) facing +y.
    scan = Scan(
        -math.pi, math.pi / 2, math.pi / 2, 0.1, 10.0, np.array([0.05, 3.0, 1.0, 2.0], np.float32)
    )
    sensor = Placement.of(PlanarPose(1.0, 2.0, math.pi / 2), Transform())
    # Slot 0 reads below range_min; slot 1 (3 m) is not kept.
    memory.add_scan(scan, sensor, 7, np.array([True, False, True, True]), robot=(0.5, 2.5))
    x, y = memory.points()
    order = np.argsort(x)
    # 1 m straight ahead (+y): (1, 3); 2 m to the LiDAR's left (-x in odom): (-1, 2).
    np.testing.assert_allclose(x[order], [-1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(y[order], [2.0, 3.0], atol=1e-9)


def test_a_sensor_on_a_tilted_base_stands_where_the_tilt_carries_its_origin():
    # A LiDAR 0.1 m ahead of the base's origin and 0.3 m above it; the base at (1, 2)
    # facing +y. Pitched nose up 7.1 degrees (a 1:8 ramp), the LiDAR stands 0.1 cos - 0.3 sin
    # ahead of the base's origin (3.8 cm short of 0.1 m); rolled 5 degrees onto its right
    # side, 0.3 sin(5 deg) to the right (+x here). Its axes stay the level mounting's.
    mounting = Transform.from_rpy(0.0, 0.0, 0.0, (0.1, 0.0, 0.3))
    base = PlanarPose(1.0, 2.0, math.pi / 2)
    level = Placement.of(base, mounting)
    slope, roll = math.atan(1 / 8), math.radians(5.0)
    pitched = Placement.of(base, mounting, Transform.from_rpy(0.0, -slope, 0.0))
    rolled = Placement.of(base, mounting, Transform.from_rpy(roll, 0.0, 0.0))
    assert (level.x, level.y) == pytest.approx((1.0, 2.1), abs=1e-12)
    ahead = 0.1 * math.cos(slope) - 0.3 * math.sin(slope)
    assert (pitched.x, pitched.y) == pytest.approx((1.0, 2.0 + ahead), abs=1e-12)
    assert (rolled.x, rolled.y) == pytest.approx((1.0 + 0.3 * math.sin(roll), 2.1), abs=1e-12)
    for tilted in (pitched, rolled):
        axes = (tilted.xx, tilted.xy, tilted.yx, tilted.yy)
        assert axes == pytest.approx((level.xx, level.xy, level.yx, level.yy), abs=1e-12)


def test_a_scan_seen_from_a_nan_placement_adds_nothing():
    memory = ObstacleMemory()
    scan = Scan(-math.pi, math.pi / 2, math.pi / 2, 0.1, 10.0, np.ones(4, np.float32))
    sensor = Placement(math.nan, 0.0, 1.0, 0.0, 0.0, 1.0)
    memory.add_scan(scan, sensor, 0, np.ones(4, dtype=bool), robot=ORIGIN)
    assert len(memory) == 0


def test_points_beyond_the_radius_never_overwrite_one_behind_the_robot():
    # The rolling grid has side cells: 2 * 2 m / 2.5 cm + 2 = 162, 4.05 m. A point 4.05 m
    # in front of one 1.55 m behind the robot shares its slot; being 2.5 m off (beyond
    # the 2 m radius) it is not remembered, by every way of adding, and the one behind stays.
    memory = ObstacleMemory()
    assert memory.settings.side == 162
    memory.add(np.array([-1.5375]), np.array([0.0125]), 0, robot=ORIGIN)
    ahead = np.array([2.5125, 2.513, 2.514])  # three pixels of one cell, 162 cells ahead
    assert memory.add_dense(ahead, np.full(3, 0.0125), 1, min_count=3, robot=ORIGIN) == 0
    memory.add(ahead[:1], np.array([0.0125]), 1, robot=ORIGIN)
    scan = Scan(0.0, 0.0, 1.0, 0.1, 10.0, np.array([2.5125], np.float32))
    memory.add_scan(scan, Placement.of(PlanarPose(0.0, 0.0125, 0.0), Transform()), 1,
                    np.ones(1, dtype=bool), robot=ORIGIN)  # fmt: skip
    x, y = memory.points()
    np.testing.assert_allclose(np.stack([x, y], axis=1), [[-1.5375, 0.0125]])


def test_pixels_far_apart_do_not_add_up_to_a_dense_cell():
    # 1.001 m and 5.051 m share a slot (4.05 m apart): two pixels in one cell and one far
    # off are not three in one cell.
    memory = ObstacleMemory(MemorySettings(radius=6.0))
    assert memory.settings.side * memory.settings.cell > 5.0  # radius 6 m: no sharing here
    small = ObstacleMemory()
    x = np.array([1.001, 1.002, 5.051])
    assert small.add_dense(x, np.full(3, 0.001), 0, min_count=3, robot=ORIGIN) == 0
    assert len(small) == 0
    assert memory.add_dense(x, np.full(3, 0.001), 0, min_count=2, robot=ORIGIN) == 1


def test_a_reading_is_stood_for_by_the_pixel_of_its_slot_nearest_its_range():
    # Readings at 0 and 10 degrees (1.5 m) and 20 degrees (2.0 m), all three asked for but
    # the last. Pixels: 1.58 m and 1.52 m in the first's slot (the nearer stands for it), one
    # a slot (0.1 degree) beside it at 1.5 m (not its slot); 1.6 m in the second's, 10 cm
    # off (none within 5 cm); 2.0 m in the third's, which is not asked for.
    ranges = np.full(SLOTS, np.nan, np.float32)
    slots = np.zeros(SLOTS, dtype=bool)
    for degrees, reach, asked in ((0.0, 1.5, True), (10.0, 1.5, True), (20.0, 2.0, False)):
        slot = int(GRID.slot_of(np.array([math.radians(degrees)]))[0])
        ranges[slot], slots[slot] = reach, asked
    scan = Scan(GRID.angle_min, GRID.angle_min + (SLOTS - 1) * GRID.angle_increment,
                GRID.angle_increment, 0.1, 10.0, ranges)  # fmt: skip
    bearings = np.radians([0.0, 0.0, 0.1, 10.0, 20.0])
    reach = np.array([1.58, 1.52, 1.5, 1.6, 2.0])
    x, y = reach * np.cos(bearings), reach * np.sin(bearings)
    assert nearest_pixels(x, y, scan, slots, AT_ORIGIN, within=0.05).tolist() == [1]
    assert nearest_pixels(x[:0], y[:0], scan, slots, AT_ORIGIN, within=0.05).size == 0
    # Seen from 1 m further along x, the same pixels lie 1 m nearer in the same slots.
    ahead = Placement.of(PlanarPose(1.0, 0.0, 0.0), Transform())
    ranges[int(GRID.slot_of(np.array([0.0]))[0])] = 0.5
    assert nearest_pixels(x, y, scan, slots, ahead, within=0.05).tolist() == [1]


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    grid=st.sampled_from(
        [
            GRID,  # a full turn from -180 degrees
            AngleGrid(-math.radians(135), math.radians(0.25), 1081),  # 270 degrees (UST-10LX)
            AngleGrid(math.pi, -2 * math.pi / 720, 720),  # a full turn, clockwise
        ]
    ),
    sensor=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-math.pi, math.pi)),
)
def test_nearest_pixels_picks_what_a_search_of_every_point_picks(seed, grid, sensor):
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.3, 3.0, grid.count).astype(np.float32)
    ranges[rng.random(grid.count) < 0.3] = np.nan
    scan = Scan(grid.angle_min, grid.angle_max, grid.angle_increment, 0.1, 10.0, ranges)
    asked = rng.random(grid.count) < 0.7
    placement = Placement.of(PlanarPose(*sensor), Transform())
    # Points at the readings' ranges, give or take 8 cm, so that many lie within 5 cm.
    slot_of_point = rng.integers(0, grid.count, 3000)
    reading = np.nan_to_num(ranges[slot_of_point].astype(np.float64), nan=1.5)
    reach = reading + rng.uniform(-0.08, 0.08, slot_of_point.size)
    # Away from slot boundaries: the kernel's bearing is within 2e-4 rad of arctan2's.
    bearing = grid.angle_min + grid.angle_increment * (
        slot_of_point + rng.uniform(-0.35, 0.35, slot_of_point.size)
    )
    world = sensor[2] + bearing
    x = sensor[0] + reach * np.cos(world)
    y = sensor[1] + reach * np.sin(world)
    expected = []
    for slot in range(grid.count):
        if not asked[slot] or not np.isfinite(ranges[slot]):
            continue
        mine = np.flatnonzero(slot_of_point == slot)
        gaps = np.abs(reach[mine] - float(ranges[slot]))
        if mine.size and gaps.min() <= 0.05:
            expected.append(int(mine[np.argmin(gaps)]))
    chosen = nearest_pixels(x, y, scan, asked, placement, within=0.05)
    assert chosen.tolist() == expected


def test_points_seen_since_a_stamp_move_with_the_frames_correction_and_older_ones_stay():
    memory = ObstacleMemory()
    memory.add(np.array([1.0]), np.array([0.5]), 1 * NS, robot=ORIGIN)  # before the anchor
    memory.stand_still(NS)  # a second standing: the memory's clock stops
    anchor = memory.clock(2 * NS)
    memory.add(np.array([1.2, 1.5]), np.array([-0.3, 0.2]), 3 * NS, robot=ORIGIN)
    memory.stand_still(NS)  # and after: the clock the anchor was taken on holds
    # The frame they were placed on was 0.1 m ahead along x and turned 0.02 rad.
    move = PlanarPose(-0.1, 0.0, 0.02)
    assert memory.move_since(anchor, move) == 2
    x, y = memory.points()
    c, s = math.cos(0.02), math.sin(0.02)
    moved = [(c * px - s * py - 0.1, s * px + c * py) for px, py in ((1.2, -0.3), (1.5, 0.2))]
    got = np.array(sorted(zip(x, y, strict=True)))
    assert got == pytest.approx(np.array(sorted([(1.0, 0.5), *moved])), abs=1e-9)


def test_moved_points_take_the_cells_they_land_in_the_newest_of_each():
    memory = ObstacleMemory()
    memory.add(np.array([0.9125]), np.array([0.0125]), 5 * NS, robot=ORIGIN)  # cell (36, 0)
    memory.add(np.array([1.0125]), np.array([0.0125]), 4 * NS, robot=ORIGIN)  # cell (40, 0)
    memory.add(np.array([0.8150]), np.array([0.0125]), 3 * NS, robot=ORIGIN)  # cell (32, 0)
    # Back 0.1 m, what was seen after 3 s: the 5 s point lands on the 3 s one's cell and
    # takes it; the 4 s one takes the cell the 5 s one left.
    assert memory.move_since(memory.clock(3 * NS), PlanarPose(-0.1, 0.0, 0.0)) == 2
    x, _ = memory.points()
    assert sorted(x.round(6).tolist()) == [0.8125, 0.9125]
    # Two moved points landing in one cell: the one seen later stays.
    memory = ObstacleMemory()
    memory.add(np.array([1.0130]), np.array([0.0125]), 6 * NS, robot=ORIGIN)  # cell (40, 0)
    memory.add(np.array([1.0260]), np.array([0.0125]), 7 * NS, robot=ORIGIN)  # cell (41, 0)
    memory.move_since(memory.clock(5 * NS), PlanarPose(-0.005, 0.0, 0.0))  # both to cell 40
    x, _ = memory.points()
    assert x.round(6).tolist() == [1.021]  # the 7 s point's


def test_after_re_anchoring_each_point_moves_by_the_share_of_the_path_driven_when_it_was_seen():
    # Up a ramp from x = 0 (the anchor) to 1.5 m, a scan at each half metre (memory clock
    # 1, 2, 3 s); the correction then moved back 0.15 m: the slip grew with the distance,
    # so a point seen at 1 s had a third of it, at 2 s two thirds, at 3 s and after all.
    stream = FusionStream(config())
    memory = ObstacleMemory()
    seen_at = (0.5, 1.0, 2.0, 3.0, 4.0)
    for k, second in enumerate(seen_at):
        memory.add(
            np.array([2.0 + 0.1 * k]), np.array([0.0125]), round(second * NS), robot=(1.0, 0.0)
        )
    # Per scan: its stamp, the memory's clock (the same: the robot never stood) and the pose;
    # the anchor's scan at 0.75 s, at x = 0.
    stream._memory_path.extend(
        (round(second * NS), round(second * NS), PlanarPose(x, 0.0, 0.0))
        for second, x in ((0.75, 0.0), (1, 0.5), (2, 1.0), (3, 1.5))
    )
    stream._move_remembered(memory, round(0.75 * NS), PlanarPose(-0.15, 0.0, 0.0))
    x, _ = memory.points()
    slip = np.array([0.0, 0.05, 0.10, 0.15, 0.15])
    assert sorted(x) == pytest.approx(2.0 + 0.1 * np.arange(5) - slip, abs=1e-9)
