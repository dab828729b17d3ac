"""Real sensor time in the simulator: rates, phases, latencies, beams at their own time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.sim import Rotate, SimConfig, SimError, Simulation, Straight, Trace
from scanfuse.sim.simulation import EPOCH_NS
from scanfuse.sim.worlds import LARGE_ROOM, ROBOT_AT_ORIGIN, World, box

SMALL = (256, 144)
MS = 1_000_000


def ms(stamp_ns: int) -> float:
    return (stamp_ns - EPOCH_NS) / MS


def wall_world(distance: float) -> World:
    """One wide, tall wall whose face (normal -x) is `distance` m ahead of the robot's origin."""
    wall = box('wall_ahead', 'wall', (distance + 0.05, 0.0), (0.05, 20.0), (0.0, 3.0))
    return World('wall', 0, (wall,), ROBOT_AT_ORIGIN, (-1.0, distance, -3.0, 3.0))


def test_depth_frames_are_stamped_at_exposure_and_delivered_latency_later():
    # 25 Hz: one exposure every 40 ms (20 physics steps of 2 ms), delivered 30 ms later.
    config = SimConfig(resolution=SMALL, noise=False, depth_rate=25.0, depth_latency=0.030)
    trace = Trace()
    Simulation(config, wall_world(3.0)).run(0.5, None, trace)
    stamps = [ms(frame.stamp_ns) for frame in trace.depth]
    delivered = [ms(frame.arrival_ns) for frame in trace.depth]
    # Exposures at 0, 40, ..., 440 ms: the one at 480 ms would arrive at 510 ms, after the run.
    assert stamps == pytest.approx([40.0 * k for k in range(12)])
    assert delivered == pytest.approx([40.0 * k + 30.0 for k in range(12)])


def test_a_phase_offsets_the_camera_and_the_lidar():
    config = SimConfig(
        resolution=SMALL, noise=False, depth_rate=10.0, depth_phase=0.05, lidar_phase=0.02
    )
    trace = Trace()
    Simulation(config, wall_world(3.0)).run(0.4, None, trace)
    # Exposures at 50, 150, 250, 350 ms, each delivered 40 ms later (the last at 390 ms).
    assert [ms(f.stamp_ns) for f in trace.depth] == pytest.approx([50.0, 150.0, 250.0, 350.0])
    # Sweeps from 20 ms every 100 ms, each delivered at its end: 120, 220, 320 ms.
    assert [ms(f.stamp_ns) for f in trace.lidar] == pytest.approx([20.0, 120.0, 220.0])
    assert [ms(f.arrival_ns) for f in trace.lidar] == pytest.approx([120.0, 220.0, 320.0])


def test_the_image_is_rendered_at_its_exposure_not_at_its_delivery():
    config = SimConfig(resolution=SMALL, noise=False, depth_rate=25.0, depth_latency=0.040)
    trace = Trace()
    Simulation(config, wall_world(3.0)).run(1.6, Straight(0.3), trace)
    base_x = {ms(s.stamp_ns): s.position[0] for s in trace.states}  # every 20 ms
    # Top row (v = 0), centre columns: y_n = -71.5 / f with f = 72 / tan(29 deg). Per unit Z
    # the ray advances cos(20 deg) - y_n sin(20 deg) = 1.12797 along x (camera pitched 20 deg).
    focal = 72.0 / math.tan(math.radians(29.0))
    ahead = math.cos(math.radians(20.0)) + (71.5 / focal) * math.sin(math.radians(20.0))
    assert ahead == pytest.approx(1.12797, abs=1e-5)
    checked = 0
    for frame in trace.depth:
        exposure, arrival = ms(frame.stamp_ns), ms(frame.arrival_ns)
        if exposure < 1000.0:
            continue  # let the robot reach its speed: 12 mm per 40 ms at 0.3 m/s
        z = frame.depth[0, 127:129].astype(np.float64) / 1000.0
        # The wall is 3 m from the start; the camera 0.12 m ahead of base_link.
        at_exposure = (3.0 - base_x[exposure] - 0.12) / ahead
        at_arrival = (3.0 - base_x[arrival] - 0.12) / ahead
        assert z == pytest.approx(at_exposure, abs=0.0015)
        assert np.all(np.abs(z - at_arrival) > 0.008)
        checked += 1
    assert checked == 15  # exposures at 1000, 1040, ..., 1560 ms (delivered by 1600 ms)


def test_lidar_scans_carry_the_driver_time_increment_and_arrive_after_the_sweep():
    config = SimConfig(world='room', resolution=SMALL, noise=False, depth_rate=2.0)
    trace = Trace()
    Simulation(config).run(0.35, None, trace)
    # 10 Hz, 1080 readings over 360 degrees: scan_time 0.1 s, time_increment 0.1 / 1080 s.
    assert [ms(f.stamp_ns) for f in trace.lidar] == pytest.approx([0.0, 100.0, 200.0])
    assert [ms(f.arrival_ns) for f in trace.lidar] == pytest.approx([100.0, 200.0, 300.0])
    scan = trace.lidar[0].scan
    assert scan.scan_time == pytest.approx(0.1)
    assert scan.time_increment == pytest.approx(0.1 / 1080, rel=1e-12)
    assert scan.stamp_ns == trace.lidar[0].stamp_ns
    # The truth is one instant's (the stamp's): no sweep time.
    assert trace.lidar[0].truth.time_increment == 0.0


def test_a_270_degree_lidar_sweeps_its_readings_in_three_quarters_of_a_turn():
    config = SimConfig(world='room', lidar='hokuyo-ust10lx', resolution=SMALL, noise=False)
    trace = Trace()
    Simulation(config).run(0.1, None, trace)
    scan = trace.lidar[0].scan
    # 40 Hz; 0.25 degree steps: 1440 per turn, as urg_node sets it (25 ms / 1440).
    assert scan.time_increment == pytest.approx(0.025 / 1440, rel=1e-12)
    assert scan.time_increment * (len(scan) - 1) == pytest.approx(0.75 * 0.025, rel=1e-12)


def test_odometry_and_state_come_at_50_hz():
    config = SimConfig(world='room', resolution=SMALL, noise=False, depth_rate=2.0)
    trace = Trace()
    Simulation(config).run(1.0, Straight(0.3), trace)
    stamps = np.array([s.stamp_ns for s in trace.states])
    assert len(stamps) == 51  # 0, 20, ..., 1000 ms
    assert np.all(np.diff(stamps) == 20 * MS)
    # Wheel odometry, not the truth: it slips a little while speeding up, within 5 cm.
    last = trace.states[-1]
    assert last.odometry.x == pytest.approx(last.position[0] + 2.0, abs=0.05)


def rectangle_range(x: float, y: float, angle: float, bounds) -> float:
    """Distance from (x, y) inside the rectangle `bounds` to its boundary along `angle`."""
    x_min, x_max, y_min, y_max = bounds
    c, s = math.cos(angle), math.sin(angle)
    along_x = (x_max - x) / c if c > 1e-12 else (x_min - x) / c if c < -1e-12 else math.inf
    along_y = (y_max - y) / s if s > 1e-12 else (y_min - y) / s if s < -1e-12 else math.inf
    return min(along_x, along_y)


def test_each_beam_is_cast_at_its_own_time_while_the_robot_turns():
    # One ray cast per beam: beam i at the physics step nearest stamp + i * time_increment.
    config = SimConfig(
        world='room', resolution=SMALL, noise=False, depth_rate=2.0, lidar_chunks=1080
    )
    trace = Trace()
    Simulation(config).run(1.5, Rotate(1.5), trace)
    frame = trace.lidar[-1]  # stamped 1.4 s, turning at full rate
    scan = frame.scan
    times = np.array([(s.stamp_ns - frame.stamp_ns) / 1e9 for s in trace.states])
    yaws = np.unwrap([s.true_pose.yaw for s in trace.states])
    xs = np.array([s.position[0] for s in trace.states])
    ys = np.array([s.position[1] for s in trace.states])
    rate = (np.interp(0.1, times, yaws) - np.interp(0.0, times, yaws)) / 0.1
    assert rate == pytest.approx(1.5, abs=0.1)
    yaw_at_stamp = float(np.interp(0.0, times, yaws))
    ranges = scan.ranges.astype(np.float64)

    def expected(beam: int, turned: float) -> float:
        t = beam * scan.time_increment
        x, y = float(np.interp(t, times, xs)), float(np.interp(t, times, ys))
        angle = yaw_at_stamp + turned + scan.angle_min + beam * scan.angle_increment
        distance = rectangle_range(x, y, angle, LARGE_ROOM)
        hit_x = x + distance * math.cos(angle)
        door = abs(hit_x - 1.5) < 0.6 and distance > 2.0  # the door gap in the +y wall
        return math.nan if door else distance

    own_time = [
        expected(i, float(np.interp(i * scan.time_increment, times, yaws)) - yaw_at_stamp)
        for i in range(len(scan))
    ]
    own_error = np.abs(ranges - np.array(own_time))
    # Within 1 ms (half a step) of its time a beam turns by 1.5 mrad: a few mm at 1-5 m.
    assert np.nanmedian(own_error) < 0.005
    # The turn that best fits a block of beams to the room is the robot's turn since the
    # stamp at the block's time: about 1.5 rad/s * i * 92.6 us, 0.13 rad by beam 950. The
    # fit is good to a few mrad: beam times are on 2 ms steps (1.5 mrad), the search grid is
    # 1 mrad, and a wall seen head-on hardly changes range with the angle.
    for centre in (100, 300, 540, 750, 950):
        block = range(centre - 40, centre + 40)
        candidates = np.arange(-0.05, 0.2, 0.001)
        misfit = [
            np.nanmean([(ranges[i] - expected(i, turned)) ** 2 for i in block])
            for turned in candidates
        ]
        turned = float(np.interp(centre * scan.time_increment, times, yaws)) - yaw_at_stamp
        assert candidates[int(np.nanargmin(misfit))] == pytest.approx(turned, abs=0.005)
    assert float(np.interp(950 * scan.time_increment, times, yaws)) - yaw_at_stamp == (
        pytest.approx(1.5 * 950 * 0.1 / 1080, abs=0.015)
    )


def test_sensors_see_the_pose_the_odometry_reads():
    simulation = Simulation(SimConfig(world='room', resolution=SMALL, noise=False))
    simulation.set_command(0.3, 1.0)
    simulation.advance_to_step(100)
    # The free joint's position is the base's: the poses the sensors use are of this step,
    # not of the one before (mj_step integrates after computing them).
    position, _ = simulation.base_pose()
    assert position == pytest.approx(simulation.data.qpos[0:3], abs=1e-12)
    assert simulation.time == pytest.approx(0.2)


def test_bad_timing_settings_are_refused():
    with pytest.raises(SimError, match=r'depth_latency -0\.01 s must be in \[0, 1\] s'):
        SimConfig(depth_latency=-0.01)
    with pytest.raises(SimError, match=r'lidar_phase 2\.0 s must be in \[0, 1\] s'):
        SimConfig(lidar_phase=2.0)
    with pytest.raises(SimError, match=r'lidar_chunks 0 must be in \[1, 10000\]'):
        SimConfig(lidar_chunks=0)
    with pytest.raises(SimError, match=r'state_rate 0\.0 Hz must be in \(0, 1000\]'):
        SimConfig(state_rate=0.0)
