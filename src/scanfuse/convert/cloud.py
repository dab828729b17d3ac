"""Point clouds (PointCloud2, or any 3D points) to a scan, as the obstacle method does pixels.

Points come in their sensor's frame with its mounting; those whose height above the floor
(base z = 0) is inside the collision slab are moved (motion compensation) into the output
LiDAR's frame and binned by their bearing into its slots, in one compiled pass. Per slot
the obstacle method's noise-robust estimate is reported: of the k nearest points, the
farthest within `cluster_spread` r^2 of the nearest (k = `min_points`; 1: the plain
nearest). Points outside the range limits are left out, and slots without points are NaN:
a cloud has no view model to say a slot is free, so it only ever adds obstacles.

The points are read where they lie (a strided view of a PointCloud2's bytes, float32 or
float64, is not copied) by the compiled kernel (`cloud_kernel`); `_nearest_loop` with the
obstacle method's numpy pick is its reference (`points_scan(..., reference=True)`) and the
fallback without numba: both give the same scan bit for bit.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.bearing import fast_atan2
from scanfuse.convert.obstacle import _cluster_range_squared
from scanfuse.scan import TWO_PI, Scan

if TYPE_CHECKING:
    from types import ModuleType

    import numpy.typing as npt

    from scanfuse.motion import PlanarMotion
    from scanfuse.scan import AngleGrid
    from scanfuse.transforms import Transform


def _nearest_loop(
    points: Any,
    height_row: Any,
    plane: Any,
    low: float,
    high: float,
    angle_min: float,
    increment: float,
    count: int,
    turn: int,
    range_min_squared: float,
    range_max_squared: float,
    nearest: Any,
) -> None:
    """Per slot the k smallest squared ranges of the points inside the slab and the range
    limits, ascending (Inf: fewer).

    `points` (N x 3) are in the sensor frame; `height_row` (4) gives their height above the
    floor, `plane` (2 x 4) their x, y in the moved output LiDAR frame: one pass, the height
    test first so most points (floor, walls above) cost three multiply-adds.
    """
    k = nearest.shape[1]
    nearest[:] = np.inf
    for i in range(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        height = height_row[0] * px + height_row[1] * py + height_row[2] * pz + height_row[3]
        if not low <= height <= high:  # also drops NaN
            continue
        x = plane[0, 0] * px + plane[0, 1] * py + plane[0, 2] * pz + plane[0, 3]
        y = plane[1, 0] * px + plane[1, 1] * py + plane[1, 2] * pz + plane[1, 3]
        r2 = x * x + y * y
        if not range_min_squared <= r2 <= range_max_squared or r2 == 0.0:
            continue
        slot = math.floor((fast_atan2(y, x) - angle_min) / increment + 0.5)
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


def _load_kernel() -> ModuleType | None:
    """The numba-compiled kernel, or None when numba is not installed (the reference runs)."""
    try:
        from scanfuse.convert import cloud_kernel  # noqa: PLC0415
    except ImportError:  # pragma: no cover - numba is a dependency; this is the fallback
        return None
    return cloud_kernel


_KERNEL = _load_kernel()
# Coordinates the kernel reads as they are; anything else is widened to float64 first
# (exact, as the kernel widens them too).
_NATIVE = (np.dtype(np.float32), np.dtype(np.float64))


def _packed(points: npt.NDArray[np.floating]) -> tuple[npt.NDArray[np.floating], int]:
    """The N x 3 `points` as one read-only run of values with x, y, z the first three of
    every 3 or 4 (C order, or x, y, z and padding), and that stride; (empty, 0) otherwise.

    The run ends at the last point's z: it spans only memory inside the points' own.
    """
    size = points.itemsize
    stride, step = points.strides
    width = stride // size if step == size and stride % size == 0 else 0
    if width not in (3, 4) or len(points) < 2:
        none = np.empty(0, points.dtype)
        none.setflags(write=False)  # the run's type: one compiled kernel for both
        return none, 0
    run = np.lib.stride_tricks.as_strided(
        points[:, 0], shape=(width * (len(points) - 1) + 3,), strides=(size,), writeable=False
    )
    return run, width


def points_scan(
    points: npt.NDArray[np.floating],
    base_to_sensor: Transform,
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
    reference: bool = False,
) -> Scan:
    """The obstacle scan of 3D points of a sensor mounted at `base_to_sensor`, on `grid`.

    Heights are above the base frame's z = 0 (the floor). `motion` moves points from the
    LiDAR frame at the cloud's stamp to the LiDAR frame at the scan's stamp. Frame and stamp
    are left for the caller. `reference`: the pure Python loop (`_nearest_loop`) and numpy
    pick, not the compiled kernel (the same scan; for tests).
    """
    sensor = base_to_sensor.matrix
    in_laser = base_to_laser.inverse().matrix @ sensor
    moving = np.array(
        [[motion.cos, -motion.sin, 0.0, motion.tx], [motion.sin, motion.cos, 0.0, motion.ty]]
    )
    plane = moving @ in_laser  # in_laser[3] is exactly (0, 0, 0, 1): product of two 4x4 poses
    array = np.asarray(points)
    if array.dtype not in _NATIVE:  # other types, and either float in the other byte order
        array = array.astype(np.float64)
    array = array.reshape(-1, 3)  # a view, strides kept, for an N x 3 view of a message
    height_row = np.ascontiguousarray(sensor[2])
    turn = round(TWO_PI / abs(grid.angle_increment))
    limits = (grid.angle_min, grid.angle_increment, grid.count, turn)
    squared = (range_min * range_min, range_max * range_max)
    if _KERNEL is not None and not reference:
        ranges = _KERNEL.cloud_ranges(
            array, *_packed(array), height_row, plane, min_height, max_height, *limits, *squared,
            max(1, min_points), cluster_spread,
        )  # fmt: skip
    else:
        nearest = np.empty((grid.count, max(1, min_points)), dtype=np.float64)
        _nearest_loop(array, height_row, plane, min_height, max_height, *limits, *squared, nearest)
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


def lidar_readings(scan: Scan) -> npt.NDArray[np.bool_]:
    """Which readings of a LaserScan are finite and in range: those `lidar_points` gives."""
    ranges = scan.ranges.astype(np.float64)
    valid: npt.NDArray[np.bool_] = (
        np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
    )
    return valid


def lidar_points(
    scan: Scan, readings: npt.NDArray[np.bool_] | None = None
) -> npt.NDArray[np.float64]:
    """The finite in-range readings of a LaserScan as 3D points in its own frame (z = 0);
    `readings`: `lidar_readings(scan)` when the caller has it already."""
    valid = lidar_readings(scan) if readings is None else readings
    angles = scan.angles()[valid]
    reach = scan.ranges[valid].astype(np.float64)
    return np.stack([reach * np.cos(angles), reach * np.sin(angles), np.zeros_like(reach)], axis=1)
