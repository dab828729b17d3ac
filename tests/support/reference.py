"""Per-pixel Python loops of Algorithm 1: the baseline of bench_row and the tests' oracle.

`row_scan_loop` is the row method written the plain way, one pixel at a time in
float64, with the order-independent REP-117 reduction of scanfuse's default mode.
`d2l_scan_loop` is a line-by-line transliteration of depthimage_to_laserscan's
convert() and use_point() (ros2 branch), in upstream's float/double precision and
visiting order. Neither shares code with scanfuse.convert.row beyond the camera's
ray table.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.scan import Scan

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.convert.floor import FloorGuard


def _preference(value: float) -> tuple[int, float]:
    """Sort key of the default mode: finite value < -Inf < +Inf < NaN, then nearer first."""
    if math.isnan(value):
        return (3, 0.0)
    if value == math.inf:
        return (2, 0.0)
    if value == -math.inf:
        return (1, 0.0)
    return (0, value)


def _pixel_value(
    depth: float,
    *,
    x_n: float,
    y_n: float,
    range_min: float,
    range_max: float,
    floor_guard: FloorGuard | None,
) -> float:
    """REP-117 value of one pixel: the range of equation 3, or +-Inf, or NaN."""
    if math.isnan(depth) or (math.isfinite(depth) and depth <= 0.0):
        return math.nan
    if math.isinf(depth):
        return depth  # REP-118: +Inf too far, -Inf too close
    x = x_n * depth  # X = (u - cx) Z / fx
    r = math.sqrt(x * x + depth * depth)  # equation 3
    if floor_guard is not None:
        pitch = floor_guard.camera_pitch
        descent = y_n * math.cos(pitch) + math.sin(pitch)
        if descent > 0.0:
            floor_depth = floor_guard.camera_height / descent
            floor_range = math.sqrt((x_n * floor_depth) ** 2 + floor_depth**2)
            if r >= floor_range - floor_guard.margin:
                return math.inf
    if r > range_max:
        return math.inf
    if r < range_min:
        return -math.inf
    return r


def row_scan_loop(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    *,
    scan_row: int | None = None,
    scan_height: int = 1,
    range_min: float,
    range_max: float,
    floor_guard: FloorGuard | None = None,
) -> Scan:
    """Algorithm 1 pixel by pixel, with the default mode's grid and reduction."""
    x_table, y_table = camera.normalized_coordinates
    row = min(max(round(camera.cy), 0), camera.height - 1) if scan_row is None else scan_row
    start = min(max(row - scan_height // 2, 0), camera.height - scan_height)

    # The grid: slots as wide as the widest spacing of neighbouring columns, from the
    # rightmost column's angle to the leftmost's. A pixel without a ray (NaN where the
    # lens distortion is not invertible) has no angle and takes no part.
    angles = [-math.atan(float(x)) for x in x_table[row] if math.isfinite(x)]
    low, high = min(angles), max(angles)
    if len(angles) > 1:
        spacing = max(abs(b - a) for a, b in itertools.pairwise(angles))
        count = math.floor((high - low) / spacing) + 1
        increment = (high - low) / (count - 1)
    else:
        count, increment = 1, 1.0e-3
    alpha = low - 0.5 * increment
    beta = low + (count - 0.5) * increment

    best = [math.nan] * count
    for v in range(start, start + scan_height):
        for u in range(camera.width):
            raw = depth[v, u]
            if depth.dtype == np.uint16:
                z = math.nan if int(raw) == 0 else int(raw) * 0.001
            else:
                z = float(raw)
            x_n, y_n = float(x_table[v, u]), float(y_table[v, u])
            if not math.isfinite(x_n):
                continue
            theta = -math.atan(x_n)  # equation 1: atan(X / Z) with X = x_n Z
            n = math.floor(count * (theta - alpha) / (beta - alpha))  # equation 2
            if not 0 <= n < count:
                continue
            value = _pixel_value(
                z,
                x_n=x_n,
                y_n=y_n,
                range_min=range_min,
                range_max=range_max,
                floor_guard=floor_guard,
            )
            if _preference(value) < _preference(best[n]):
                best[n] = value
    return Scan(
        angle_min=low,
        angle_max=low + increment * (count - 1),
        angle_increment=increment,
        range_min=range_min,
        range_max=range_max,
        ranges=np.asarray(best, dtype=np.float32),
        frame_id=camera.frame_id,
    )


def _use_point(
    new: np.float32, old: np.float32, range_min: np.float32, range_max: np.float32
) -> bool:
    """depthimage_to_laserscan's use_point, statement by statement."""
    new_finite = math.isfinite(new)
    old_finite = math.isfinite(old)
    if not new_finite and not old_finite:
        return not math.isnan(new)
    if not (range_min <= new <= range_max):
        return False
    if not old_finite:
        return True
    return bool(new < old)


def _angle_between_rays(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return math.acos(
        dot
        / (
            math.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2)
            * math.sqrt(b[0] ** 2 + b[1] ** 2 + b[2] ** 2)
        )
    )


def d2l_scan_loop(
    depth: npt.NDArray[np.generic],
    fx: float,
    cx: float,
    cy: float,
    *,
    scan_height: int,
    range_min: float,
    range_max: float,
) -> tuple[float, float, float, npt.NDArray[np.float32]]:
    """(angle_min, angle_max, angle_increment, ranges) as depthimage_to_laserscan computes them.

    Raises RuntimeError where upstream throws std::runtime_error.
    """
    height, width = depth.shape
    angle_max = np.float32(_angle_between_rays(((0 - cx) / fx, 0.0, 1.0), (0.0, 0.0, 1.0)))
    angle_min = np.float32(-_angle_between_rays((0.0, 0.0, 1.0), ((width - 1 - cx) / fx, 0.0, 1.0)))
    increment = np.float32((angle_max - angle_min) / np.float32(width - 1))
    if scan_height // 2 > cy or scan_height // 2 > height - cy:
        msg = f'scan_height ( {scan_height} pixels) is too large for the image height.'
        raise RuntimeError(msg)
    ranges = np.full(width, np.nan, dtype=np.float32)
    is_mm = depth.dtype == np.uint16
    unit_scaling = float(np.float32(0.001)) if is_mm else 1.0
    center_x = np.float32(cx)
    constant_x = np.float32(unit_scaling / fx)
    rmin, rmax = np.float32(range_min), np.float32(range_max)
    offset = int(cy - scan_height / 2.0)
    for v in range(offset, offset + scan_height):
        for u in range(width):
            raw = depth[v, u]
            pixel = np.float32(raw)
            r = float(pixel)
            th = -math.atan2(float(np.float32(u) - center_x) * float(constant_x), unit_scaling)
            index = int((th - float(angle_min)) / float(increment))
            valid = int(raw) != 0 if is_mm else math.isfinite(pixel)
            if valid:
                x = float((np.float32(u) - center_x) * pixel * constant_x)
                z = float(pixel * np.float32(0.001)) if is_mm else float(pixel)
                r = math.sqrt(x**2 + z**2)
            value = np.float32(r)
            if _use_point(value, ranges[index], rmin, rmax):
                ranges[index] = value
    return float(angle_min), float(angle_max), float(increment), ranges
