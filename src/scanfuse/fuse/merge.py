"""Algorithm 2 (merge) with REP-117 semantics."""

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
      only ever adds obstacles. Where the LiDAR wins, its raw value is kept.
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
    ranges = np.where(depth_wins, depth_ranges, lidar.ranges)
    intensities = None
    if lidar.intensities is not None and lidar.intensities.size:
        intensities = np.where(depth_wins, np.float32(0.0), lidar.intensities)
    return lidar.with_ranges(
        ranges,
        intensities=intensities,
        range_min=min(lidar.range_min, depth_on_lidar_grid.range_min),
        range_max=max(lidar.range_max, depth_on_lidar_grid.range_max),
    )
