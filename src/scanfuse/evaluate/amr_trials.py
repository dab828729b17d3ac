"""Closed-loop trials of the two-LiDAR, two-camera AMR (`scanfuse.sim.robot.AMR`): backing out.

`amr-deadend`: the AMR starts nose-in to the closed end of a walled bay (a pick station or
a charger) and must back out of it: the first waypoint, 3.0 m straight behind, is reached
driving backwards (`Navigator.reverse_waypoints`), rear first, then it turns and drives to a
goal beside the bay. A low box (6-14 cm, under both LiDARs' 0.30 m plane, inside the
collision slab) stands behind the bay on the line it backs out along: only the rear camera
can show it. Seeded variants move the box sideways (up to 12 cm, always in the swept path:
the box's half width plus the chassis' exceeds 0.39 m) and along (up to 8 cm), and draw its
height and yaw.

What the rear camera does not show, the planner plans through: the `lidar` AMR backs
straight into the box.

The AMR (box chassis 0.5 m x 0.34 m, planned as its 0.30 m circumscribed disc) starts at the
origin facing +x; goals and waypoints are in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanfuse.sim.worlds import WALL_HEIGHT, Pose2D, World, box, low_box, room_walls

AMR_LIDAR = 'hokuyo-ust10lx'  # the AMR's two LiDARs: 270 degrees, 40 Hz, 1081 readings
AMR_TIME_LIMIT = 40.0  # simulated seconds: 3.0 m backwards round the box, a turn, 1.1 m
BAY_HALF_WIDTH = 0.6  # metres, inner half width of the bay
BAY_END = 0.75  # x of the bay's closed end: 0.5 m ahead of the AMR's front face
BAY_MOUTH = -0.4  # x where the bay's side walls end: 0.15 m behind the AMR's rear face
BACK_OUT = (-3.0, 0.0)  # the waypoint reached backwards, past the box
GOAL = (-3.0, 1.1)


@dataclass(frozen=True)
class AmrTrial:
    """One AMR world's route: waypoints (the first `reverse` of them backwards), the goal."""

    world: World
    goal: tuple[float, float]
    waypoints: tuple[tuple[float, float], ...]
    reverse: int


def _deadend(seed: int, rng: np.random.Generator) -> AmrTrial:
    bounds = (-3.8, 1.1, -1.6, 1.6)
    obstacles = room_walls(bounds)
    t = 0.05  # half a bay wall's thickness
    length = (BAY_END - BAY_MOUTH) / 2
    centre = (BAY_END + BAY_MOUTH) / 2
    for sign, name in ((1.0, 'bay_left'), (-1.0, 'bay_right')):
        obstacles.append(
            box(
                name, 'wall', (centre, sign * (BAY_HALF_WIDTH + t)), (length, t), (0.0, WALL_HEIGHT)
            )
        )
    obstacles.append(
        box('bay_end', 'wall', (BAY_END + t, 0.0), (t, BAY_HALF_WIDTH + 2 * t), (0.0, WALL_HEIGHT))
    )
    # Its face 1.1-1.3 m beyond the mouth: the 0.30 m disc passes between it and a wall's end.
    x = -1.8 + float(rng.uniform(-0.08, 0.08))
    y = float(rng.uniform(-0.12, 0.12))
    height = float(rng.uniform(0.06, 0.14))
    yaw = float(rng.uniform(-0.3, 0.3))
    obstacles.append(low_box('box_behind', (x, y), yaw, (0.35, 0.45, height)))
    world = World('amr-deadend', seed, tuple(obstacles), Pose2D(0.0, 0.0, 0.0), bounds)
    return AmrTrial(world, GOAL, (BACK_OUT,), reverse=1)


AMR_FAMILIES = {'amr-deadend': _deadend}
AMR_METHODS = ('lidar', 'obstacle')  # the two LiDARs merged; every LiDAR and camera


def amr_trial(name: str, seed: int) -> AmrTrial:
    """The seeded variant `seed` of one AMR family."""
    rng = np.random.default_rng(seed + 9000)
    return AMR_FAMILIES[name](seed, rng)
