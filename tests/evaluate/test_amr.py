"""The AMR's trials: backing out of a dead end past a low box, the navigator in reverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.errors import ConfigError
from scanfuse.evaluate.amr_trials import AMR_FAMILIES, BACK_OUT, amr_trial
from scanfuse.evaluate.closed_loop import Navigator
from scanfuse.evaluate.mapping import GridSpec
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings, amr_specs
from scanfuse.scan import Scan
from scanfuse.sim.robot import AMR, AMR_CHASSIS
from scanfuse.sim.worlds import Pose2D

LIDAR_HEIGHT = 0.30
SLAB = (0.03, 0.5)


def empty_scan(count: int = 360) -> Scan:
    increment = 2 * math.pi / count
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - increment,
        angle_increment=increment,
        range_min=0.05,
        range_max=10.0,
        ranges=np.full(count, np.inf, dtype=np.float32),
    )


def navigator(**changes) -> Navigator:
    # Cell centres on whole multiples of 5 cm: the path straight back runs along y = 0.
    spec = GridSpec(0.05, (-3.025, -3.025), 121, 121)
    values = {'waypoints': [(-2.0, 0.0)], 'reverse_waypoints': 1, **changes}
    return Navigator(spec, (-2.0, 1.5), AMR.body_radius, **values)


def test_a_waypoint_reached_backwards_is_driven_rear_first():
    # The waypoint lies 2 m straight behind: backwards, the rear already faces it (no turn).
    nav = navigator()
    v, omega = nav.step(empty_scan(), Pose2D(0.0, 0.0, 0.0))
    assert v == pytest.approx(-nav.reverse_speed)
    assert omega == pytest.approx(0.0, abs=1e-9)
    assert nav.last_v == v
    # Forwards (no reverse waypoint) the same waypoint is behind: turn in place first.
    ahead = navigator(reverse_waypoints=0)
    v, omega = ahead.step(empty_scan(), Pose2D(0.0, 0.0, 0.0))
    assert v == 0.0
    assert abs(omega) == pytest.approx(ahead.max_turn)


def test_the_stop_zone_guards_the_rear_when_reversing():
    # A reading 0.35 m straight behind the LiDAR (at the base's origin): 0.05 m past the
    # 0.30 m disc's rear edge, inside the 0.08 m stop zone.
    scan = empty_scan()
    behind = int(scan.grid.slot_of(np.array([math.pi]))[0])
    ranges = scan.ranges.copy()
    ranges[behind] = AMR.body_radius + 0.05
    v, _ = navigator().step(scan.with_ranges(ranges), Pose2D(0.0, 0.0, 0.0))
    assert v == 0.0
    # The same reading ahead does not stop a robot backing away from it.
    ahead = int(scan.grid.slot_of(np.array([0.0]))[0])
    ranges = scan.ranges.copy()
    ranges[ahead] = AMR.body_radius + 0.05
    v, _ = navigator().step(scan.with_ranges(ranges), Pose2D(0.0, 0.0, 0.0))
    assert v < 0.0


def test_the_scan_frame_mounting_places_readings_in_the_base_frame():
    # A LiDAR at (0.25, 0.17) facing +45 degrees; a reading 1 m along its own +x axis lies at
    # (0.25 + cos 45, 0.17 + sin 45) in base_link.
    nav = navigator(lidar_x=0.25, lidar_y=0.17, lidar_yaw=math.pi / 4)
    scan = empty_scan()
    ranges = np.full(len(scan), np.nan, dtype=np.float32)
    ranges[int(scan.grid.slot_of(np.array([0.0]))[0])] = 1.0
    points = nav._points_in_robot(scan.with_ranges(ranges))
    np.testing.assert_allclose(points, [[0.25 + math.sqrt(0.5), 0.17 + math.sqrt(0.5)]])


@pytest.mark.parametrize('seed', range(5))
def test_the_box_behind_is_low_and_in_the_straight_way_out(seed):
    trial = amr_trial('amr-deadend', seed)
    (box,) = [o for o in trial.world.obstacles if o.kind == 'low_box']
    # Under both LiDARs' plane, inside the collision slab: only a camera can show it.
    assert SLAB[0] < box.z_max < LIDAR_HEIGHT
    # Backing straight out along y = 0 the chassis (half width 0.17 m) sweeps it.
    ys = box.footprint[:, 1]
    assert ys.min() < AMR_CHASSIS[1]
    assert ys.max() > -AMR_CHASSIS[1]
    # It stands between the start and the waypoint reached backwards.
    xs = box.footprint[:, 0]
    assert BACK_OUT[0] < xs.min() < xs.max() < -AMR_CHASSIS[0]
    assert trial.reverse == 1
    assert trial.waypoints == (BACK_OUT,)


def test_amr_specs_are_seeded_variants_with_their_reverse_waypoint():
    specs = amr_specs(tuple(AMR_FAMILIES), 2)
    assert [s.label for s in specs] == ['amr-deadend-0', 'amr-deadend-1']
    assert all(s.reverse_waypoints == 1 for s in specs)


def test_unknown_amr_trials_and_methods_are_refused():
    with pytest.raises(ConfigError, match=r"unknown AMR trial 'amr-maze'; choose from amr-dead"):
        Evaluation(EvaluationSettings.quick(amr=('amr-maze',)))
    with pytest.raises(ConfigError, match=r"unknown AMR method 'd2l'; choose from lidar, obst"):
        Evaluation(EvaluationSettings.quick(amr_methods=('d2l',)))
