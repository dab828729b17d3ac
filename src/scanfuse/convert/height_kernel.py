"""The compiled rebuild of `ObstacleProjector`'s height tables for a new ground.

The tables (per pixel the slab's depth interval, where the drop interval starts and the
floor crossing depth, in metres and in millimetres, and the blocks' extremes the kernel
skips by) depend on the ground. The numpy functions of `obstacle` that build them at
start-up take ~100 ms at 1280x720, most of it temporaries; a pitching body or a ramp moves
the ground every frame, so this rebuilds them in one pass of plain loops. It is the same
arithmetic as `obstacle._depth_interval`, `obstacle._drop_interval` and
`obstacle._millimetre_interval` (their numpy code is the reference: see the tests), with
the ramp's lifts: the slab's top, its bottom and the floor crossing each measured above
the ground where the line of sight is at that height (`GroundProfile.ground_under`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from scanfuse.compiled import compiled

_LEVEL_RAY = 1e-12
_MM_ROUNDING = 1e-6
_MILLIMETRE = 0.001
_UINT16_MAX = 65535.0
DROP_NOISE_SIGMAS = 6.0


def _millimetres(lo: float, hi: float) -> tuple[int, int]:
    """`obstacle._millimetre_interval` of one interval."""
    lo_mm = math.ceil(min(max(lo / _MILLIMETRE - _MM_ROUNDING, 1.0), _UINT16_MAX))
    hi_mm = math.floor(min(max(hi / _MILLIMETRE + _MM_ROUNDING, 0.0), _UINT16_MAX))
    if lo_mm > hi_mm:
        return int(_UINT16_MAX), 0
    return lo_mm, hi_mm


def _tables(
    x_n: Any,
    y_n: Any,
    width: int,
    horizontal: Any,
    normal: Any,
    offset: float,
    lifts: Any,
    stride: int,
    limits: Any,
    drops: Any,
    metres_lo: Any,
    metres_hi: Any,
    metres_drop: Any,
    metres_floor: Any,
    millimetres_lo: Any,
    millimetres_hi: Any,
    millimetres_drop: Any,
    millimetres_floor: Any,
) -> None:
    """Per pixel the tables (`ObstacleProjector`'s): lo, hi, drop_lo, floor in float32
    metres; lo, hi, drop_lo in uint16 millimetres and the floor in float32 millimetres.

    `limits` = (min_obstacle_height, max_obstacle_height, range_min, range_max,
    `obstacle._depth_interval`'s bottom_noise); `drops` =
    (on, min_depth, min_width, noise); `lifts` (4 x block rows x block columns, or 0 rows:
    none; `ground.Lifts.coarse`, blocks of `stride` pixels a side of an image `width` wide)
    the ground's height above the plane at the slab's top, its bottom, the floor crossing
    and the lowest ground's crossing (a drop lies beyond it).
    """
    size = min(x_n.size, y_n.size, metres_lo.size, metres_hi.size, metres_drop.size)
    size = min(size, metres_floor.size, millimetres_lo.size, millimetres_hi.size)
    size = min(size, millimetres_drop.size, millimetres_floor.size)
    with_drops = drops[0] > 0.0
    if with_drops:
        size = min(size, horizontal.size)
    min_h, max_h, range_min, range_max = limits[0], limits[1], limits[2], limits[3]
    bottom_noise = limits[4]
    drop = (drops[0], drops[1], drops[2], drops[3])
    rows = size // width
    lifted = lifts.shape[0] >= 4 and lifts.shape[1] * stride >= rows
    lifted = lifted and lifts.shape[2] * stride >= width
    # Row by row: the row's blocks' lifts spread over its pixels first (no division per
    # pixel); without lifts, the plane's offset throughout.
    row_lifts = np.full((4, width), offset)
    for v in range(rows):
        if lifted:
            row = v // stride
            for u in range(width):
                column = u // stride
                for level in range(4):
                    row_lifts[level, u] = offset - lifts[level, row, column]
        first = v * width
        for u in range(width):
            i = first + u
            a_z = normal[0] * x_n[i] + normal[1] * y_n[i] + normal[2]
            lo, hi, drop_lo, drop_hi, floor = pixel(
                a_z, row_lifts[0, u], row_lifts[1, u], row_lifts[2, u], row_lifts[3, u],
                horizontal[i] if with_drops else 1.0, min_h, max_h, range_min, range_max,
                bottom_noise, drop,
            )  # fmt: skip
            metres_lo[i], metres_hi[i], metres_drop[i], metres_floor[i] = lo, hi, drop_lo, floor
            lo_mm, hi_mm = millimetres(lo, hi)
            millimetres_lo[i], millimetres_hi[i] = lo_mm, hi_mm
            millimetres_drop[i] = millimetres(drop_lo, drop_hi)[0]
            millimetres_floor[i] = floor / _MILLIMETRE


def _pixel(
    a_z: float,
    b_top: float,
    b_bottom: float,
    b_floor: float,
    b_lowest: float,
    horizontal: float,
    min_h: float,
    max_h: float,
    range_min: float,
    range_max: float,
    bottom_noise: float,
    drops: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float]:
    """`_tables` of one pixel: its slab interval (lo, hi), drop interval (drop_lo, drop_hi)
    and floor crossing. Its line of sight rises `a_z` metres per metre of depth above the
    plane and `horizontal` metres per metre of depth; b_top, b_bottom, b_floor and b_lowest
    are the plane's offset less the lifts at the slab's top, its bottom, the floor crossing
    and the lowest ground's crossing; min_h to range_max are `_tables`'s `limits`, `drops`
    its `drops`."""
    if not math.isfinite(a_z):
        lo, hi = math.inf, -math.inf
    elif (a_z > _LEVEL_RAY or a_z < -_LEVEL_RAY) and bottom_noise > 0.0:
        z_top = (max_h - b_top) / a_z
        constant = min_h - b_bottom
        curve = bottom_noise * abs(a_z)
        discriminant = a_z * a_z - 4.0 * curve * constant
        if discriminant >= 0.0:
            q = 0.5 * (a_z + math.copysign(math.sqrt(discriminant), a_z))
            first, second = q / curve, constant / q
            bottom_lo, bottom_hi = min(first, second), max(first, second)
        else:
            bottom_lo, bottom_hi = math.inf, -math.inf
        if a_z > 0.0:
            lo, hi = max(bottom_lo, range_min), min(z_top, bottom_hi, range_max)
        else:
            lo, hi = max(z_top, bottom_lo, range_min), min(bottom_hi, range_max)
    elif a_z > _LEVEL_RAY or a_z < -_LEVEL_RAY:
        z_top = (max_h - b_top) / a_z
        z_bottom = (min_h - b_bottom) / a_z
        lo = max(min(z_top, z_bottom), range_min)
        hi = min(max(z_top, z_bottom), range_max)
    else:
        inside = min_h <= b_bottom and b_top <= max_h
        lo = range_min if inside else math.inf
        hi = range_max if inside else -math.inf
    drop_lo, drop_hi, floor = math.inf, -math.inf, math.nan
    if drops[0] > 0.0:
        crossing = -b_floor / a_z if a_z != 0.0 else math.nan
        beneath = -b_lowest / a_z if a_z != 0.0 else math.nan
        if a_z < -_LEVEL_RAY and range_min <= crossing <= range_max:
            margin = drops[1] / -a_z
            if drops[2] > 0.0:
                margin = max(margin, drops[2] / horizontal)
            margin = max(margin, DROP_NOISE_SIGMAS * drops[3] * crossing * crossing)
            # Where the line of sight meets the lowest ground beyond the range, the
            # ground may be there: no drop within it.
            if math.isfinite(margin) and beneath <= range_max:
                drop_lo = max(beneath, crossing) + margin
                drop_hi, floor = math.inf, crossing
    return lo, hi, drop_lo, drop_hi, floor


def _extremes(
    lo: Any,
    hi: Any,
    drop_lo: Any,
    height: int,
    width: int,
    bands: Any,
    block: int,
    least: Any,
    greatest: Any,
    drop_least: Any,
) -> None:
    """`obstacle._block_extremes`: per row and block of each band the least lo, greatest hi
    and least drop_lo (least[row, bands[b, 2] + k] for block k of band b)."""
    size = min(lo.size, hi.size, drop_lo.size, height * width)
    blocks = min(least.shape[1], greatest.shape[1], drop_least.shape[1])
    rows = min(height, least.shape[0], greatest.shape[0], drop_least.shape[0])
    for row in range(rows):
        for b in range(bands.shape[0]):
            start, stop, k = bands[b, 0], min(bands[b, 1], width), bands[b, 2]
            for block_start in range(start, stop, block):
                first = row * width + block_start
                last = min(row * width + min(block_start + block, stop), size)
                if not (0 <= k < blocks and first < last):
                    break
                low, high, drop = lo[first], hi[first], drop_lo[first]
                for index in range(first + 1, last):
                    low = min(low, lo[index])
                    high = max(high, hi[index])
                    drop = min(drop, drop_lo[index])
                least[row, k], greatest[row, k], drop_least[row, k] = low, high, drop
                k += 1


millimetres = compiled(_millimetres)
pixel = compiled(_pixel, error_model='numpy', inline='always')
tables = compiled(_tables, error_model='numpy')
extremes = compiled(_extremes)
