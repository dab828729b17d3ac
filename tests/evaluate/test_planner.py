"""A* on small grids with known shortest paths, inflation, and the stop/slow zones."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanfuse.errors import InputError
from scanfuse.evaluate.planner import SafetyZones, astar, inflate, path_length


def empty(height: int, width: int) -> np.ndarray:
    return np.zeros((height, width), dtype=bool)


@pytest.mark.parametrize('compiled', [True, False])
def test_straight_line_is_its_length(compiled):
    path = astar(empty(3, 12), (1, 0), (1, 10), compiled=compiled)
    assert path is not None
    assert path[0] == (1, 0)
    assert path[-1] == (1, 10)
    assert path_length(path) == pytest.approx(10.0)


def test_diagonal_and_octile_lengths():
    # 5 down and 5 across: five diagonal steps. 3 down, 7 across: 3 diagonal + 4 straight.
    assert path_length(astar(empty(10, 10), (0, 0), (5, 5))) == pytest.approx(5 * math.sqrt(2))
    assert path_length(astar(empty(10, 10), (0, 0), (3, 7))) == pytest.approx(3 * math.sqrt(2) + 4)


def test_detour_through_a_gap():
    # A wall in column 5 with one gap at row 0; start (4, 0), goal (4, 10).
    # Shortest: 4 diagonal steps up to (0, 4), 2 straight through the gap, 4 diagonal down:
    # 8 sqrt(2) + 2.
    grid = empty(5, 11)
    grid[1:, 5] = True
    path = astar(grid, (4, 0), (4, 10))
    assert path is not None
    assert (0, 5) in path
    assert path_length(path) == pytest.approx(8 * math.sqrt(2) + 2)


def test_no_corner_cutting_between_two_blocked_cells():
    grid = empty(2, 2)
    grid[0, 1] = True
    grid[1, 0] = True
    assert astar(grid, (0, 0), (1, 1)) is None


def test_no_path_and_blocked_goal():
    grid = empty(5, 5)
    grid[:, 2] = True
    assert astar(grid, (0, 0), (0, 4)) is None
    assert astar(grid, (0, 0), (0, 2)) is None


def test_blocked_start_may_leave():
    grid = empty(3, 5)
    grid[1, 0] = True
    assert path_length(astar(grid, (1, 0), (1, 4))) == pytest.approx(4.0)


def test_cells_outside_the_grid_are_rejected():
    with pytest.raises(InputError, match=r'goal cell .* outside the 3x3 grid'):
        astar(empty(3, 3), (0, 0), (3, 0))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_compiled_and_python_agree(seed):
    rng = np.random.default_rng(seed)
    grid = rng.random((12, 12)) < 0.3
    grid[0, 0] = grid[11, 11] = False
    fast = astar(grid, (0, 0), (11, 11))
    slow = astar(grid, (0, 0), (11, 11), compiled=False)
    assert (fast is None) == (slow is None)
    if fast is not None and slow is not None:
        assert path_length(fast) == pytest.approx(path_length(slow))
        # Never shorter than the straight line, and every step stays on free cells.
        assert path_length(fast) >= 11 * math.sqrt(2) - 1e-9
        assert not any(grid[cell] for cell in fast)


def test_inflate_by_radius():
    grid = empty(7, 7)
    grid[3, 3] = True
    inflated = inflate(grid, 2.0)
    # Offsets with dx^2 + dy^2 <= 4: 13 cells.
    assert inflated.sum() == 13
    assert inflated[3, 5]
    assert not inflated[5, 5]


ZONES = SafetyZones(radius=0.2, stop=0.1, slow=0.5, slow_factor=0.4)


def test_stop_zone_halts_forward_motion():
    # A point 0.25 m ahead is 0.05 m from the footprint's front edge: stop.
    assert ZONES.limit(0.3, np.array([[0.25, 0.0]])) == 0.0


def test_slow_zone_scales_speed():
    # 0.5 m ahead: 0.3 m from the front edge, inside the 0.5 m slow zone.
    assert ZONES.limit(0.3, np.array([[0.5, 0.0]])) == pytest.approx(0.12)


def test_points_behind_or_beside_or_far_do_not_limit():
    points = np.array([[-0.25, 0.0], [0.3, 0.5], [2.0, 0.0]])
    assert ZONES.limit(0.3, points) == 0.3


def test_front_edge_is_round():
    # At y = 0.16 the round front is at x = sqrt(0.2^2 - 0.16^2) = 0.12; a point at
    # x = 0.2 there is 0.08 from it (stop), one at x = 0.3 is 0.18 (slow only).
    assert ZONES.limit(0.3, np.array([[0.2, 0.16]])) == 0.0
    assert ZONES.limit(0.3, np.array([[0.3, 0.16]])) == pytest.approx(0.12)


def test_turning_in_place_is_never_limited():
    assert ZONES.limit(0.0, np.array([[0.21, 0.0]])) == 0.0
