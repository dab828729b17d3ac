"""Algorithm 2 (merge) with REP-117 semantics.

Each input is first normalised against its own limits (`normalized_ranges`): a finite
value outside its scan's [range_min, range_max], or not positive, is a driver's error
value (a Hokuyo's 0 for no return, an overflow code) and becomes NaN, "no valid
measurement". Not -Inf: REP-117 keeps -Inf for "too close to measure", and a LaserScan
cannot say that a value below range_min means that (a Hokuyo URG's values under 20 mm
are error codes, 0 among them); a driver that means it publishes -Inf, which is kept.
NaN is the safe reading of the two for fusion: it hides nothing the other sensor sees,
where a false -Inf would put an obstacle on the robot.

The merge then publishes only normalised values under min(range_min) and
max(range_max) of the inputs, so every finite value it publishes is a real reading of
one sensor, inside that sensor's limits and so inside the published ones.
"""

from __future__ import annotations

import numpy as np

from scanfuse.errors import InputError
from scanfuse.scan import Scan, normalized_ranges


def merge_scans(lidar: Scan, depth_on_lidar_grid: Scan) -> Scan:
    """Algorithm 2 (merge): per slot the nearer of the LiDAR and depth readings.

    Header, angles and times come from the LiDAR; range_min is the smaller and
    range_max the larger of the two scans' limits. Beyond the paper:

    - readings outside their own scan's [range_min, range_max] (a driver's 0 or
      overflow value) carry no information and never hide the other sensor;
    - NaN (no information) never hides a reading of the other sensor, whatever
      the argument order (the paper's plain `min` does, depending on it);
    - -Inf (too close) wins over everything, +Inf (free) only over NaN;
    - the result is never farther than a finite in-range LiDAR reading: fusion
      only ever adds obstacles;
    - the published values are the normalised ones (module docstring): a driver's
      error value is published as NaN, never as a range inside the merged limits.
    """
    if len(depth_on_lidar_grid) != len(lidar):
        msg = (
            f'cannot merge a {len(depth_on_lidar_grid)}-reading depth scan into a '
            f'{len(lidar)}-reading LiDAR scan; resample it onto the LiDAR grid first'
        )
        raise InputError(msg)
    lidar_ranges = normalized_ranges(lidar)
    depth_ranges = normalized_ranges(depth_on_lidar_grid)
    depth_wins = (depth_ranges < lidar_ranges) | (np.isnan(lidar_ranges) & ~np.isnan(depth_ranges))
    ranges = np.where(depth_wins, depth_ranges, lidar_ranges)
    intensities = None
    if lidar.intensities is not None and lidar.intensities.size:
        intensities = np.where(depth_wins, np.float32(0.0), lidar.intensities)
    return lidar.with_ranges(
        ranges,
        intensities=intensities,
        range_min=min(lidar.range_min, depth_on_lidar_grid.range_min),
        range_max=max(lidar.range_max, depth_on_lidar_grid.range_max),
    )
