"""The compiled (numba) cloud kernel: per LiDAR slot the k nearest points in the slab.

Importing this module needs numba; `scanfuse.convert.cloud` falls back to its reference
(`cloud._nearest_loop` and the obstacle method's numpy `_cluster_range_squared`) without
it. The arithmetic of every point is the reference's: coordinates (float32 or float64, read
where they lie in the message, any strides) widened to float64, the height row first, the
plane rows, then `bearing.fast_atan2`'s octant polynomial and the same slot rounding, so
both give the same scan bit for bit. What differs is how the points are visited:

- Points go in blocks. A first pass computes every point's height and packs the indices
  of those inside the slab, without branches (most points, the floor and what is above
  the slab, stop there; their order in a cloud is arbitrary, so a branch on the slab test
  would mispredict often); their coordinates are then copied to contiguous scratch. When
  each point's x, y, z are the first three of 3 or 4 values (an N x 3 array; x, y, z and
  padding: point_step 16 for float32, a depth camera's cloud) the pass reads them as one
  run with a constant stride, which LLVM vectorises (`_in_slab_packed`: the slab pass
  alone 1.24 -> 0.60 ns per point on the 848x480 organized cloud of `python -m benchmarks.run
  sources`, measured once while writing it).
- A second pass over the kept points, branch-free and so vectorised by LLVM, moves them
  into the output LiDAR's frame, tests the range limits and computes the slot. This is why
  the bearing is `fast_atan2`'s polynomial written out with selects (`_slot`): the same
  operations in the same order, with no early return. numba's Python error model would put
  a zero-division check (a branch) before each division: `error_model='numpy'` leaves the
  IEEE result, which the selects discard (x = y = 0 has r^2 = 0, outside the range limits).
- A slot's k nearest are float32: squared ranges are rounded to float32 as they go in,
  not after the k smallest are chosen, which picks the same values since rounding keeps
  order. Insertion into a slot's sorted row is branch-free (`_insert`), after one test
  against its k-th; for the default k = 16 (`obstacle_min_points`) with a constant trip
  count (the kernel alone on that benchmark's 30 000 points in random order: 2.74 -> 2.50 ns
  per point, measured once while writing it).
"""

from __future__ import annotations

import math
from typing import Any

import numba  # noqa: F401  (importing this module needs numba: cloud.py falls back without)
import numpy as np

from scanfuse.compiled import compiled

# Points per block: scratch of three float64 coordinates, a slot and a value per point
# stays in L1.
BLOCK = 512
HALF_PI = 0.5 * math.pi


def _in_slab(
    points: Any,
    start: int,
    size: int,
    height_row: Any,
    low: float,
    high: float,
    index: Any,
) -> int:
    """Of points start ... start + size - 1, those whose height is in [low, high] (not NaN):
    their indices packed into `index`; how many."""
    h0, h1, h2, h3 = height_row[0], height_row[1], height_row[2], height_row[3]
    kept = 0
    for i in range(size):
        height = (
            h0 * np.float64(points[start + i, 0])
            + h1 * np.float64(points[start + i, 1])
            + h2 * np.float64(points[start + i, 2])
            + h3
        )
        index[kept] = start + i
        kept += (height >= low) & (height <= high)
    return kept


def _in_slab_packed(
    values: Any,
    width: int,
    start: int,
    size: int,
    height_row: Any,
    low: float,
    high: float,
    flags: Any,
    spare: Any,
    index: Any,
) -> int:
    """`_in_slab` for points whose x, y, z are the first three of `width` (3 or 4)
    consecutive values of `values`, the same arithmetic.

    With a constant stride LLVM loads the points with shuffles instead of gathers (twice
    as fast); for a stride of 4 only when all four values are read, hence `spare` (x, y, z,
    padding: PCL's PointXYZ and a depth camera's cloud, point_step 16 for float32). The
    caller keeps the last point of a stride-4 run out: its padding may be past the data.
    """
    h0, h1, h2, h3 = height_row[0], height_row[1], height_row[2], height_row[3]
    # Sliced, so that every index below is provably non-negative: no wraparound select to
    # stop the vectoriser.
    run = values[width * start :]
    any_kept = 0
    if width == 4:
        for i in range(size):
            height = (
                h0 * np.float64(run[4 * i])
                + h1 * np.float64(run[4 * i + 1])
                + h2 * np.float64(run[4 * i + 2])
                + h3
            )
            inside = (height >= low) & (height <= high)
            flags[i] = inside
            spare[i] = run[4 * i + 3]
            any_kept += inside
    else:
        for i in range(size):
            height = (
                h0 * np.float64(run[3 * i])
                + h1 * np.float64(run[3 * i + 1])
                + h2 * np.float64(run[3 * i + 2])
                + h3
            )
            inside = (height >= low) & (height <= high)
            flags[i] = inside
            any_kept += inside
    if any_kept == 0:  # most blocks of a camera's cloud (floor, above the slab): no packing
        return 0
    kept = 0
    for i in range(size):
        index[kept] = start + i
        kept += flags[i]
    return kept


def _gather(points: Any, index: Any, kept: int, xs: Any, ys: Any, zs: Any) -> None:
    """The coordinates (float64) of the kept points, contiguous for the vectorised pass."""
    for j in range(kept):
        p = index[j]
        xs[j] = points[p, 0]
        ys[j] = points[p, 1]
        zs[j] = points[p, 2]


def _slot(
    xs: Any,
    ys: Any,
    zs: Any,
    kept: int,
    plane: Any,
    angle_min: float,
    increment: float,
    count: int,
    turn: int,
    range_min_squared: float,
    range_max_squared: float,
    slots: Any,
    values: Any,
) -> None:
    """Of the kept points, the slot (-1: outside the range limits or the grid) and the
    squared range (float32) in the moved LiDAR frame."""
    a0, a1, a2, a3 = plane[0, 0], plane[0, 1], plane[0, 2], plane[0, 3]
    b0, b1, b2, b3 = plane[1, 0], plane[1, 1], plane[1, 2], plane[1, 3]
    whole = np.float64(turn)
    slots_on_grid = np.float64(count)
    for j in range(kept):
        px, py, pz = xs[j], ys[j], zs[j]
        x = a0 * px + a1 * py + a2 * pz + a3
        y = b0 * px + b1 * py + b2 * pz + b3
        r2 = x * x + y * y
        # bearing.fast_atan2, with selects for its branches
        ax, ay = abs(x), abs(y)
        big = max(ax, ay)
        small = min(ay, ax)
        a = small / big
        a_2 = a * a
        angle = ((-0.0464964749 * a_2 + 0.15931422) * a_2 - 0.327622764) * a_2 * a + a
        angle = HALF_PI - angle if ay > ax else angle
        angle = math.pi - angle if x < 0.0 else angle
        angle = -angle if y < 0.0 else angle
        angle = 0.0 if big == 0.0 else angle
        slot = np.floor((angle - angle_min) / increment + 0.5)
        slot = slot + whole if slot < 0.0 else slot
        slot = slot - whole if slot >= whole else slot
        inside = (
            (r2 >= range_min_squared)
            & (r2 <= range_max_squared)
            & (r2 != 0.0)
            & (slot >= 0.0)
            & (slot < slots_on_grid)
        )
        slots[j] = np.int64(slot if inside else -1.0)
        values[j] = np.float32(r2)


def _insert(nearest: Any, slot: int, value: np.float32) -> None:
    """`value` into the ascending row `slot` of `nearest`, its last dropped: entry j becomes
    min(row[j], max(row[j - 1], value)), no data-dependent branch."""
    k = nearest.shape[1]
    for j in range(k - 1, 0, -1):
        before = nearest[slot, j - 1]
        higher = max(value, before)
        here = nearest[slot, j]
        nearest[slot, j] = min(higher, here)
    first = nearest[slot, 0]
    nearest[slot, 0] = min(value, first)


def _insert16(nearest: Any, slot: int, value: np.float32) -> None:
    """`_insert` for rows of 16."""
    for j in range(15, 0, -1):
        nearest[slot, j] = min(max(value, nearest[slot, j - 1]), nearest[slot, j])
    nearest[slot, 0] = min(value, nearest[slot, 0])


def _pick(nearest: Any, spread: float, ranges: Any) -> None:
    """Per slot the range of the farthest of its k nearest within spread r^2 of the nearest
    (NaN: no point): `obstacle._cluster_range_squared` and the square root, the same float64
    arithmetic; the entries within are counted as numpy sums them."""
    count, k = nearest.shape
    for s in range(min(count, ranges.size)):
        first = np.float64(nearest[s, 0])
        root = math.sqrt(first) + spread * first
        limit = root * root
        within = 0
        for j in range(k):
            within += nearest[s, j] <= limit
        best = nearest[s, max(within - 1, 0)]
        ranges[s] = np.sqrt(best) if np.isfinite(best) else np.float32(np.nan)


in_slab = compiled(_in_slab, error_model='numpy')
in_slab_packed = compiled(_in_slab_packed, error_model='numpy')
gather = compiled(_gather)
slot_of = compiled(_slot, error_model='numpy')
insert = compiled(_insert)
insert16 = compiled(_insert16)
pick = compiled(_pick)


def _cloud_ranges(
    points: Any,
    packed: Any,
    width: int,
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
    k: int,
    spread: float,
) -> Any:
    """The ranges (float32, `count`) of the points (N x 3, sensor frame) binned as
    `cloud._nearest_loop` bins them, reported as `cloud.points_scan` reports them.

    `packed`: the same points' values as one run, x, y, z first of every `width` (3 or 4;
    0: they are not, `packed` is not read).
    """
    nearest = np.full((count, max(k, 1)), np.inf, dtype=np.float32)
    last = nearest.shape[1] - 1
    xs = np.empty(BLOCK)
    ys = np.empty(BLOCK)
    zs = np.empty(BLOCK)
    index = np.empty(BLOCK, dtype=np.int64)
    slots = np.empty(BLOCK, dtype=np.int64)
    values = np.empty(BLOCK, dtype=np.float32)
    flags = np.empty(BLOCK, dtype=np.uint8)
    spare = np.empty(BLOCK)
    total = points.shape[0]
    packed_end = total - 1 if width == 4 else total if width == 3 else 0
    # Last block first: an organized cloud's last rows are the bottom of the image, nearest
    # for a camera looking ahead and down, so the k nearest fill with near points early and
    # later, farther ones fail the k-th test (benchmark organized cloud: 20 127 -> 13 081
    # insertions). The k smallest do not depend on the order.
    for block in range((total + BLOCK - 1) // BLOCK - 1, -1, -1):
        start = block * BLOCK
        size = min(BLOCK, total - start)
        if start + size <= packed_end:
            kept = in_slab_packed(
                packed, width, start, size, height_row, low, high, flags, spare, index
            )
        else:
            kept = in_slab(points, start, size, height_row, low, high, index)
        gather(points, index, kept, xs, ys, zs)
        slot_of(
            xs, ys, zs, kept, plane, angle_min, increment, count, turn,
            range_min_squared, range_max_squared, slots, values,
        )  # fmt: skip
        for j in range(kept):
            slot = slots[j]
            if 0 <= slot < count and values[j] < nearest[slot, last]:
                if last == 15:
                    insert16(nearest, slot, values[j])
                else:
                    insert(nearest, slot, values[j])
    ranges = np.empty(count, dtype=np.float32)
    pick(nearest, spread, ranges)
    return ranges


cloud_ranges = compiled(_cloud_ranges)
