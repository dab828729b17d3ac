"""Obstacle memory: its cost per output scan with 20 000 remembered points (target <= 0.3 ms).

Per scan the stream adds the depth scan's readings the LiDAR does not see, forgets by
radius and age, and projects what is remembered onto the LiDAR's 1080 slots; per fused
depth frame it also tries every remembered point against the image (clearing) and adds
the frame's dense slab cells. The points fill a 2 m disc around the robot
as a cluttered room would (boxes, shelf edges), not a uniform cloud.

The memory's drift correction matches each LiDAR scan against a kept reference scan
(`scanfuse.scan_matching`, budget about 0.2 ms per scan): 1080 readings of the benchmark
room (walls 2.8 m ahead, 3.0 m behind, 1.6 m left, 2.0 m right, four chair legs), 1 cm
noise and 1 % dropouts, the robot turning at 1.5 rad/s (a scan every 0.15 rad, a new
reference every third scan) while odometry over-counts the turn by 3 %.
"""

from __future__ import annotations

import math

import numpy as np
from tests.support.render import ray_to_circle

from benchmarks.common import Row, median_seconds
from scanfuse.camera import CameraModel
from scanfuse.memory import (
    MemorySettings,
    ObstacleMemory,
    Placement,
    lidar_misses,
    nearest_pixels,
    slab_points,
    worth_remembering,
)
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.scan_matching import DriftCorrection, RelativePose, match, reference
from scanfuse.transforms import BODY_TO_OPTICAL, Transform

SECTION = 'memory'
POINTS = 20_000


def remembered() -> ObstacleMemory:
    memory = ObstacleMemory(MemorySettings(radius=2.0, cell=0.025))
    rng = np.random.default_rng(0)
    while len(memory) < POINTS:
        # Edges of boxes and boards: short segments of points 1 cm apart.
        centre = rng.uniform(-1.9, 1.9, 2)
        angle = rng.uniform(0, math.pi)
        steps = np.arange(40) * 0.01
        x = centre[0] + steps * math.cos(angle)
        y = centre[1] + steps * math.sin(angle)
        inside = np.hypot(x, y) < 2.0
        memory.add(x[inside], y[inside], 0, robot=(0.0, 0.0))
    return memory


WALLS = (2.8, -3.0, 1.6, -2.0)  # x ahead, x behind, y left, y right
CHAIR_LEGS = ((1.2, 0.6), (1.2, 1.0), (1.6, 0.6), (1.6, 1.0))


def room_scan(yaw: float, seed: int) -> Scan:
    """The benchmark room from a LiDAR at the origin heading `yaw`."""
    count = 1080
    increment = 2 * math.pi / count
    world = yaw - math.pi + increment * np.arange(count)
    dx, dy = np.cos(world), np.sin(world)
    with np.errstate(divide='ignore'):
        tx = np.where(dx > 0, WALLS[0] / dx, WALLS[1] / dx)
        ty = np.where(dy > 0, WALLS[2] / dy, WALLS[3] / dy)
    ranges = np.minimum(np.abs(tx), np.abs(ty))
    for leg in CHAIR_LEGS:
        ranges = np.minimum(ranges, ray_to_circle((0.0, 0.0), world, leg, 0.0125))
    rng = np.random.default_rng(seed)
    ranges = ranges + rng.normal(0.0, 0.01, count)
    ranges[rng.random(count) < 0.01] = np.inf
    return Scan(-math.pi, math.pi - increment, increment, 0.15, 12.0, ranges.astype(np.float32))


def scan_matching_rows() -> list[Row]:
    turn = [room_scan(0.15 * k, k) for k in range(12)]
    drift = DriftCorrection()
    step = iter(range(1 << 30))

    def per_scan() -> None:
        k = next(step)
        if k % len(turn) == 0:
            drift.reset()  # the turn starts again: a new reference
        scan = turn[k % len(turn)]
        drift.update(scan, PlanarPose(0.0, 0.0, 0.15 * (k % len(turn)) * 1.03), Transform())

    ref, current = reference(turn[0]), turn[1]
    prediction = RelativePose(0.15 * 1.03, 0.0, 0.0)

    def one_match() -> None:
        match(ref, current, prediction)

    return [
        Row(
            SECTION,
            'drift correction per LiDAR scan (1080 readings, turning, 3 % over-count)',
            median_seconds(per_scan),
            'budget about 0.2 ms',
        ),
        Row(
            SECTION,
            'scan matching: one match of 1080 readings against a reference',
            median_seconds(one_match),
            'part of the row above',
        ),
        Row(
            SECTION,
            'scan matching: a 1080-reading reference (lines fitted)',
            median_seconds(lambda: reference(current)),
            'every third scan when turning',
        ),
    ]


def run() -> list[Row]:
    memory = remembered()
    count = 1080
    increment = 2 * math.pi / count
    scan = Scan(
        -math.pi,
        math.pi - increment,
        increment,
        0.2,
        3.0,
        np.random.default_rng(1).uniform(0.5, 3.0, count).astype(np.float32),
    )
    free = scan.with_ranges(np.full(count, np.inf, dtype=np.float32))
    placement = Placement.of(PlanarPose(0.1, 0.0, 0.3), Transform())
    fx = 640 / (2 * math.tan(math.radians(43.5)))
    camera = CameraModel.from_intrinsics(640, 480, fx, fx, 319.5, 239.5)
    view = Transform.from_rpy(0.0, math.radians(20), 0.0, (0.0, 0.0, 0.45)) @ BODY_TO_OPTICAL
    depth = np.full((480, 640), 2500, dtype=np.uint16)

    def per_scan() -> None:
        # As the stream: the depth scan's readings the LiDAR does not see (here: none it
        # sees, a LiDAR reading nothing in range), then forget and project.
        memory.add_scan(
            scan, placement, 0, lidar_misses(scan, free, (0.05, 0.02)), robot=(0.1, 0.0)
        )
        memory.scan(placement, scan.grid, robot=(0.1, 0.0), now_ns=1)

    def clearing() -> None:
        # Nothing is cleared (the wall at 2.5 m is behind most points): the full cost each time.
        memory.clear_seen(depth, camera, view, slab=(0.03, 0.5), range_min=0.2, range_max=3.0)

    cells = ObstacleMemory(memory.settings)

    def slab_cells() -> None:
        # What the stream adds per fused depth frame: a wall 2.5 m ahead fills the slab rows.
        x, y = slab_points(depth, camera, view, slab=(0.03, 0.5), range_min=0.2, range_max=3.0)
        keep = worth_remembering(x, y, scan, scan, placement, (0.05, 0.02))
        cells.add_dense(x[keep], y[keep], 0, min_count=3, robot=(0.0, 0.0))

    # Every slab pixel of the wall's frame (the stream keeps fewer: those behind their
    # slot's reading the LiDAR does not see), reprojected each scan as the stream does.
    wall_x, wall_y = slab_points(
        depth, camera, view, slab=(0.03, 0.5), range_min=0.2, range_max=3.0
    )
    every_reading = np.isfinite(scan.ranges)

    def standing_for() -> None:
        nearest_pixels(wall_x, wall_y, scan, every_reading, placement, 0.05)

    points = len(memory)
    return [
        Row(
            SECTION,
            f'add a scan + forget + project, {points} points, 1080 slots',
            median_seconds(per_scan),
            'target <= 0.3 ms',
        ),
        Row(
            SECTION,
            f"1080 readings' pixels among a 640x480 frame's {wall_x.size} slab pixels",
            median_seconds(standing_for),
            'once per output scan (`READING_PIXEL_WITHIN`)',
        ),
        Row(
            SECTION,
            f'clearing against a 640x480 frame, {points} points',
            median_seconds(clearing),
            'once per fused depth frame',
        ),
        Row(
            SECTION,
            'slab cells of a 640x480 frame (extract, filter, add)',
            median_seconds(slab_cells),
            'once per fused depth frame',
        ),
        *scan_matching_rows(),
    ]
