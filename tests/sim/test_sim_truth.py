"""Ground-truth obstacle scan: exact minimum over each slot's angular interval."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanfuse.scan import AngleGrid
from scanfuse.sim import Obstacle, SimError, TruthScanner
from scanfuse.sim.worlds import box, cylinder

GRID = AngleGrid(-math.pi, 2 * math.pi / 360, 360)  # one-degree slots


def scanner(*obstacles, grid=GRID, range_max=12.0):
    return TruthScanner(
        obstacles, grid, min_obstacle_height=0.03, max_obstacle_height=0.5, range_max=range_max
    )


def test_a_wall_face_ahead_is_at_its_distance_and_the_nearest_edge_of_each_slot():
    wall = box('w', 'wall', (1.1, 0.0), (0.1, 0.5), (0.0, 1.0))  # face at x = 1.0, |y| <= 0.5
    ranges = scanner(wall).scan(0.0, 0.0, 0.0)
    angles = GRID.angles()
    half = GRID.angle_increment / 2
    ahead = np.abs(np.tan(np.abs(angles) + half)) < 0.5
    ahead &= np.cos(angles) > 0
    expected = 1.0 / np.cos(np.maximum(np.abs(angles[ahead]) - half, 0.0))
    assert ranges[ahead] == pytest.approx(expected, rel=1e-6)
    assert ranges[180] == pytest.approx(1.0)
    assert np.all(np.isinf(ranges[np.cos(angles) < 0]))


def test_pose_moves_and_turns_the_scan():
    wall = box('w', 'wall', (3.1, 2.0), (0.1, 0.5), (0.0, 1.0))  # face at x = 3.0 around y = 2
    # From (1, 2) heading +pi/2 (facing +y), the wall is to the right: angle -pi/2.
    ranges = scanner(wall).scan(1.0, 2.0, math.pi / 2)
    right = int(np.argmin(np.abs(GRID.angles() + math.pi / 2)))
    assert ranges[right] == pytest.approx(2.0)


def test_only_obstacles_reaching_into_the_collision_slab_count():
    above = box('a', 'shelf_board', (1.1, 0.0), (0.1, 0.5), (0.6, 0.618))
    below = box('b', 'cable_tray', (2.1, 0.0), (0.1, 0.5), (0.0, 0.02))
    touching = box('c', 'low_box', (3.1, 0.0), (0.1, 0.5), (0.0, 0.03))
    ranges = scanner(above, below, touching).scan(0.0, 0.0, 0.0)
    assert ranges[180] == pytest.approx(3.0)


def test_beyond_range_max_is_infinite():
    wall = box('w', 'wall', (5.1, 0.0), (0.1, 0.5), (0.0, 1.0))
    assert np.isinf(scanner(wall, range_max=4.0).scan(0.0, 0.0, 0.0)[180])
    assert scanner(wall, range_max=6.0).scan(0.0, 0.0, 0.0)[180] == pytest.approx(5.0)


def test_a_thin_leg_narrower_than_a_slot_is_still_found():
    # A 12 mm leg at 3 m spans 0.23 degrees, a quarter of a slot, between two slot centres.
    leg = cylinder(
        'leg',
        'chair_leg',
        (3.0 * math.cos(0.5 * math.pi / 180), 3.0 * math.sin(0.5 * math.pi / 180)),
        0.012,
        (0.0, 0.43),
    )
    ranges = scanner(leg).scan(0.0, 0.0, 0.0)
    hit = np.flatnonzero(np.isfinite(ranges))
    assert hit.size >= 1
    assert ranges[hit].min() == pytest.approx(3.0 - 0.012, abs=2e-4)


def _dense_minimum(obstacle, angles_lo, angles_hi, samples=400):
    """Brute force: many rays per slot against every footprint edge."""
    a = obstacle.footprint
    b = np.roll(a, -1, axis=0)
    best = np.full(angles_lo.size, np.inf)
    for fraction in np.linspace(0.0, 1.0, samples):
        angle = angles_lo + fraction * (angles_hi - angles_lo)
        u = np.column_stack([np.cos(angle), np.sin(angle)])
        edge = b - a
        denom = u[:, None, 0] * edge[None, :, 1] - u[:, None, 1] * edge[None, :, 0]
        with np.errstate(divide='ignore', invalid='ignore'):
            t = (a[None, :, 0] * edge[None, :, 1] - a[None, :, 1] * edge[None, :, 0]) / denom
            s = (a[None, :, 0] * u[:, None, 1] - a[None, :, 1] * u[:, None, 0]) / denom
        t = np.where((t > 0) & (s >= 0) & (s <= 1), t, np.inf).min(axis=1)
        best = np.minimum(best, t)
    return best


@settings(max_examples=25, deadline=None)
@given(
    x=st.floats(0.8, 4.0),
    y=st.floats(-3.0, 3.0),
    half_x=st.floats(0.01, 0.6),
    half_y=st.floats(0.01, 0.6),
    yaw=st.floats(-math.pi, math.pi),
)
def test_truth_equals_a_brute_force_minimum_over_each_slot(x, y, half_x, half_y, yaw):
    obstacle = box('o', 'low_box', (x, y), (half_x, half_y), (0.0, 0.1), yaw=yaw)
    if np.linalg.norm(obstacle.footprint, axis=1).min() < 0.3:
        return  # the origin must lie outside the box
    ranges = scanner(obstacle).scan(0.0, 0.0, 0.0).astype(np.float64)
    half = GRID.angle_increment / 2
    dense = _dense_minimum(obstacle, GRID.angles() - half, GRID.angles() + half)
    both = np.isfinite(dense)
    # Dense sampling can only miss the exact minimum from above, by a sliver.
    assert np.all(ranges[both] <= dense[both] + 1e-6)
    assert np.all(ranges[both] >= dense[both] - 2e-3)
    # Slots that the dense rays miss entirely can only be grazed at their very edge.
    grazed = np.isfinite(ranges) & ~both
    assert grazed.sum() <= 2


def test_clockwise_footprints_are_reordered_and_give_the_same_truth():
    wall = box('w', 'wall', (1.1, 0.0), (0.1, 0.5), (0.0, 1.0))
    clockwise = Obstacle('cw', 'wall', wall.footprint[::-1].copy(), 0.0, 1.0, '')
    assert np.array_equal(clockwise.footprint, wall.footprint)
    assert scanner(clockwise).scan(0.0, 0.0, 0.0)[180] == pytest.approx(1.0)


def test_a_degenerate_footprint_is_refused():
    with pytest.raises(SimError, match=r"obstacle 'line' needs an \(N >= 3, 2\) footprint"):
        Obstacle('line', 'wall', np.zeros((2, 2)), 0.0, 1.0, '')
