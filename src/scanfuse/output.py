"""The output scan's frame, grid and limits (`output_frame`, `angle_min`, `angle_max`,
`angle_increment`, `output_range_min`, `output_range_max`), and a LiDAR's readings re-binned
onto it from their 3D points.

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
    import numpy.typing as npt

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


def within_limits(scan: Scan, range_min: float, range_max: float) -> Scan:
    """`scan` published with `range_min` and `range_max` (0: its own), as REP-117 has a
    reading outside them: one nearer than range_min is dropped (NaN: no valid measurement,
    the robot's own body or a sensor's near blind zone as pointcloud_to_laserscan drops
    them), one farther than range_max is +Inf (nothing within range that way)."""
    low = range_min if range_min > 0.0 else scan.range_min
    high = range_max if range_max > 0.0 else scan.range_max
    if (low, high) == (scan.range_min, scan.range_max):
        return scan
    ranges = scan.ranges.copy()
    with np.errstate(invalid='ignore'):
        ranges[np.isfinite(ranges) & (ranges < low)] = np.nan
        ranges[np.isfinite(ranges) & (ranges > high)] = np.inf
    return scan.with_ranges(ranges, range_min=low, range_max=high)


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
    frame, from `scan`'s stamp to `stamp_ns`) and stamped then. A slot no point falls in is
    +Inf where a beam of `scan` with no return (+Inf) points (`_no_return_slots`: far away
    every origin sees a direction alike), else NaN: no reading in the output frame. The
    limits: 0 (a reading from another origin may be nearer than the LiDAR's own range_min) up
    to the LiDAR's range_max plus its distance from the output origin."""
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
    ranges = binned.ranges
    free = _no_return_slots(scan, laser_in_output, grid, motion)
    if free is not None:
        ranges = np.where(free & np.isnan(ranges), np.float32(np.inf), ranges)
    return binned.with_ranges(
        ranges,
        frame_id=frame_id,
        stamp_ns=scan.stamp_ns if stamp_ns is None else stamp_ns,
        scan_time=scan.scan_time,
    )


def _no_return_slots(
    scan: Scan, laser_in_output: Transform, grid: AngleGrid, motion: PlanarMotion
) -> npt.NDArray[np.bool_] | None:
    """Per slot of `grid`: some beam of `scan` without a return (+Inf) points into it, its
    direction turned into the output frame (and by `motion`); None when no beam is +Inf.
    Each beam covers its own slot's interval (sampled finer than both increments), so a
    coarser LiDAR leaves no gaps on a finer output grid."""
    free_beams = np.isposinf(scan.ranges)
    if not free_beams.any():
        return None
    step = abs(scan.angle_increment)
    count = 2 * max(1, math.ceil(step / abs(grid.angle_increment)))
    offsets = ((np.arange(count) + 0.5) / count - 0.5) * step  # half an output slot apart
    beams = scan.angles()[free_beams]
    angles = (beams[:, None] + offsets[None, :]).ravel()
    rotation = laser_in_output.matrix[:2, :2]
    x = rotation[0, 0] * np.cos(angles) + rotation[0, 1] * np.sin(angles)
    y = rotation[1, 0] * np.cos(angles) + rotation[1, 1] * np.sin(angles)
    # A beam tilted out of the plane still has its bearing; one pointing straight up or
    # down has none.
    flat = np.hypot(x, y) > 1e-6
    bearing = np.arctan2(y[flat], x[flat]) + motion.angle
    slots = grid.slot_of(bearing)
    free = np.zeros(grid.count, dtype=bool)
    free[slots[slots >= 0]] = True
    return free
