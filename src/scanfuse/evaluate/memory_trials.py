"""Closed-loop worlds where obstacle memory matters: low obstacles beside and behind the robot.

Four families (issue 13), each with seeded variants (positions jittered by a few
centimetres, box heights drawn between 5 and 15 cm: under the LiDAR's 0.30 m plane,
inside the collision slab):

- `memory-turn`: the robot starts facing away from its goal between two rows of low
  boxes; it turns in place (the boxes leave the camera's view), drives along them and
  rounds the end of one row;
- `memory-slalom`: low boxes alternate left and right of the line to the goal;
- `memory-shelf`: the robot drives past a bookshelf and low boxes to a waypoint, then
  turns back to a goal beside the shelf (what it saw on the way out is behind it);
- `memory-deadend`: the robot starts facing the closed end of a walled corridor with low
  boxes along its walls, and must turn round, drive out past them and round the
  corridor's wall past one more.

The robot (radius 0.18 m) starts at the origin; goals and waypoints are in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanfuse.sim.worlds import (
    WALL_HEIGHT,
    Obstacle,
    Pose2D,
    World,
    bookshelf,
    box,
    low_box,
    room_walls,
)

JITTER = 0.05  # metres, seeded variants
HEIGHTS = (0.05, 0.15)  # metres, low boxes


@dataclass(frozen=True)
class MemoryTrial:
    """A memory world's route: waypoints to pass, then the goal (world frame, metres)."""

    world: World
    goal: tuple[float, float]
    waypoints: tuple[tuple[float, float], ...] = ()


def _box(
    rng: np.random.Generator, name: str, x: float, y: float, size: tuple[float, float]
) -> Obstacle:
    dx, dy = rng.uniform(-JITTER, JITTER, 2)
    height = float(rng.uniform(*HEIGHTS))
    yaw = float(rng.uniform(-0.15, 0.15))
    return low_box(name, (x + dx, y + dy), yaw, (size[0], size[1], height))


def _turn(seed: int, rng: np.random.Generator) -> MemoryTrial:
    bounds = (-1.0, 3.0, -1.3, 1.3)
    obstacles = room_walls(bounds)
    row = float(rng.uniform(0.48, 0.55))
    for index, x in enumerate((-0.1, 0.6, 1.3, 2.0)):
        obstacles.append(_box(rng, f'left{index}', x, row, (0.35, 0.16)))
        obstacles.append(_box(rng, f'right{index}', x + 0.3, -row, (0.35, 0.16)))
    world = World('memory-turn', seed, tuple(obstacles), Pose2D(0.0, 0.0, math.pi), bounds)
    # Round the far end of the left row: the box on the inside of the turn leaves the view.
    return MemoryTrial(world, (2.6, 0.85))


def _slalom(seed: int, rng: np.random.Generator) -> MemoryTrial:
    bounds = (-0.8, 4.0, -1.4, 1.4)
    obstacles = room_walls(bounds)
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    for index, x in enumerate((0.9, 1.7, 2.5)):
        obstacles.append(_box(rng, f'gate{index}', x, side * 0.3, (0.3, 0.5)))
        side = -side
    world = World('memory-slalom', seed, tuple(obstacles), Pose2D(0.0, 0.0, 0.0), bounds)
    return MemoryTrial(world, (3.4, 0.0))


def _shelf(seed: int, rng: np.random.Generator) -> MemoryTrial:
    bounds = (-0.8, 3.2, -1.2, 1.6)
    obstacles = room_walls(bounds)
    shelf_y = float(rng.uniform(0.75, 0.85))
    obstacles += bookshelf('shelf', 1.1, shelf_y)
    obstacles.append(_box(rng, 'box_before', 0.7, 0.45, (0.3, 0.2)))
    obstacles.append(_box(rng, 'box_after', 1.9, 0.45, (0.3, 0.2)))
    obstacles.append(_box(rng, 'box_right', 1.3, -0.5, (0.4, 0.2)))
    world = World('memory-shelf', seed, tuple(obstacles), Pose2D(0.0, 0.0, 0.0), bounds)
    return MemoryTrial(world, (0.2, 0.8), waypoints=((2.5, 0.0),))


def _deadend(seed: int, rng: np.random.Generator) -> MemoryTrial:
    bounds = (-2.6, 1.4, -1.6, 1.6)
    obstacles = room_walls(bounds)
    half = 0.6  # the corridor's inner half width
    t = 0.05
    for sign, name in ((1.0, 'corridor_left'), (-1.0, 'corridor_right')):
        obstacles.append(box(name, 'wall', (-0.2, sign * (half + t)), (1.0, t), (0.0, WALL_HEIGHT)))
    obstacles.append(box('corridor_end', 'wall', (0.9, 0.0), (t, half + 2 * t), (0.0, WALL_HEIGHT)))
    for index, (x, sign) in enumerate(((0.55, 1.0), (0.3, -1.0), (-0.3, 1.0), (-0.7, -1.0))):
        obstacles.append(_box(rng, f'box{index}', x, sign * (half - 0.07), (0.3, 0.12)))
    # Outside, round the corridor's left wall: a low box on the inside of the last turn.
    obstacles.append(_box(rng, 'box_outside', -1.6, 0.35, (0.3, 0.2)))
    world = World('memory-deadend', seed, tuple(obstacles), Pose2D(0.2, 0.0, 0.0), bounds)
    return MemoryTrial(world, (-2.0, 0.95))


MEMORY_FAMILIES = {
    'memory-turn': _turn,
    'memory-slalom': _slalom,
    'memory-shelf': _shelf,
    'memory-deadend': _deadend,
}


def memory_trial(name: str, seed: int) -> MemoryTrial:
    """The seeded variant `seed` of one memory family (seed 0 unjittered boxes apart from rng)."""
    rng = np.random.default_rng(seed + 7000)
    return MEMORY_FAMILIES[name](seed, rng)
