"""Driving: physics, collisions, wheel odometry, scripted paths and the controller hook."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.pipeline import FusionPipeline
from scanfuse.sim import (
    FusedController,
    Lap,
    Observation,
    Pose2D,
    SimConfig,
    SimError,
    Simulation,
    Trace,
    WheelOdometry,
    fusion_config,
    scripted_path,
)
from scanfuse.sim.simulation import EPOCH_NS

LOW = {'resolution': (256, 144), 'depth_rate': 2.0, 'noise': False}


def seconds(stamp_ns: int) -> float:
    return (stamp_ns - EPOCH_NS) / 1e9


def odometry_error(sample) -> float:
    # The odom frame starts at the robot's start pose, (0, 0, 0) in the bookshelf world.
    return math.hypot(
        sample.odometry.x - sample.position[0], sample.odometry.y - sample.position[1]
    )


def test_driving_into_the_bookshelf_stops_the_robot_and_odometry_drifts_after_contact():
    simulation = Simulation(SimConfig(world='bookshelf', **LOW))
    trace = Trace()
    simulation.run(9.0, scripted_path('straight'), trace)
    assert trace.contacts, 'driving at 0.3 m/s for 9 s must reach the shelf 2 m ahead'
    kinds = {contact.kind for contact in trace.contacts}
    assert kinds <= {'shelf_board', 'shelf_side'}
    assert 'shelf_board' in kinds
    first = seconds(trace.contacts[0].stamp_ns)
    # The chassis (radius 0.18) meets the board fronts at x = 2.0 and cannot pass them.
    front = np.array([s.position[0] for s in trace.states]) + 0.18
    assert front.max() < 2.0 + 0.01
    assert front.max() > 2.0 - 0.01
    assert all(c.position[0] == pytest.approx(2.0, abs=0.01) for c in trace.contacts)
    before = [odometry_error(s) for s in trace.states if seconds(s.stamp_ns) <= first]
    after = odometry_error(trace.states[-1])
    # Against the shelf the wheels push at their torque limit (40 N each, about what their
    # friction holds): they creep on, and odometry runs ahead of the robot, which does not.
    assert max(before) < 0.05
    assert after > max(before)
    late = [s for s in trace.states if seconds(s.stamp_ns) > first + 1.0]
    errors = [odometry_error(s) for s in late]
    assert errors[-1] > errors[0]


def test_rotating_in_place_turns_without_moving():
    simulation = Simulation(SimConfig(world='room', **LOW))
    trace = Trace()
    simulation.run(3.0, scripted_path('rotate'), trace)
    last = trace.states[-1]
    assert last.true_pose.yaw == pytest.approx(0.5 * 3.0, abs=0.15)
    assert last.odometry.yaw == pytest.approx(0.5 * 3.0, abs=0.15)
    assert math.hypot(last.position[0] + 2.0, last.position[1] + 1.5) < 0.02


def test_a_lap_of_the_room_returns_near_the_start():
    simulation = Simulation(
        SimConfig(world='room', resolution=(256, 144), depth_rate=0.5, noise=False)
    )
    trace = Trace()
    simulation.run(62.0, Lap(), trace)
    path = np.array([s.position[:2] for s in trace.states])
    start = path[0]
    # It went round: visited all four corners of the 4 m x 3 m rectangle.
    for corner in ((2.0, -1.5), (2.0, 1.5), (-2.0, 1.5)):
        assert np.linalg.norm(path - corner, axis=1).min() < 0.25
    assert np.linalg.norm(path[-1] - start) < 0.4
    assert not trace.contacts


def test_controller_sees_every_scan_with_odometry_and_the_latest_depth():
    seen: list[Observation] = []

    def controller(observation: Observation) -> tuple[float, float]:
        seen.append(observation)
        return 0.2, 0.0

    simulation = Simulation(SimConfig(world='bookshelf', **LOW))
    trace = Trace()
    simulation.run(2.0, controller, trace)
    # 10 Hz sweeps from 0 s, each delivered at its end: 0.1, 0.2, ..., 2.0 s.
    assert len(seen) == len(trace.lidar) == 20
    assert [o.scan.stamp_ns for o in seen] == [f.scan.stamp_ns for f in trace.lidar]
    assert [o.time for o in seen] == pytest.approx([0.1 * k for k in range(1, 21)])
    assert all(len(o.scan) == 1080 for o in seen)
    # The first image, exposed at 0 s, is delivered at 0.04 s: before the first scan.
    assert seen[0].depth is not None
    assert seen[0].depth.shape == (144, 256)
    # Driving from 0.1 s (the first command) to 2.0 s at 0.2 m/s.
    assert seen[-1].odometry.x == pytest.approx(0.2 * 1.9, abs=0.05)


def test_wheel_odometry_integrates_hand_worked_motions():
    odometry = WheelOdometry(wheel_radius=0.05, wheel_separation=0.3)
    odometry.update(0.0, 0.0, 0.0)
    odometry.update(10.0, 10.0, 1.0)  # both wheels 10 rad: 0.5 m straight
    assert (odometry.x, odometry.y, odometry.yaw) == pytest.approx((0.5, 0.0, 0.0))
    assert odometry.v == pytest.approx(0.5)
    odometry.update(10.0 - 3.0, 10.0 + 3.0, 1.0)  # +-0.15 m on a 0.3 m track: 1 rad on the spot
    assert (odometry.x, odometry.y, odometry.yaw) == pytest.approx((0.5, 0.0, 1.0))
    assert odometry.omega == pytest.approx(1.0)


def test_bad_run_settings_are_refused():
    simulation = Simulation(SimConfig(world='room', **LOW))
    with pytest.raises(SimError, match='duration must be positive'):
        simulation.run(0.0, scripted_path('straight'), Trace())
    with pytest.raises(
        SimError, match=r"unknown path 'zigzag'; choose one of straight, rotate, rotate-fast, arc"
    ):
        scripted_path('zigzag')
    with pytest.raises(SimError, match=r'depth_rate 0\.0 Hz must be in'):
        SimConfig(depth_rate=0.0)
    with pytest.raises(SimError, match=r'timestep 0\.1 s must be in'):
        SimConfig(timestep=0.1)


def test_fused_controller_sees_the_shelf_boards_the_lidar_misses():
    config = SimConfig(world='bookshelf', resolution=(424, 240), depth_rate=10.0, noise=False)
    ahead: list[tuple[float, float]] = []

    def policy(fused, observation):
        ahead.append((float(fused.ranges[540]), float(observation.scan.ranges[540])))
        return 0.0, 0.0

    controller = FusedController(policy, FusionPipeline(fusion_config(config)))
    Simulation(config).run(0.3, controller, Trace())
    fused_ahead, lidar_ahead = ahead[-1]
    # The LiDAR looks between the boards to the wall at 2.8 m; fused, the boards are 2.0 m away.
    assert lidar_ahead == pytest.approx(2.8, abs=0.01)
    assert fused_ahead == pytest.approx(2.0, abs=0.05)
    # Scans arrive at 0.1, 0.2, 0.3 s; the first image (exposed at 0 s) at 0.04 s, so every
    # scan is fused.
    assert len(ahead) == 3
    assert all(fused == pytest.approx(2.0, abs=0.05) for fused, _ in ahead)


def test_placing_the_robot_moves_it_and_restarts_odometry():
    simulation = Simulation(SimConfig(world='room', **LOW))
    simulation.run(1.0, scripted_path('straight'), Trace())
    assert simulation.odometry.x > 0.2
    simulation.place(Pose2D(1.0, 0.5, math.pi / 2))
    pose = simulation.true_pose()
    assert (pose.x, pose.y, pose.yaw) == pytest.approx((1.0, 0.5, math.pi / 2))
    assert (simulation.odometry.x, simulation.odometry.y) == (0.0, 0.0)
    trace = Trace()
    simulation.run(1.0, scripted_path('straight'), trace)
    # Facing +y now: driving forward increases y, and odometry counts from the new place.
    assert trace.states[-1].position[1] > 0.5 + 0.2
    assert trace.states[-1].odometry.x == pytest.approx(
        trace.states[-1].position[1] - 0.5, abs=0.05
    )


def test_a_40_hz_lidar_is_sampled_at_40_hz():
    config = SimConfig(world='room', lidar='hokuyo-ust10lx', **LOW)
    trace = Trace()
    Simulation(config).run(0.5, scripted_path('rotate'), trace)
    stamps = np.array([frame.stamp_ns for frame in trace.lidar])
    # Sweeps from 0, 25, ..., 475 ms, delivered 25 ms later; on 2 ms physics steps.
    assert len(stamps) == 20
    assert np.diff(stamps) == pytest.approx(np.full(19, 25_000_000), abs=1_000_000)
