"""Drop-off worlds: the floor really ends, the truth scan holds the edges, the robot falls."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from scanfuse.sim import Drop, Pose2D, SimConfig, SimError, Simulation, Trace
from scanfuse.sim.robot import FALL_DEPTH
from scanfuse.sim.sensors import lidar_profile
from scanfuse.sim.truth import TruthScanner
from scanfuse.sim.worlds import hole_world, ledge_world, make_world, stairs_world

LOW = {'resolution': (256, 144), 'depth_rate': 2.0, 'noise': False}
GRID = lidar_profile('rplidar-a2').grid
AHEAD = 540  # rplidar-a2: angle_min -pi, 1080 slots of 1/3 degree: slot 540 looks along +x


def straight_down(sim: Simulation, x: float, y: float) -> tuple[float, str]:
    """Distance from z = 1 m straight down to the first geom, and that geom's name."""
    geom = np.zeros(1, dtype=np.int32)
    distance = mujoco.mj_ray(
        sim.model, sim.data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom
    )
    return distance, sim.model.geom(int(geom[0])).name


def test_the_ledge_floor_ends_where_its_parameters_say():
    world = ledge_world(edge=2.0, walkway=0.3, depth=0.4)
    sim = Simulation(SimConfig(world='ledge', **LOW), world)
    try:
        # From 1 m above: the dock's floor (z = 0) is 1.0 m down just before the edge, the
        # yard (z = -0.4) 1.4 m down just past it; north of the walkway line the floor goes on.
        assert straight_down(sim, 1.95, -1.0)[0] == pytest.approx(1.0, abs=1e-9)
        assert straight_down(sim, 2.05, -1.0) == (pytest.approx(1.4, abs=1e-9), 'floor')
        assert straight_down(sim, 4.0, 0.25)[0] == pytest.approx(1.4, abs=1e-9)
        assert straight_down(sim, 4.0, 0.35)[0] == pytest.approx(1.0, abs=1e-9)
        # The LiDAR plane (0.3 m) passes over the edge to the east wall, 4.5 m ahead.
        frame = sim.lidar_frame()
        assert frame.scan.ranges[AHEAD] == pytest.approx(4.5, abs=2e-3)
    finally:
        sim.close()


def test_stair_treads_step_down_by_one_rise_each():
    world = stairs_world(edge=1.6, steps=4, rise=0.17, run=0.3)
    sim = Simulation(SimConfig(world='stairs', **LOW), world)
    try:
        for step in range(5):  # the floor before the stairs, three treads, the landing
            x = 1.45 + 0.3 * step
            assert straight_down(sim, x, 0.0)[0] == pytest.approx(1.0 + 0.17 * step, abs=1e-9)
    finally:
        sim.close()


def test_truth_scan_holds_the_ledge_edge_at_its_hand_worked_range():
    world = ledge_world(edge=2.0, walkway=0.3)
    scanner = TruthScanner(
        world.obstacles,
        GRID,
        min_obstacle_height=0.03,
        max_obstacle_height=0.5,
        range_max=12.0,
        drops=world.drops,
    )
    # The LiDAR at (0, -1.5) facing +x: the edge x = 2 is 2.0 m straight ahead. 30 degrees
    # left the slot's nearest ray (its right bound, half an increment less) meets the edge at
    # y = -1.5 + 2 tan(30 deg) = -0.35 < 0.3, still the ledge: range 2 / cos(30 deg - inc/2).
    ranges = scanner.scan(0.0, -1.5, 0.0)
    assert ranges[AHEAD] == pytest.approx(2.0, abs=1e-6)
    left = AHEAD + 90
    expected = 2.0 / math.cos(math.radians(30.0) - GRID.angle_increment / 2)
    assert ranges[left] == pytest.approx(expected, abs=1e-5)
    # Without the drop, only the east wall (4.5 m) is ahead.
    plain = TruthScanner(
        world.obstacles, GRID, min_obstacle_height=0.03, max_obstacle_height=0.5, range_max=12.0
    )
    assert plain.scan(0.0, -1.5, 0.0)[AHEAD] == pytest.approx(4.5, abs=1e-6)


def test_truth_scan_sees_the_near_side_of_the_hole_and_nothing_from_inside():
    world = hole_world(near=1.5, length=0.8, width=1.0)
    scanner = TruthScanner(
        (),
        GRID,
        min_obstacle_height=0.03,
        max_obstacle_height=0.5,
        range_max=12.0,
        drops=world.drops,
    )
    assert scanner.scan(0.0, 0.0, 0.0)[AHEAD] == pytest.approx(1.5, abs=1e-6)
    # Facing away (+x behind the robot): the near side is 1.5 m behind, slot 0 (angle -pi).
    assert scanner.scan(0.0, 0.0, math.pi)[0] == pytest.approx(1.5, abs=1e-6)
    # A robot that fell into the hole sees no edge facing it.
    assert np.all(np.isinf(scanner.scan(1.9, 0.0, 0.0)))


@pytest.mark.parametrize(('name', 'edge'), [('ledge', 2.0), ('stairs', 1.6), ('hole', 1.5)])
def test_a_robot_driven_straight_off_the_edge_falls(name, edge):
    sim = Simulation(SimConfig(world=name, **LOW), make_world(name))
    trace = Trace()
    try:
        sim.run(10.0, lambda _: (0.35, 0.0), trace, stop=lambda: sim.fell_ns is not None)
        assert sim.fell_ns is not None
        fell = next(s for s in trace.states if s.stamp_ns == sim.fell_ns)
        # The base (between the wheels) sinks once the wheels pass the edge: not before it,
        # and well before it has crossed a wheel's radius plus a caster's offset beyond.
        assert edge - 0.02 <= fell.position[0] <= edge + 0.3
        assert sim.base_drop() > FALL_DEPTH
        # Falling off the floor is not a collision: the floor's blocks are not obstacles.
        assert trace.contacts == []
    finally:
        sim.close()


def test_driving_on_flat_floor_and_beside_the_ledge_is_no_fall():
    for world, heading in ((make_world('room'), 0.0), (ledge_world(), math.pi / 2)):
        sim = Simulation(SimConfig(world=world.name, **LOW), world)
        try:
            if world.name == 'ledge':  # along the dock, 0.6 m short of its edge, turning north
                sim.place(Pose2D(1.4, -1.5, heading))
            sim.run(4.0, lambda _: (0.35, 0.0), Trace())
            assert sim.fell_ns is None
            assert abs(sim.base_drop()) < 0.01
        finally:
            sim.close()


def test_bad_drops_are_refused():
    with pytest.raises(SimError, match='needs x_min < x_max'):
        Drop('d', 'hole', (1.0, 1.0, 0.0, 1.0), 0.3)
    with pytest.raises(SimError, match=r'depth -0.1 m must be in \(0, 5\]'):
        Drop('d', 'hole', (1.0, 2.0, 0.0, 1.0), -0.1)
    with pytest.raises(SimError, match='at least one step'):
        Drop('d', 'stairs', (1.0, 2.0, 0.0, 1.0), 0.3, steps=0)


def test_a_recording_reports_when_the_robot_fell(tmp_path):
    from rosbags.highlevel import AnyReader

    from scanfuse.ros.messages import typestore
    from scanfuse.sim.recording import record

    def drive(_):
        return (0.35, 0.0)

    fell = record(SimConfig(world='ledge', **LOW), drive, 8.0, tmp_path / 'ledge.mcap')
    assert fell.fell_at is not None
    # The recorded ground truth: the base sinks below where it started by FALL_DEPTH then.
    store = typestore()
    with AnyReader([tmp_path / 'ledge.mcap']) as reader:
        wanted = [c for c in reader.connections if c.topic == '/ground_truth/pose']
        poses = [
            (log_time, store.deserialize_cdr(raw, c.msgtype).pose.position.z)
            for c, log_time, raw in reader.messages(wanted)
        ]
    first_time, first_z = poses[0]
    sunk = next(time for time, z in poses if first_z - z > FALL_DEPTH)
    assert (sunk - first_time) / 1e9 == pytest.approx(fell.fell_at, abs=0.25)
    stayed = record(SimConfig(world='room', **LOW), drive, 3.0, tmp_path / 'room.mcap')
    assert stayed.fell_at is None


def _reported(output: str, quantity: str) -> str:
    """The value `scanfuse simulate`'s summary table gives `quantity` (its row's last cell)."""
    row = next(line for line in output.splitlines() if quantity in line)
    return row.split(quantity, 1)[1].strip(' │|\n').split('│')[-1].strip()


def test_cli_simulate_reports_the_fall_and_the_contacts(tmp_path, capsys):
    from scanfuse.cli import main
    from scanfuse.sim.robot import RobotSpec

    low = ['--resolution', '256x144', '--depth-rate', '2', '--no-noise', '--path', 'straight']
    # Straight at 0.3 m/s (`Straight`) from x = 0 at the ledge, whose floor ends at x = 2 m
    # (`ledge_world`, the start's y is over the yard): the base's edge reaches it after
    # (2 - r) / 0.3 s, its centre after 2 / 0.3 s; it has fallen well before 2 s later.
    radius = RobotSpec().body_radius
    ledge = ['simulate', '--world', 'ledge', '--duration', '9', '--out', str(tmp_path / 'l.mcap')]
    assert main([*ledge, *low]) == 0
    fell = _reported(capsys.readouterr().out, 'robot fell (down a drop)')
    assert fell.startswith('yes, ')
    assert (2.0 - radius) / 0.3 <= float(fell.split()[1]) <= 2.0 / 0.3 + 2.0
    # The bookshelf's boards stand 2 m ahead, below the LiDAR's plane: the robot drives into
    # them and does not fall (a floor everywhere).
    shelf = [
        'simulate',
        '--world',
        'bookshelf',
        '--duration',
        '9',
        '--out',
        str(tmp_path / 'b.mcap'),
    ]
    assert main([*shelf, *low]) == 0
    output = capsys.readouterr().out
    assert int(_reported(output, 'contact samples (robot touching an obstacle)')) > 0
    assert _reported(output, 'robot fell (down a drop)') == 'no'
