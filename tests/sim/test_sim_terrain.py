"""Terrain: ramps, platforms and sills are floor; the sprung robot climbs them, pitches when it
brakes, and its IMU says so; the truth measures heights above the ground under each obstacle."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from scanfuse.sim import Ground, Pose2D, SimConfig, SimError, Simulation, Trace
from scanfuse.sim.robot import SPRUNG, RobotSpec, Suspension
from scanfuse.sim.sensors import VISIBLE_GROUPS, lidar_profile
from scanfuse.sim.truth import TruthScanner
from scanfuse.sim.worlds import (
    GROUND_SOLID_GROUP,
    RAMP_FOOT,
    RAMP_RISE,
    World,
    box,
    box_on_ground,
    ground_runs,
    ramp_ledge_world,
    ramp_pieces,
    ramp_world,
    sills_world,
)

LOW = {'resolution': (256, 144), 'depth_rate': 2.0, 'noise': False}
GRID = lidar_profile('rplidar-a2').grid
AHEAD = 540  # rplidar-a2: slot 540 looks along +x
SLAB = {'min_obstacle_height': 0.03, 'max_obstacle_height': 0.5, 'range_max': 12.0}


def straight_down(sim: Simulation, x: float, y: float) -> tuple[float, str]:
    """Distance from z = 1 m straight down to the first geom, and that geom's name."""
    geom = np.zeros(1, dtype=np.int32)
    distance = mujoco.mj_ray(
        sim.model, sim.data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom
    )
    return distance, sim.model.geom(int(geom[0])).name


SOLID_ONLY = np.array([int(g == GROUND_SOLID_GROUP) for g in range(6)], dtype=np.uint8)


def nose_down(sim: Simulation) -> float:
    """The body's pitch, degrees, positive nose-down (REP-103)."""
    rotation = sim.base_pose()[1]
    return math.degrees(math.asin(-rotation[2, 0]))


@pytest.mark.parametrize(('name', 'grade'), [('ramp-12', 12.0), ('ramp-8', 8.0)])
def test_ramp_surfaces_lie_where_their_grade_says(name, grade):
    sim = Simulation(SimConfig(world=name, **LOW))
    try:
        run = grade * RAMP_RISE  # 1.8 m (1:12), 1.2 m (1:8)
        # Half way up the ramp: rise / 2 above the floor; on the platform: the rise; a quarter of
        # the way down the far ramp: rise / 4 (mesh vertices are float32: 1e-6).
        up = straight_down(sim, RAMP_FOOT + run / 2, 0.0)
        assert up == (pytest.approx(1.0 - RAMP_RISE / 2, abs=1e-6), 'ramp_up')
        platform = straight_down(sim, RAMP_FOOT + run + 0.3, 0.2)
        assert platform == (pytest.approx(1.0 - RAMP_RISE, abs=1e-6), 'ramp_platform')
        quarter_down = straight_down(sim, RAMP_FOOT + 1.2 + 1.75 * run, -0.2)
        assert quarter_down == (pytest.approx(1.0 - RAMP_RISE / 4, abs=1e-6), 'ramp_down')
        for piece in ('ramp_up', 'ramp_platform', 'ramp_down'):
            assert sim.geom_kind(sim.model.geom(piece).id) == 'floor'
        # The world's own surface height agrees, and is 0 off the ramp.
        xs = np.array([RAMP_FOOT + run / 2, RAMP_FOOT + run + 0.3, 0.5])
        heights = sim.world.surface_height(xs, np.zeros(3))
        assert heights == pytest.approx([RAMP_RISE / 2, RAMP_RISE, 0.0], abs=1e-12)
    finally:
        sim.close()


def test_sills_are_bevelled_and_one_to_two_centimetres_high():
    world = sills_world(3)
    tops = [piece for piece in world.ground if piece.name.endswith('_top')]
    assert len(tops) == 2
    for top in tops:
        assert 0.01 <= top.z_start == top.z_end <= 0.02
        bevel = next(p for p in world.ground if p.name == top.name.replace('_top', '_in'))
        # 1:2 bevel: the rise over twice its height.
        x_min, x_max, _, _ = bevel.rectangle
        assert (x_max - x_min) == pytest.approx(2 * top.z_start)


def test_ground_pieces_are_checked():
    with pytest.raises(SimError, match=r"ground 'bad' needs x_min < x_max"):
        Ground('bad', 'ramp', (1.0, 0.0, 0.0, 1.0), 0.0, 0.1)
    with pytest.raises(SimError, match=r"kind 'stairs' is not one of ramp, platform, sill"):
        Ground('bad', 'stairs', (0.0, 1.0, 0.0, 1.0), 0.0, 0.1)


def test_truth_the_ramp_is_floor_a_box_on_it_an_obstacle_a_plate_on_it_not():
    # A 1:12 ramp 0.15 m high from x = 1.6 (run 1.8 m), a platform from 3.4 to 4.6.
    pieces = ramp_pieces('ramp', 1.6, 12.0, 0.15, 0.6)
    # A box 0.3 m long, 6 cm above the ramp at its centre x = 2.8: the ramp under it rises
    # from (2.65 - 1.6) / 12 = 0.0875 m to (2.95 - 1.6) / 12 = 0.1125 m; its top is at
    # (2.8 - 1.6) / 12 + 0.06 = 0.16 m, 0.0725 m above the lowest ground under it.
    on_ramp = box_on_ground('on_ramp', pieces, (2.8, 0.0), (0.15, 0.1), 0.06)
    assert on_ramp.ground == pytest.approx(0.0875)
    assert on_ramp.z_max == pytest.approx(0.16)
    assert on_ramp.top == pytest.approx(0.0725)
    assert on_ramp.overlaps_slab(0.03, 0.5)
    # A plate 2 cm thick on the platform (0.15-0.17 m in the world's z) is under the slab's
    # 3 cm above the ground it lies on: not an obstacle, though its world z is above 3 cm.
    plate = box_on_ground('plate', pieces, (4.0, 0.0), (0.2, 0.2), 0.02)
    assert (plate.z_min, plate.z_max) == pytest.approx((0.15, 0.17))
    assert not plate.overlaps_slab(0.03, 0.5)
    # A shelf 0.55-0.60 m above the platform (0.70-0.75 m in the world): above the slab.
    shelf = box('shelf', 'shelf_board', (4.2, 0.0), (0.1, 0.3), (0.70, 0.75))
    assert not shelf.overlaps_slab(0.03 + 0.15, 0.5 + 0.15)
    start = Pose2D(0.0, 0.0, 0.0)
    bounds = (0.0, 6.0, -1.0, 1.0)
    world = World('ramp', 0, (on_ramp, plate), start, bounds, ground=tuple(pieces))
    # From the origin facing +x: nothing but the box is in the slab; its near face is at
    # x = 2.65, straight ahead, so the slot looking along +x reads 2.65 m.
    scanner = TruthScanner(world.obstacles, GRID, **SLAB)
    ranges = scanner.scan(0.0, 0.0, 0.0)
    assert ranges[AHEAD] == pytest.approx(2.65, abs=1e-6)
    # Only the box's slots (within 20 slots of straight ahead) hold anything.
    ahead = np.isfinite(ranges[AHEAD - 20 : AHEAD + 21]).sum()
    assert int(np.isfinite(ranges).sum()) == int(ahead)
    # The ramp alone (the terrain world without its boxes and walls): no obstacle anywhere.
    empty = TruthScanner((), GRID, **SLAB)
    assert np.isinf(empty.scan(1.0, 0.0, 0.0)).all()


def test_the_ramp_worlds_boxes_stand_on_the_ground_under_them():
    world = ramp_world(2, grade=8.0)
    on_ramp = next(o for o in world.obstacles if o.name == 'box_on_ramp')
    corners = on_ramp.footprint
    under = world.surface_height(corners[:, 0], corners[:, 1])
    assert on_ramp.ground == pytest.approx(under.min())
    assert (
        0.06
        <= on_ramp.z_max
        - float(world.surface_height(*(np.array([v]) for v in corners.mean(axis=0)))[0])
        <= 0.12
    )
    on_platform = next(o for o in world.obstacles if o.name == 'box_on_platform')
    assert on_platform.ground == pytest.approx(RAMP_RISE)
    assert all(o.overlaps_slab(0.03, 0.5) for o in world.obstacles)


def drive_straight(sim: Simulation, speed: float, seconds: float) -> Trace:
    trace = Trace()
    sim.run(seconds, lambda _: (speed, 0.0), trace)
    return trace


@pytest.mark.parametrize('name', ['ramp-12', 'ramp-8'])
def test_the_sprung_robot_drives_up_the_ramp_its_base_rising_by_the_ramps_height(name):
    sim = Simulation(SimConfig(world=name, robot=SPRUNG, **LOW))
    try:
        z0 = float(sim.base_pose()[0][2])
        grade = 12.0 if name == 'ramp-12' else 8.0
        # At 0.3 m/s: to the platform's middle, RAMP_FOOT + run + 0.6 m, with time to spare.
        distance = RAMP_FOOT + grade * RAMP_RISE + 0.6
        trace = drive_straight(sim, 0.3, distance / 0.3 + 2.0)
        x, _, z = trace.states[-1].position
        assert RAMP_FOOT + grade * RAMP_RISE < x < RAMP_FOOT + grade * RAMP_RISE + 1.2
        assert z - z0 == pytest.approx(RAMP_RISE, abs=0.005)
        assert sim.fell_ns is None
        assert not trace.contacts  # ramps are floor
        # The wheels roll up the ramp: rubber (friction 1) holds far more than the slope asks
        # (1:8 is a friction of 0.125), so the wheel odometry's distance is the distance
        # driven along the floor and the ramp.
        positions = np.array([s.position for s in trace.states])
        driven = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
        assert trace.states[-1].odometry.x == pytest.approx(driven, rel=0.03)
        # Half way up the ramp the body is pitched nose-up by the ramp's angle and leans back
        # on its springs by at most 2.5 degrees more (climbing, the wheels' torque and
        # gravity pitch it back).
        on_ramp = [
            s
            for s in trace.states
            if abs(s.position[0] - (RAMP_FOOT + grade * RAMP_RISE / 2)) < 0.05
        ]
        x_, y_, z_, w_ = on_ramp[0].orientation
        pitch = math.degrees(math.asin(2 * (w_ * y_ - z_ * x_)))
        ramp = math.degrees(math.atan(1 / grade))
        assert -ramp - 2.5 < pitch < -ramp + 0.3
    finally:
        sim.close()


def test_the_rigid_robot_cannot_climb_the_ramp():
    # Its front caster rides up the ramp's foot and lifts its wheels off the floor: they spin,
    # and the robot gets no more than half way up (the ramp is 1.2 m long).
    sim = Simulation(SimConfig(world='ramp-8', robot=RobotSpec(), **LOW))
    try:
        trace = drive_straight(sim, 0.3, 12.0)
        last = trace.states[-1]
        assert last.position[0] < RAMP_FOOT + 8.0 * RAMP_RISE / 2
        assert last.odometry.x > last.position[0] + 0.5
    finally:
        sim.close()


@pytest.mark.parametrize(('seed', 'heading'), [(1, 0.0), (3, 10.0), (4, -10.0)])
def test_the_robot_drives_over_sills_without_contacts(seed, heading):
    # Square to the door or 10 degrees off it (as a planned path crosses it), through the
    # door's middle 1.5 m ahead; stopping short of the middle room's low box.
    sim = Simulation(SimConfig(world='sills', seed=seed, robot=SPRUNG, **LOW))
    try:
        door = next(p for p in sim.world.ground if p.name == 'sill0_top').rectangle
        yaw = math.radians(heading)
        sim.place(Pose2D(0.0, (door[2] + door[3]) / 2 - 1.5 * math.tan(yaw), yaw))
        trace = drive_straight(sim, 0.3, 7.0)
        assert trace.states[-1].position[0] > 1.5 + 0.3  # past the first door's sill
        assert not trace.contacts
        assert sim.fell_ns is None
    finally:
        sim.close()


@pytest.mark.parametrize(('seed', 'heading'), [(1, 0.0), (3, 15.0)])
def test_the_robot_stays_upright_over_a_sill_at_cruising_speed(seed, heading):
    # At the terrain trials' 0.35 m/s from 1.2 m before the sill's bevel: with a 2 ms physics
    # step the body bounced off the bevel and tipped over in these two drives.
    sim = Simulation(SimConfig(world='sills', seed=seed, robot=SPRUNG, **LOW))
    try:
        assert sim.config.physics_step == SPRUNG.suspension.timestep
        bevel = next(p for p in sim.world.ground if p.name == 'sill0_in').rectangle
        yaw = math.radians(heading)
        sim.place(Pose2D(0.3, (bevel[2] + bevel[3]) / 2 - 1.2 * math.tan(yaw), yaw))
        trace = drive_straight(sim, 0.35, 7.0)
        assert trace.states[-1].position[0] > 1.5 + 0.3  # past the sill
        # The body's up axis stays within 15 degrees of the vertical all the way.
        up = np.array(
            [1.0 - 2.0 * (q[0] ** 2 + q[1] ** 2) for q in (s.orientation for s in trace.states)]
        )
        assert np.degrees(np.arccos(up.min())) < 15.0
        assert sim.fell_ns is None
    finally:
        sim.close()


def test_each_sill_and_ramp_is_one_solid_the_sensors_do_not_see():
    assert [[p.name for p in run] for run in ground_runs(sills_world(2).ground)] == [
        ['sill0_in', 'sill0_top', 'sill0_out'],
        ['sill1_in', 'sill1_top', 'sill1_out'],
    ]
    assert [len(run) for run in ground_runs(ramp_world(0, grade=8.0).ground)] == [3]
    sim = Simulation(SimConfig(world='sills', seed=2, **LOW))
    try:
        piece = next(p for p in sim.world.ground if p.name == 'sill0_top')
        x, y = (piece.rectangle[0] + piece.rectangle[1]) / 2, sum(piece.rectangle[2:]) / 2
        # The sensors' rays meet the sill's top; the solid's top (made opaque: mj_ray skips
        # transparent geoms) lies exactly there.
        solid = sim.model.geom('sill0_in_solid').id
        sim.model.geom_rgba[solid, 3] = 1.0
        for groups, name in ((VISIBLE_GROUPS, 'sill0_top'), (SOLID_ONLY, 'sill0_in_solid')):
            geom = np.zeros(1, dtype=np.int32)
            distance = mujoco.mj_ray(
                sim.model,
                sim.data,
                np.array([x, y, 1.0]),
                np.array([0.0, 0.0, -1.0]),
                groups,
                1,
                -1,
                geom,
            )
            assert sim.model.geom(int(geom[0])).name == name
            assert distance == pytest.approx(1.0 - piece.z_start, abs=1e-6)
    finally:
        sim.close()


def test_a_robot_driving_off_the_ramps_ledge_falls():
    # The ramp-ledge world's start is right of the ramp: straight ahead the yard begins at
    # x = RAMP_FOOT, 0.4 m down.
    world = ramp_ledge_world()
    sim = Simulation(SimConfig(world='ramp-ledge', robot=SPRUNG, **LOW), world)
    try:
        drive_straight(sim, 0.3, 9.0)
        assert sim.fell_ns is not None
        assert sim.base_drop() > 0.1  # it went over the edge (and may hang on it)
    finally:
        sim.close()


def braking_pitch(robot: RobotSpec) -> tuple[float, float]:
    """Peak nose-down pitch (degrees) braking hard from 0.35 m/s (the command dropped to 0:
    the wheels' torque limit brakes), and the peak nose-up setting off to 0.35 m/s."""
    sim = Simulation(SimConfig(world='room', robot=robot, **LOW))
    try:
        sim.set_command(0.35, 0.0)
        start = [nose_down_after(sim, step) for step in range(300)]
        sim.advance(2.0)
        sim.set_command(0.0, 0.0)
        braking = [nose_down_after(sim, step, 2.0) for step in range(500)]
        return max(braking), -min(start)
    finally:
        sim.close()


def nose_down_after(sim: Simulation, step: int, start: float = 0.0) -> float:
    sim.advance(start + 0.002 * (step + 1))
    return nose_down(sim)


def test_the_sprung_body_pitches_1_5_to_3_degrees_braking_hard_and_setting_off():
    braking, setting_off = braking_pitch(SPRUNG)
    assert 1.5 <= braking <= 3.0
    assert 1.5 <= setting_off <= 3.0
    # The rigid robot barely pitches at all.
    rigid_braking, rigid_start = braking_pitch(RobotSpec())
    assert rigid_braking < 0.5
    assert rigid_start < 0.5


def test_the_imus_pitch_matches_the_bodys_within_its_noise():
    config = SimConfig(world='room', robot=SPRUNG, resolution=(256, 144), depth_rate=2.0)
    sim = Simulation(config)
    try:
        trace = Trace()
        # Set off, cruise, brake: the body pitches both ways.
        sim.run(1.5, lambda observation: (0.35 if observation.time < 1.0 else 0.0, 0.0), trace)
    finally:
        sim.close()
    # 100 Hz over [0, 1.5] s, both ends.
    assert len(trace.imu) == 151
    stamps = np.array([s.stamp_ns for s in trace.imu])
    assert np.diff(stamps) == pytest.approx(1e7, abs=1)
    body = {s.stamp_ns: s.orientation for s in trace.states}  # 50 Hz: every other IMU sample
    errors = []
    pitches = []
    for sample in trace.imu:
        if sample.stamp_ns in body:
            x, y, z, w = body[sample.stamp_ns]
            true_pitch = math.asin(2 * (w * y - z * x))
            pitches.append(true_pitch)
            errors.append(sample.roll_pitch[1] - true_pitch)
    assert len(errors) == 76
    sigma = config.imu_noise.orientation  # 0.1 degree
    assert np.abs(errors).max() < 4.5 * sigma
    assert np.std(errors) == pytest.approx(sigma, rel=0.35)
    assert abs(np.mean(errors)) < 3 * sigma / math.sqrt(len(errors))
    # The body did pitch (more than 1.5 degrees one way or the other): the match is not
    # of a level robot's zeros.
    assert math.degrees(max(abs(p) for p in pitches)) > 1.5
    # Noise off: exactly the body's orientation.
    quiet = Simulation(SimConfig(world='room', robot=SPRUNG, **LOW))
    try:
        sample = quiet.imu()
        w, x, y, z = (float(v) for v in quiet.data.xquat[quiet.model.body('robot').id])
        assert sample.orientation == pytest.approx((x, y, z, w))
    finally:
        quiet.close()


def test_suspension_is_checked():
    with pytest.raises(SimError, match=r'suspension needs stiffness > 0'):
        Suspension(stiffness=0.0)
    with pytest.raises(SimError, match=r'wheel_preload in \(0, 0.05\) m, got 2500.0, 300.0, 0.1'):
        Suspension(wheel_preload=0.1)
    with pytest.raises(SimError, match=r'imu_rate 2000.0 Hz must be in \[0, 1000\]'):
        SimConfig(imu_rate=2000.0)
