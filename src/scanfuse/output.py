"""The output scan's frame and grid (`output_frame`, `angle_min`, `angle_max`,
`angle_increment`), and a LiDAR's readings re-binned onto it from their 3D points.

Pure: arrays and transforms in, scans out. `FusionStream` decides which frame holds and
where it lies on the base (TF or the mountings).

A LiDAR whose frame is the output's, on the output's grid, stays as it is (its own bytes can
be published). Otherwise each reading becomes a point in the LiDAR's frame, is placed in the
output frame, and the nearest per output slot is reported: a LiDAR at a corner of the robot
read from `base_link` is exact at every slot it covers, not shifted by its offset as a
resampling by angle would be.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.convert.cloud import lidar_points, points_scan
from scanfuse.motion import IDENTITY_MOTION
from scanfuse.scan import AngleGrid, Scan

if TYPE_CHECKING:
    from scanfuse.config import FusionConfig
    from scanfuse.motion import PlanarMotion
    from scanfuse.transforms import Transform

# The output grid's step when nothing gives one (no LiDAR, obstacle method or clouds only):
# half a degree, a 720-reading turn, as common 2D LiDARs have.
DEFAULT_INCREMENT = math.pi / 360.0


def configured_grid(config: FusionConfig) -> AngleGrid | None:
    """The grid `angle_min`, `angle_max`, `angle_increment` give; None when
    `angle_increment` is 0 (the trigger's own grid)."""
    if config.angle_increment <= 0.0:
        return None
    return grid_between(config.angle_min, config.angle_max, config.angle_increment)


def default_grid(config: FusionConfig) -> AngleGrid:
    """The grid of an output no LiDAR gives: the configured one, else angle_min..angle_max
    at `DEFAULT_INCREMENT`."""
    return configured_grid(config) or grid_between(
        config.angle_min, config.angle_max, DEFAULT_INCREMENT
    )


def grid_between(angle_min: float, angle_max: float, increment: float) -> AngleGrid:
    """Readings from `angle_min` every `increment` up to `angle_max` (included when it falls
    on a step); a full turn (angle_max - angle_min = 2 pi) holds each direction once."""
    span = angle_max - angle_min
    count = math.floor(span / increment + 1e-9) + 1
    if count * increment > 2.0 * math.pi + 1e-9 * increment:
        count = math.floor(2.0 * math.pi / increment + 1e-9)
    return AngleGrid(angle_min, increment, max(count, 1))


def empty_scan(
    grid: AngleGrid, frame_id: str, stamp_ns: int, range_min: float, range_max: float
) -> Scan:
    """A scan on `grid` with no reading at all (NaN): what the sources are merged into when
    no LiDAR gives the output."""
    return Scan(
        angle_min=grid.angle_min,
        angle_max=grid.angle_max,
        angle_increment=grid.angle_increment,
        range_min=range_min,
        range_max=range_max,
        ranges=np.full(grid.count, np.nan, dtype=np.float32),
        frame_id=frame_id,
        stamp_ns=stamp_ns,
    )


def rebinned_lidar(
    scan: Scan,
    base_to_laser: Transform,
    base_to_output: Transform,
    grid: AngleGrid,
    frame_id: str,
    *,
    motion: PlanarMotion = IDENTITY_MOTION,
    stamp_ns: int | None = None,
) -> Scan:
    """`scan`'s finite readings as points, placed in the output frame and binned on `grid`
    (nearest per slot), with `scan`'s stamp and times; or moved by `motion` (in the output
    frame, from `scan`'s stamp to `stamp_ns`) and stamped then. Readings without a point (+Inf, NaN)
    become NaN: no reading in the output frame. The limits: 0 (a reading from another origin
    may be nearer than the LiDAR's own range_min) up to the LiDAR's range_max plus its
    distance from the output origin."""
    laser_in_output = base_to_output.inverse() @ base_to_laser
    offset = float(np.hypot(*laser_in_output.translation[:2]))
    range_max = float(scan.range_max) + offset
    binned = points_scan(
        lidar_points(scan),
        base_to_laser,
        base_to_output,
        grid,
        motion=motion,
        min_height=-math.inf,
        max_height=math.inf,
        range_min=0.0,
        range_max=range_max,
    )
    return binned.with_ranges(
        binned.ranges,
        frame_id=frame_id,
        stamp_ns=scan.stamp_ns if stamp_ns is None else stamp_ns,
        scan_time=scan.scan_time,
    )
