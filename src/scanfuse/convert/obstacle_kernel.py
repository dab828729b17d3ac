"""The compiled (numba) obstacle kernel: per LiDAR slot the k nearest points in the slab.

Importing this module needs numba; `scanfuse.convert.obstacle` falls back to its numpy
reference without it. The arithmetic of every point is the reference's
(`obstacle._nearest_squared_numpy`): float32 points, moved by the motion, float64
pseudo-angles against the same slot tables, so both give the same scan bit for bit.
What differs is only which points are looked at, and in which order:

- Each image row is cut into blocks. Most blocks (the floor, what is above the slab) hold
  no depth inside the block's widest interval [least lo, greatest hi], a test that reads
  the image alone. In the others, a vectorised pass (no branches, so the noisy speckle of
  floor pixels around the slab's bottom costs no mispredictions) tests every pixel
  against its own [lo, hi] and, for the kept ones, computes the point, its squared range
  and its pseudo-angle bin.
- A point can only change a slot's k nearest when it is nearer than the slot's k-th.
  Every bin keeps an upper bound of the k-th of the slots it touches, so the exact slot
  lookup and the insertion only run for points nearer than their bin's bound (gathered
  first, without branches): after the first rows of a wall, a few per cent of its points.
- Rows go in an order the projector chose (nearest typical range first), so the k nearest
  fill early with near points and the bounds tighten sooner. The k smallest of a set do
  not depend on the order in which it is visited, so neither does the output.
- Each row is read only over its span of columns (`row_spans`): the tiles whose points,
  moved by the frame's motion, can land on the grid. A fragment of a revolution (issue 12:
  a PSENscan's six 60-degree messages, each fused on its own) thus reads only the part
  of the image that can land in it; a pixel left out holds no point of any slot.
- `nearest_squared_parallel` splits the columns into bands, one per thread, each with its
  own k nearest, and merges them per slot (k smallest of the parts' k smallest).
- Drop-offs (the module docstring of `obstacle`): a pixel whose depth lies in its drop
  interval [drop_lo, top] is the point at its floor crossing depth, kept in rows count + slot of
  `nearest` (and bins + bin of `bound`): the slab's and the drops' k nearest side by side,
  so one insertion serves both. With drops off `_accumulate_plain` (the loops as they were
  before drops, compiled on their own) runs; with drops on, a block without a drop
  candidate takes the plain pass and insertion (benchmark: drops on / off 1.04-1.07 on the
  realistic room, uint16).

Every index is checked against the arrays it reads, and a point whose coordinates are not
finite (a translation beyond float32 range, NaN in the motion) is dropped before it could
reach an index: the kernel reads only inside its arrays whatever it is given.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from scanfuse.compiled import compiled

# Pixels per block of the vectorised pass: long enough for the vector loop to pay,
# short enough that its scratch stays in L1 and floor blocks are skipped.
BLOCK = 256
_F32_BELOW_MAX = 3.0e38


def _pick(nearest: Any, spread: float, best: Any, drops: Any) -> None:
    """Per slot the farthest of its k nearest within spread r^2 of the nearest (r its range),
    or the nearest drop crossing when the slot holds k drop points and it is nearer.

    `obstacle._pick` (`_cluster_range_squared`), the same float64 arithmetic, slot by slot;
    rows count + s of `nearest` are slot s's drop points.
    """
    k = nearest.shape[1]
    count = min(best.size, drops.size, nearest.shape[0] // 2)
    for s in range(count):
        first = np.float64(nearest[s, 0])
        root = math.sqrt(first) + spread * first
        limit = root * root
        last = 0
        for j in range(1, k):
            if nearest[s, j] <= limit:
                last = j
        slab = nearest[s, last]
        drop_first = nearest[count + s, 0]
        is_drop = nearest[count + s, k - 1] < np.inf and drop_first < slab
        best[s] = drop_first if is_drop else slab
        drops[s] = is_drop


def _row_blocks(row: int, width: int, columns: Any, spans: Any) -> tuple[int, int, int, int]:
    """Where row `row` is read within the band `columns` [start, stop, first block]: only its
    span of columns whose points can land on the grid (`row_spans`). (row start, row stop) as
    flat pixel indices, then the flat start and the index of the band's block holding the
    span's start: the blocks stay where `block_lo` has them, each cut to the span (its
    extremes still bound the pixels left)."""
    column_start = max(columns[0], 0)
    span_start = max(column_start, spans[row, 0])
    row_start = row * width + span_start
    row_stop = row * width + min(columns[1], width, spans[row, 1])
    skipped = (span_start - column_start) // BLOCK
    return row_start, row_stop, row * width + column_start + skipped * BLOCK, columns[2] + skipped


def _accumulate(
    depth: Any,
    lo: Any,
    hi: Any,
    a_x: Any,
    a_y: Any,
    drop_lo: Any,
    top: Any,
    floor: Any,
    b_x: np.float32,
    b_y: np.float32,
    m_cos: np.float32,
    m_sin: np.float32,
    m_tx: np.float32,
    m_ty: np.float32,
    rows: Any,
    width: int,
    columns: Any,
    spans: Any,
    block_lo: Any,
    block_hi: Any,
    block_drop_lo: Any,
    with_drops: bool,
    scale: float,
    first: Any,
    second: Any,
    before: Any,
    middle: Any,
    after: Any,
    nearest: Any,
    bound: Any,
) -> None:
    """Insert the kept points of `rows` (image row indices, in this order), columns
    [columns[0], columns[1]) of each within the row's span [spans[row, 0], spans[row, 1]),
    into `nearest`.

    The band's blocks (BLOCK pixels from columns[0] on) are blocks columns[2], ... of
    each row in `block_lo`, `block_hi` (rows x blocks): the least lo and greatest hi of
    their pixels, so a block whose depths are all outside is skipped reading the image
    alone; so does `block_drop_lo` (least drop_lo) for the drop intervals [drop_lo, top].
    Without `with_drops` the loops are the plain slab's (drop_lo, floor are not read).

    `nearest` (2 slots x k) holds each slot's k smallest squared ranges, ascending, Inf where
    fewer, of its slab points (row slot) and of its drop points (row slots + slot); `bound`
    (2 x one per pseudo-angle bin, the same way) an upper bound of the k-th of every slot the
    bin touches (-Inf for a bin without a slot). Both are updated in place.
    """
    k = nearest.shape[1]
    count = nearest.shape[0] // 2
    bins = min(first.size, second.size, before.size, middle.size, after.size)
    bins = min(bins, bound.size // 2)
    last_bin = bins - 1
    size = min(depth.size, lo.size, hi.size, a_x.size, a_y.size)
    if with_drops:
        size = min(size, drop_lo.size, floor.size)
    pseudo_of = np.empty(BLOCK, np.float64)
    # A point's bin, plus `bins` for a drop point: its entry in `bound`.
    bin_of = np.empty(BLOCK, np.int64)
    squared = np.empty(BLOCK, np.float32)
    chosen = np.empty(BLOCK, np.int64)
    block_rows = min(block_lo.shape[0], block_hi.shape[0], block_drop_lo.shape[0])
    block_rows = min(block_rows, spans.shape[0])
    blocks = min(block_lo.shape[1], block_hi.shape[1], block_drop_lo.shape[1])
    for row in rows:
        if not 0 <= row < block_rows:
            continue
        row_start, row_stop, first_start, block = row_blocks(row, width, columns, spans)
        if not row_start < row_stop <= size:
            continue
        for block_start in range(first_start, row_stop, BLOCK):
            start = max(block_start, row_start)
            stop = min(block_start + BLOCK, row_stop)
            if not 0 <= block < blocks:
                break
            least, greatest = block_lo[row, block], block_hi[row, block]
            drop_least = block_drop_lo[row, block]
            block += 1
            # Slices, so the loops below index from 0 and compile without wraparound checks.
            z_block = depth[start:stop]
            n = z_block.size
            near_slab = 0
            near_drop = 0
            if with_drops:
                for i in range(n):
                    z = z_block[i]
                    near_slab += (z >= least) & (z <= greatest)
                    # Every drop interval ends at `top`: only its start is tested here.
                    near_drop += z >= drop_least
            else:
                for i in range(n):
                    z = z_block[i]
                    near_slab += (z >= least) & (z <= greatest)
            if near_slab == 0 and near_drop == 0:
                continue
            # Sliced only here: slicing costs, and most blocks are skipped above.
            lo_block = lo[start:stop]
            hi_block = hi[start:stop]
            ax_block = a_x[start:stop]
            ay_block = a_y[start:stop]
            # Two copies of the pass: with drops only for a block that may hold one, so a
            # block of the slab alone (a wall, the floor's speckle) costs what it did.
            if near_drop > 0:
                drop_lo_block = drop_lo[start:stop]
                floor_block = floor[start:stop]
                for i in range(n):
                    z = z_block[i]
                    in_slab = (z >= lo_block[i]) & (z <= hi_block[i])
                    drop = (z >= drop_lo_block[i]) & (z <= top) & (not in_slab)
                    # A drop pixel is the point where its line of sight crosses the floor
                    # (NaN for a pixel that cannot see a drop: dropped below as not finite).
                    z32 = floor_block[i] if drop else np.float32(z)
                    x_seen = ax_block[i] * z32 + b_x
                    y_seen = ay_block[i] * z32 + b_y
                    # Motion compensation (identity: x_seen, y_seen up to the sign of zero).
                    x = m_cos * x_seen - m_sin * y_seen + m_tx
                    y = m_sin * x_seen + m_cos * y_seen + m_ty
                    x64 = np.float64(x)
                    y64 = np.float64(y)
                    norm = abs(x64) + abs(y64)
                    # Not finite (inf, NaN) or at the origin: no direction, never indexed.
                    good = (in_slab | drop) & (norm > 0.0) & (norm < np.inf)
                    ratio = x64 / (norm if good else 1.0)
                    pseudo = (1.0 - ratio if y64 >= 0.0 else 3.0 + ratio) if good else 0.0
                    pseudo_of[i] = pseudo
                    bin_of[i] = min(np.int64(pseudo * scale), last_bin) + bins * np.int64(drop)
                    squared[i] = x * x + y * y if good else np.float32(np.inf)
            else:
                for i in range(n):
                    z = z_block[i]
                    keep = (z >= lo_block[i]) & (z <= hi_block[i])
                    z32 = np.float32(z)
                    x_seen = ax_block[i] * z32 + b_x
                    y_seen = ay_block[i] * z32 + b_y
                    x = m_cos * x_seen - m_sin * y_seen + m_tx
                    y = m_sin * x_seen + m_cos * y_seen + m_ty
                    x64 = np.float64(x)
                    y64 = np.float64(y)
                    norm = abs(x64) + abs(y64)
                    good = keep & (norm > 0.0) & (norm < np.inf)
                    ratio = x64 / (norm if good else 1.0)
                    pseudo = (1.0 - ratio if y64 >= 0.0 else 3.0 + ratio) if good else 0.0
                    pseudo_of[i] = pseudo
                    bin_of[i] = min(np.int64(pseudo * scale), last_bin)
                    squared[i] = x * x + y * y if good else np.float32(np.inf)
            # The candidates, nearer than their bin's bound as the block starts (bounds only
            # fall, so this keeps every point the exact test below would): compacted without
            # a branch, as speckle makes them unpredictable.
            found = 0
            for i in range(n):
                chosen[found] = i
                found += squared[i] < bound[bin_of[i]]
            if near_drop == 0:
                # Slab points only: the plain insertion (`_accumulate_plain`'s).
                for c in range(found):
                    i = chosen[c]
                    r2 = squared[i]
                    index = bin_of[i]
                    pseudo = pseudo_of[i]
                    if pseudo >= second[index]:
                        slot = after[index]
                    elif pseudo >= first[index]:
                        slot = middle[index]
                    else:
                        slot = before[index]
                    if 0 <= slot < count and r2 < nearest[slot, k - 1]:
                        j = k - 1
                        while j > 0 and nearest[slot, j - 1] > r2:
                            nearest[slot, j] = nearest[slot, j - 1]
                            j -= 1
                        nearest[slot, j] = r2
                    tight = -np.inf
                    for candidate in (before[index], middle[index], after[index]):
                        if 0 <= candidate < count:
                            tight = max(tight, nearest[candidate, k - 1])
                    bound[index] = tight
                continue
            for c in range(found):
                i = chosen[c]
                r2 = squared[i]
                entry = bin_of[i]
                side = np.int64(entry >= bins)  # 1: a drop point
                index = entry - bins * side
                pseudo = pseudo_of[i]
                if pseudo >= second[index]:
                    slot = after[index]
                elif pseudo >= first[index]:
                    slot = middle[index]
                else:
                    slot = before[index]
                rows_at = count * side  # 0: the slab's rows, count: the drops'
                if 0 <= slot < count and r2 < nearest[rows_at + slot, k - 1]:
                    j = k - 1
                    while j > 0 and nearest[rows_at + slot, j - 1] > r2:
                        nearest[rows_at + slot, j] = nearest[rows_at + slot, j - 1]
                        j -= 1
                    nearest[rows_at + slot, j] = r2
                # The bin's bound is the largest k-th of its slots (-Inf for no slot).
                tight = -np.inf
                for candidate in (before[index], middle[index], after[index]):
                    if 0 <= candidate < count:
                        tight = max(tight, nearest[rows_at + candidate, k - 1])
                bound[entry] = tight


def _accumulate_plain(
    depth: Any,
    lo: Any,
    hi: Any,
    a_x: Any,
    a_y: Any,
    b_x: np.float32,
    b_y: np.float32,
    m_cos: np.float32,
    m_sin: np.float32,
    m_tx: np.float32,
    m_ty: np.float32,
    rows: Any,
    width: int,
    columns: Any,
    spans: Any,
    block_lo: Any,
    block_hi: Any,
    scale: float,
    first: Any,
    second: Any,
    before: Any,
    middle: Any,
    after: Any,
    nearest: Any,
    bound: Any,
) -> None:
    """`_accumulate` without drops, as it was before them (its own compiled loops: the same
    loops beside the drops' in one function ran 10 % slower).

    Insert the kept points of `rows` (image row indices, in this order), columns
    [columns[0], columns[1]) of each within the row's span [spans[row, 0], spans[row, 1]),
    into `nearest`.

    The band's blocks (BLOCK pixels from columns[0] on) are blocks columns[2], ... of
    each row in `block_lo`, `block_hi` (rows x blocks): the least lo and greatest hi of
    their pixels, so a block whose depths are all outside is skipped reading the image
    alone.

    `nearest` (slots x k) holds each slot's k smallest squared ranges, ascending, Inf where
    fewer; `bound` (one per pseudo-angle bin) an upper bound of the k-th of every slot the
    bin touches (-Inf for a bin without a slot). Both are updated in place.
    """
    count, k = nearest.shape
    bins = first.size
    last_bin = bins - 1
    size = min(depth.size, lo.size, hi.size, a_x.size, a_y.size)
    pseudo_of = np.empty(BLOCK, np.float64)
    bin_of = np.empty(BLOCK, np.int64)
    squared = np.empty(BLOCK, np.float32)
    chosen = np.empty(BLOCK, np.int64)
    block_rows, blocks = block_lo.shape
    block_rows = min(block_rows, spans.shape[0])
    for row in rows:
        if not 0 <= row < block_rows:
            continue
        row_start, row_stop, first_start, block = row_blocks(row, width, columns, spans)
        if not row_start < row_stop <= size:
            continue
        for block_start in range(first_start, row_stop, BLOCK):
            start = max(block_start, row_start)
            stop = min(block_start + BLOCK, row_stop)
            if not 0 <= block < blocks:
                break
            least, greatest = block_lo[row, block], block_hi[row, block]
            block += 1
            # Slices, so the loops below index from 0 and compile without wraparound checks.
            z_block = depth[start:stop]
            n = z_block.size
            near_slab = 0
            for i in range(n):
                z = z_block[i]
                near_slab += (z >= least) & (z <= greatest)
            if near_slab == 0:
                continue
            lo_block = lo[start:stop]
            hi_block = hi[start:stop]
            ax_block = a_x[start:stop]
            ay_block = a_y[start:stop]
            for i in range(n):
                z = z_block[i]
                keep = (z >= lo_block[i]) & (z <= hi_block[i])
                z32 = np.float32(z)
                x_seen = ax_block[i] * z32 + b_x
                y_seen = ay_block[i] * z32 + b_y
                # Motion compensation (identity: x_seen, y_seen up to the sign of zero).
                x = m_cos * x_seen - m_sin * y_seen + m_tx
                y = m_sin * x_seen + m_cos * y_seen + m_ty
                x64 = np.float64(x)
                y64 = np.float64(y)
                norm = abs(x64) + abs(y64)
                # Not finite (inf, NaN) or at the origin: no direction, never indexed.
                good = keep & (norm > 0.0) & (norm < np.inf)
                ratio = x64 / (norm if good else 1.0)
                pseudo = (1.0 - ratio if y64 >= 0.0 else 3.0 + ratio) if good else 0.0
                pseudo_of[i] = pseudo
                bin_of[i] = min(np.int64(pseudo * scale), last_bin)
                squared[i] = x * x + y * y if good else np.float32(np.inf)
            # The candidates, nearer than their bin's bound as the block starts (bounds only
            # fall, so this keeps every point the exact test below would): compacted without
            # a branch, as speckle makes them unpredictable.
            found = 0
            for i in range(n):
                chosen[found] = i
                found += squared[i] < bound[bin_of[i]]
            for c in range(found):
                i = chosen[c]
                r2 = squared[i]
                index = bin_of[i]
                pseudo = pseudo_of[i]
                if pseudo >= second[index]:
                    slot = after[index]
                elif pseudo >= first[index]:
                    slot = middle[index]
                else:
                    slot = before[index]
                if 0 <= slot < count and r2 < nearest[slot, k - 1]:
                    j = k - 1
                    while j > 0 and nearest[slot, j - 1] > r2:
                        nearest[slot, j] = nearest[slot, j - 1]
                        j -= 1
                    nearest[slot, j] = r2
                # The bin's bound is the largest k-th of its slots (-Inf for no slot).
                tight = -np.inf
                for candidate in (before[index], middle[index], after[index]):
                    if 0 <= candidate < count:
                        tight = max(tight, nearest[candidate, k - 1])
                bound[index] = tight


def _reset(nearest: Any, bound: Any, before: Any, middle: Any, after: Any) -> None:
    """Every slot empty (Inf); a bin's bound Inf when it touches a slot, else -Inf.

    `nearest` and `bound` hold the slab's rows and bins, then the drops' (`_accumulate`).
    """
    count = nearest.shape[0] // 2
    bins = min(bound.size // 2, before.size, middle.size, after.size)
    nearest[:] = np.inf
    bound[:] = -np.inf
    for index in range(bins):
        touches = (
            0 <= before[index] < count or 0 <= middle[index] < count or 0 <= after[index] < count
        )
        bound[index] = bound[bins + index] = np.inf if touches else -np.inf


def _merge(into: Any, other: Any) -> None:
    """`into` (slots x k, ascending rows) becomes the k smallest of `into` and `other`."""
    count, k = into.shape
    for s in range(count):
        for value in other[s]:
            if not value < into[s, k - 1]:
                break  # rows are ascending: the rest are not smaller either
            j = k - 1
            while j > 0 and into[s, j - 1] > value:
                into[s, j] = into[s, j - 1]
                j -= 1
            into[s, j] = value


def _seen_slots(
    depth: Any,
    centres: Any,
    low: Any,
    high: Any,
    starts: Any,
    ends: Any,
    seen: Any,
) -> None:
    """`ViewCoverage.seen` of the tiles whose centre pixel is in [low, high].

    `depth` is the flattened image, `centres` the centre pixel (flat index) of each run's
    tile: `seen` gets the slots inside a run [start, end) of a tile with a valid centre.
    Only the centres of tiles with a run are read: on a fragment of a revolution, those of
    the part of the image that covers it.
    """
    count = seen.size
    marks = np.zeros(count + 1, np.int64)
    for piece in range(min(centres.size, starts.size, ends.size)):
        centre = centres[piece]
        if not 0 <= centre < depth.size:
            continue
        z = depth[centre]
        if (z >= low) & (z <= high):
            start, end = starts[piece], ends[piece]
            if 0 <= start <= count and 0 <= end <= count:
                marks[start] += 1
                marks[end] -= 1
    running = 0
    for s in range(count):
        running += marks[s]
        seen[s] = running > 0


def _row_spans(
    after: Any, before: Any, turn: float, margin: float, tile: int, width: int, spans: Any
) -> None:
    """Per image row the columns [start, stop) of the tiles (tile x tile pixels; `after`,
    `before`: tile rows x tile columns) whose arcs may meet the grid, and what lies between.

    `after`, `before` are each tile's slots past the grid's end and short of its start
    (`obstacle._tile_gaps`); the frame's motion turns the arcs by `turn` slots and widens
    them by `margin`: a tile with after + turn > margin and before - turn > margin holds no
    point of the grid. An empty span (start = stop = 0) where no tile of the row is left.
    """
    tiles_down = min(after.shape[0], before.shape[0])
    tiles_across = min(after.shape[1], before.shape[1])
    for row in range(spans.shape[0]):
        spans[row, 0] = 0
        spans[row, 1] = 0
    for down in range(tiles_down):
        first = tiles_across
        for across in range(tiles_across):
            if min(after[down, across] + turn, before[down, across] - turn) <= margin:
                first = across
                break
        if first == tiles_across:
            continue
        last = first
        for across in range(tiles_across - 1, first, -1):
            if min(after[down, across] + turn, before[down, across] - turn) <= margin:
                last = across
                break
        start = min(first * tile, width)
        stop = min((last + 1) * tile, width)
        for row in range(down * tile, min((down + 1) * tile, spans.shape[0])):
            spans[row, 0] = start
            spans[row, 1] = stop


row_spans = compiled(_row_spans)
row_blocks = compiled(_row_blocks)
seen_slots = compiled(_seen_slots)
pick = compiled(_pick)
accumulate = compiled(_accumulate)
accumulate_plain = compiled(_accumulate_plain)
reset = compiled(_reset)
merge = compiled(_merge)


def _nearest_squared(
    depth: Any,
    lo: Any,
    hi: Any,
    a_x: Any,
    a_y: Any,
    drop_lo: Any,
    top: Any,
    floor: Any,
    b_x: np.float32,
    b_y: np.float32,
    m_cos: np.float32,
    m_sin: np.float32,
    m_tx: np.float32,
    m_ty: np.float32,
    rows: Any,
    width: int,
    spans: Any,
    block_lo: Any,
    block_hi: Any,
    block_drop_lo: Any,
    with_drops: bool,
    scale: float,
    first: Any,
    second: Any,
    before: Any,
    middle: Any,
    after: Any,
    spread: float,
    nearest: Any,
    bound: Any,
    best: Any,
    drops: Any,
) -> None:
    """One thread: fill `nearest` (2 slots x k), `best` (the reported squared range) and
    `drops` (the slots whose range is a drop's edge) from each row's span of columns
    (`spans`, rows x 2: [start, stop), `row_spans`)."""
    reset(nearest, bound, before, middle, after)
    every = np.array([0, width, 0])
    if with_drops:
        accumulate(
            depth, lo, hi, a_x, a_y, drop_lo, top, floor, b_x, b_y, m_cos, m_sin, m_tx, m_ty,
            rows, width, every, spans, block_lo, block_hi, block_drop_lo, with_drops, scale,
            first, second, before, middle, after, nearest, bound,
        )  # fmt: skip
    else:
        accumulate_plain(
            depth, lo, hi, a_x, a_y, b_x, b_y, m_cos, m_sin, m_tx, m_ty, rows, width, every,
            spans, block_lo, block_hi, scale, first, second, before, middle, after, nearest,
            bound,
        )  # fmt: skip
    pick(nearest, spread, best, drops)


def _nearest_squared_parallel(
    depth: Any,
    lo: Any,
    hi: Any,
    a_x: Any,
    a_y: Any,
    drop_lo: Any,
    top: Any,
    floor: Any,
    b_x: np.float32,
    b_y: np.float32,
    m_cos: np.float32,
    m_sin: np.float32,
    m_tx: np.float32,
    m_ty: np.float32,
    rows: Any,
    width: int,
    spans: Any,
    parts: Any,
    block_lo: Any,
    block_hi: Any,
    block_drop_lo: Any,
    with_drops: bool,
    scale: float,
    first: Any,
    second: Any,
    before: Any,
    middle: Any,
    after: Any,
    spread: float,
    nearest: Any,
    bound: Any,
    best: Any,
    drops: Any,
) -> None:
    """`nearest_squared` with columns [parts[p, 0], parts[p, 1]) of every row (within its
    span) on thread p (their blocks from parts[p, 2] on).

    Columns, not rows: a column band sees its own range of directions, hence mostly its
    own slots, so the parts do not each insert the same slots' points (as row bands
    would: their k nearest fill separately). `nearest` and `bound` have one leading entry
    per part; part 0 gets the merged result.
    """
    for p in numba.prange(parts.shape[0]):
        reset(nearest[p], bound[p], before, middle, after)
        if with_drops:
            accumulate(
                depth, lo, hi, a_x, a_y, drop_lo, top, floor, b_x, b_y, m_cos, m_sin, m_tx,
                m_ty, rows, width, parts[p], spans, block_lo, block_hi, block_drop_lo,
                with_drops, scale, first, second, before, middle, after, nearest[p], bound[p],
            )  # fmt: skip
        else:
            accumulate_plain(
                depth, lo, hi, a_x, a_y, b_x, b_y, m_cos, m_sin, m_tx, m_ty, rows, width,
                parts[p], spans, block_lo, block_hi, scale, first, second, before, middle,
                after, nearest[p], bound[p],
            )  # fmt: skip
    for p in range(1, parts.shape[0]):
        merge(nearest[0], nearest[p])
    pick(nearest[0], spread, best, drops)


nearest_squared = compiled(_nearest_squared)
nearest_squared_parallel = compiled(_nearest_squared_parallel, parallel=True)
