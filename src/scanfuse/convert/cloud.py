"""Point clouds (PointCloud2, or any 3D points) to a scan, as the obstacle method does pixels.

Points are given in the base frame (z = 0 is the floor); those whose height is inside the
collision slab are moved (motion compensation) into the output LiDAR's frame and binned by
their bearing into its slots. Per slot the same noise-robust estimate as the obstacle
method's is reported: of the k nearest points, the farthest within `cluster_spread` r^2 of
the nearest (k = `min_points`; 1: the plain nearest). Points outside the range limits are
left out, and slots without points are NaN: a cloud has no view model to say a slot is
free, so it only ever adds obstacles.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.bearing import fast_atan2
from scanfuse.convert.obstacle import _cluster_range_squared
from scanfuse.scan import TWO_PI, Scan

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

    from scanfuse.motion import PlanarMotion
    from scanfuse.scan import AngleGrid
    from scanfuse.transforms import Transform


def _nearest_loop(
    x: Any,
    y: Any,
    angle_min: float,
    increment: float,
    count: int,
    turn: int,
    range_min_squared: float,
    range_max_squared: float,
    nearest: Any,
) -> None:
    """Per slot the k smallest squared ranges of points (x, y) within the range limits,
    ascending (Inf: fewer)."""
    k = nearest.shape[1]
    nearest[:] = np.inf
    for i in range(x.size):
        r2 = x[i] * x[i] + y[i] * y[i]
        if not range_min_squared <= r2 <= range_max_squared or r2 == 0.0:
            continue
        slot = math.floor((fast_atan2(y[i], x[i]) - angle_min) / increment + 0.5)
        if slot < 0:
            slot += turn
        elif slot >= turn:
            slot -= turn
        if slot < 0 or slot >= count:
            continue
        if not r2 < nearest[slot, k - 1]:
            continue
        j = k - 1
        while j > 0 and nearest[slot, j - 1] > r2:
            nearest[slot, j] = nearest[slot, j - 1]
            j -= 1
        nearest[slot, j] = r2


def _load_kernel() -> Callable[..., None]:
    try:
        import numba  # noqa: PLC0415
    except ImportError:  # pragma: no cover - numba is a dependency
        return _nearest_loop
    kernel: Callable[..., None] = numba.njit(cache=True, nogil=True)(_nearest_loop)
    return kernel


_KERNEL = _load_kernel()


def points_scan(
    points_base: npt.NDArray[np.floating],
    base_to_laser: Transform,
    grid: AngleGrid,
    *,
    motion: PlanarMotion,
    min_height: float,
    max_height: float,
    range_min: float,
    range_max: float,
    min_points: int = 1,
    cluster_spread: float = math.inf,
) -> Scan:
    """The obstacle scan of 3D points in the base frame, on the LiDAR's `grid`.

    `motion` moves points from the LiDAR frame at the cloud's stamp to the LiDAR frame at the
    scan's stamp. Frame and stamp are left for the caller.
    """
    points = np.asarray(points_base, dtype=np.float64).reshape(-1, 3)
    inside = (points[:, 2] >= min_height) & (points[:, 2] <= max_height)
    in_laser = base_to_laser.inverse().apply(points[inside]) if inside.any() else np.empty((0, 3))
    x, y = motion.apply(in_laser[:, 0], in_laser[:, 1])
    nearest = np.empty((grid.count, max(1, min_points)), dtype=np.float64)
    _KERNEL(
        np.ascontiguousarray(x),
        np.ascontiguousarray(y),
        grid.angle_min,
        grid.angle_increment,
        grid.count,
        round(TWO_PI / abs(grid.angle_increment)),
        range_min * range_min,
        range_max * range_max,
        nearest,
    )
    best = _cluster_range_squared(nearest.astype(np.float32), cluster_spread)
    ranges = np.where(np.isfinite(best), np.sqrt(best), np.float32(np.nan)).astype(np.float32)
    return Scan(
        angle_min=grid.angle_min,
        angle_max=grid.angle_max,
        angle_increment=grid.angle_increment,
        range_min=range_min,
        range_max=range_max,
        ranges=ranges,
    )


def lidar_points(scan: Scan) -> npt.NDArray[np.float64]:
    """The finite in-range readings of a LaserScan as 3D points in its own frame (z = 0)."""
    ranges = scan.ranges.astype(np.float64)
    valid = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
    angles = scan.angles()[valid]
    reach = ranges[valid]
    return np.stack([reach * np.cos(angles), reach * np.sin(angles), np.zeros_like(reach)], axis=1)
