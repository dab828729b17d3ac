"""Height-filtered full-frame obstacle scan: every depth pixel, kept inside the collision slab.

Beyond the paper (which converts one image row): each pixel becomes a 3D point
in the base frame; points whose height above the floor (base z = 0) lies in
[min_obstacle_height, max_obstacle_height] are obstacles; they are binned by
their direction seen from the LiDAR's origin into the LiDAR's own slots, and a
near horizontal range per slot is reported: of the slot's k nearest points
(k = `min_points`), the farthest within c r^2 of the nearest one, r its range
(c = `cluster_spread`). k = 1 is the plain nearest point.

Why not the nearest: a slot on a wall gathers tens of pixels, and stereo depth
noise grows as Z^2 (sigma about 0.01 Z^2 on a RealSense D435). The minimum of n
noisy samples of one surface lies about 2 sigma short for n of a few tens: 0.15 m
for a wall at 2.5 m, beyond a 0.05 m + 2 % tolerance. The k-th nearest lies near
the k/n quantile instead (0.7 sigma short for k = 16 of 65). But a thin or low
obstacle (an 18 mm board, a cable tray 1 cm into the slab) gives a slot only a few
points, often in front of a wall: the plain k-th nearest would report the wall
behind it. So the k nearest count only as far as noise could have spread one
surface's points, a window that grows as r^2 as the noise does; a slot with fewer
points, or a gap behind its nearest ones, keeps its near cluster.

All geometry that does not depend on the depth values is folded into per-pixel
tables when the projector is built. A pixel with ray (x_n, y_n, 1) and depth Z
(along the optical axis) is at

    height = a_z Z + b_z,   x_laser = a_x Z + b_x,   y_laser = a_y Z + b_y

so the height test and the range limits on Z together become one interval
lo <= Z <= hi per pixel, and per frame only two compares per pixel remain, plus
two multiply-adds, a slot lookup and an insertion into the slot's k nearest for the
pixels that pass.

Drop-offs (`detect_drops`: stairs going down, ledges, holes in the floor; issue 15). A
pixel whose ray goes down (a_z < 0) would see the floor at Z0 = -b_z / a_z. A depth
beyond Z0 + margin puts its point below the floor, where the robot cannot drive: such
a pixel reports not its own point but the point where its line of sight crosses the
floor plane (x, y at Z0, per pixel in the tables), as the near edge of the drop is no
farther than that, so the robot stops before the edge. The margin is the largest of

- drop_min_depth / -a_z: the point lies more than `drop_min_depth` below the floor
  (this also absorbs errors of the floor plane: a mounting 2 cm off moves the floor by
  2 cm);
- drop_min_width / h, h the horizontal distance the ray travels per unit of Z: the ray
  runs at least `drop_min_width` beyond the floor's edge, so a hole or gap shorter than
  that along the line of sight (a round hole narrower than it, always) is ignored;
- DROP_NOISE_SIGMAS * depth_noise * Z0^2: the camera's noise (sigma = depth_noise Z^2)
  cannot carry a reading of the floor itself that far (6 sigma: about 1e-9 of the
  readings of a Gaussian floor), so flat floors give no drops.

Z0 must lie within [range_min, range_max] (the floor would be seen there); the reading
itself may lie beyond range_max (a deep drop seen from above), but must be a finite
measurement: missing returns (0, NaN: black or shiny floors, out of range, REP-118 +Inf)
are never drops, as a camera loses the floor that way without any drop-off. A mirror or
a glossy floor reflecting the room behind the floor plane does read as a drop.

Drop points go into their own k nearest per slot: a slot is a drop when it holds at
least `min_points` of them (so isolated noisy pixels never make one) and then reports
the nearest crossing (noise-free: the geometry of the pixel, not its depth), unless the
slab's estimate of the slot is nearer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.camera import MILLIMETRE
from scanfuse.convert import height_kernel
from scanfuse.convert.ground import GroundPlane, GroundProfile, Lifts
from scanfuse.errors import InputError
from scanfuse.motion import IDENTITY_MOTION, PlanarMotion
from scanfuse.scan import TWO_PI, AngleGrid, Scan, to_rep117

if TYPE_CHECKING:
    from types import ModuleType

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.transforms import Extrinsics

    F32 = npt.NDArray[np.float32]
    F64 = npt.NDArray[np.float64]
    Mask = npt.NDArray[np.bool_]

# A ray this close to horizontal keeps one height whatever its depth.
_LEVEL_RAY = 1e-12
# uint16 millimetre limits are rounded towards inclusion by this much.
_MM_ROUNDING = 1e-6
UINT16_MAX = 65535
# The slot lookup has 16 / angle_increment bins of 28 bytes (7.3 MB at this limit): the
# finest real 2D LiDARs read every 0.01-0.1 deg (36 000 - 3600 a turn), this allows 103 000.
FINEST_INCREMENT = 16.0 / (1 << 18)
# A new ground plane rebuilds the height tables only when some height within range_max of
# the camera moves by more than this (metres): a 0.1 deg change at 3 m. Below, the scan is
# the old plane's (a steady estimate costs nothing).
GROUND_TOLERANCE = 0.005
# Most threads `ObstacleProjector` splits a frame over.
MAX_THREADS = 64
# A drop needs a reading this many noise sigmas (depth_noise Z0^2) behind the floor: a
# Gaussian floor reading goes this far once in 1e9 (and a slot needs min_points of them).
DROP_NOISE_SIGMAS = 6.0
# The upper end of every drop interval: any finite reading (uint16 has no infinity).
_DROP_TOP = {
    np.dtype(np.uint16): np.uint16(np.iinfo(np.uint16).max),
    np.dtype(np.float32): np.finfo(np.float32).max,
}


def _pseudo_angle(x: F64, y: F64) -> F64:
    """A value in [0, 4] that grows with the angle atan2(y, x) over [0, 2 pi) ("diamond angle").

    Monotone in the true angle, but a division instead of an atan2; NaN at (0, 0).
    """
    with np.errstate(invalid='ignore', divide='ignore'):
        ratio = x / (np.abs(x) + np.abs(y))
    pseudo: F64 = np.where(y >= 0.0, 1.0 - ratio, 3.0 + ratio)
    return pseudo


def _angle_of_pseudo(pseudo: F64) -> F64:
    """The inverse of `_pseudo_angle`: the angle whose pseudo-angle is `pseudo`."""
    upper = pseudo <= 2.0
    x = np.where(upper, 1.0 - pseudo, pseudo - 3.0)
    y = 1.0 - np.abs(x)
    angle: F64 = np.arctan2(np.where(upper, y, -y), x)
    return angle


@dataclass(frozen=True)
class SlotLookup:
    """`AngleGrid.slot_of` for points (x, y) without an atan2, for the per-pixel hot loop.

    The pseudo-angle range [0, 4) is cut into `bins` equal bins, fine enough that
    one bin holds at most two slot boundaries (one, or the two ends of the gap of a
    grid that does not fill the turn). A bin's slot is `before`, or `middle` from
    the pseudo-angle `first` on, or `after` from `second` on (-1: no slot).
    """

    scale: float  # bins per unit of pseudo-angle
    first: F64
    second: F64
    before: npt.NDArray[np.int32]
    middle: npt.NDArray[np.int32]
    after: npt.NDArray[np.int32]

    @classmethod
    def for_grid(cls, grid: AngleGrid) -> SlotLookup:
        """The lookup of `grid`; InputError for an increment finer than `FINEST_INCREMENT`."""
        increment = abs(grid.angle_increment)
        if not increment >= FINEST_INCREMENT:
            msg = (
                f'LiDAR angle_increment {grid.angle_increment!r} rad is finer than the finest '
                f'supported {FINEST_INCREMENT:.3g} rad ({math.degrees(FINEST_INCREMENT):.2g} deg, '
                f'{math.ceil(TWO_PI / FINEST_INCREMENT)} readings per turn): the slot tables '
                'grow as 1 / angle_increment; check the LaserScan (a driver that reports the '
                'increment in degrees, or 0, is misconfigured)'
            )
            raise InputError(msg)
        # Pseudo-angle grows at least half as fast as the angle: bins of a quarter of
        # a slot's pseudo-width hold at most one regular boundary.
        bins = math.ceil(16.0 / increment)
        edges = np.arange(bins + 1, dtype=np.float64) * (4.0 / bins)
        in_turn = np.arange(grid.count + 1) * increment < TWO_PI
        boundary_angles = grid.angle_min + (np.arange(grid.count + 1)[in_turn] - 0.5) * (
            grid.angle_increment
        )
        boundaries = np.sort(_pseudo_angle(np.cos(boundary_angles), np.sin(boundary_angles)))
        start = np.searchsorted(boundaries, edges[:-1], side='left')
        stop = np.searchsorted(boundaries, edges[1:], side='left')
        if (stop - start).max(initial=0) > 2:  # pragma: no cover - excluded by the bin size
            msg = f'slot lookup bins too coarse for angle_increment {grid.angle_increment}'
            raise InputError(msg)
        padded = np.concatenate([boundaries, [np.inf, np.inf]])
        first = np.where(stop - start >= 1, padded[start], np.inf)
        second = np.where(stop - start >= 2, padded[start + 1], np.inf)
        low, high = edges[:-1], edges[1:]

        def slot_between(lower: F64, upper: F64) -> npt.NDArray[np.int32]:
            middle = 0.5 * (lower + np.minimum(upper, high))
            return grid.slot_of(_angle_of_pseudo(middle)).astype(np.int32)

        return cls(
            scale=bins / 4.0,
            first=first,
            second=second,
            before=slot_between(low, first),
            middle=slot_between(np.minimum(first, high), second),
            after=slot_between(np.minimum(second, high), high),
        )

    def slots(self, x: F64, y: F64) -> npt.NDArray[np.int32]:
        """Slot of every point (x, y); -1 outside the grid or at the origin."""
        pseudo = _pseudo_angle(x, y)
        at_origin = np.isnan(pseudo)
        pseudo[at_origin] = 0.0
        index = np.minimum((pseudo * self.scale).astype(np.int64), self.first.size - 1)
        slot = np.where(
            pseudo >= self.second[index],
            self.after[index],
            np.where(pseudo >= self.first[index], self.middle[index], self.before[index]),
        )
        slot[at_origin] = -1
        return slot


def _load_kernel() -> ModuleType | None:
    """The numba-compiled kernels, or None when numba is not installed (numpy is used then)."""
    try:
        from scanfuse.convert import obstacle_kernel  # noqa: PLC0415
    except ImportError:  # pragma: no cover - numba is a dependency; this is the fallback
        return None
    return obstacle_kernel


_KERNEL = _load_kernel()


def _nearest_squared_numpy(
    depth: npt.NDArray[Any],
    lo: npt.NDArray[Any],
    hi: npt.NDArray[Any],
    a_x: F32,
    a_y: F32,
    b_x: np.float32,
    b_y: np.float32,
    motion: tuple[np.float32, np.float32, np.float32, np.float32],
    lookup: SlotLookup,
    nearest: F32,
    drops: tuple[npt.NDArray[Any], Any, F32] | None,
) -> None:
    """The reference (and the fallback without numba): the same reduction, vectorised.

    `drops` are the start of the drop interval per pixel, its end (one for all: the
    largest finite depth) and the floor crossing depth Z0 per pixel (NaN where the pixel
    cannot see a drop); `nearest` has 2 x slots rows: the slab's points, then the drops'.
    """
    with np.errstate(invalid='ignore'):
        in_slab = (depth >= lo) & (depth <= hi)
    if drops is None:
        drop = np.zeros(depth.shape, dtype=np.bool_)
        floor: F32 = np.zeros(depth.shape, dtype=np.float32)
    else:
        drop_lo, top, floor = drops
        with np.errstate(invalid='ignore'):
            drop = (depth >= drop_lo) & (depth <= top) & ~in_slab
    keep = np.flatnonzero(in_slab | drop)
    is_drop = drop[keep]
    z = np.where(is_drop, floor[keep], depth[keep].astype(np.float32))
    x_seen = a_x[keep] * z + b_x
    y_seen = a_y[keep] * z + b_y
    m_cos, m_sin, m_tx, m_ty = motion
    x = m_cos * x_seen - m_sin * y_seen + m_tx
    y = m_sin * x_seen + m_cos * y_seen + m_ty
    slot = lookup.slots(x.astype(np.float64), y.astype(np.float64))
    inside = slot >= 0
    squared = (x * x + y * y)[inside]
    count = nearest.shape[0] // 2
    row = slot[inside] + np.int32(count) * is_drop[inside].astype(np.int32)
    nearest[:] = _smallest_per_slot(row, squared, *nearest.shape)


def _pick(nearest: F32, spread: float, best: F32, drops: Mask) -> None:
    """`best` per slot from `nearest` (2 x slots rows: slab points, then drop points).

    The slab's estimate (`_cluster_range_squared`), or the nearest drop crossing where the
    slot holds at least k drop points and it is nearer (then `drops` is True).
    """
    count, k = best.size, nearest.shape[1]
    slab = _cluster_range_squared(nearest[:count], spread)
    drop_first, drop_kth = nearest[count:, 0], nearest[count:, k - 1]
    drops[:] = (drop_kth < np.inf) & (drop_first < slab)
    best[:] = np.where(drops, drop_first, slab)


def _smallest_per_slot(slot: npt.NDArray[np.int32], squared: F32, count: int, k: int) -> F32:
    """Per slot the k smallest of `squared`, ascending (count x k; Inf where fewer).

    One sort of 64-bit keys, slot in the high half and the float's bits in the low
    half: the bits of a non-negative float32 order as the floats do.
    """
    keys = (slot.astype(np.uint64) << np.uint64(32)) | squared.view(np.uint32).astype(np.uint64)
    keys.sort()
    ordered = (keys & np.uint64(0xFFFFFFFF)).astype(np.uint32).view(np.float32)
    per_slot = np.bincount(slot, minlength=count)
    starts = np.cumsum(per_slot) - per_slot
    smallest = np.full((count, k), np.inf, dtype=np.float32)
    for rank in range(k):
        enough = per_slot > rank
        smallest[enough, rank] = ordered[starts[enough] + rank]
    return smallest


def _cluster_range_squared(nearest: F32, spread: float) -> F32:
    """Per slot the farthest of its k nearest (rows of `nearest`) within spread r^2 of the
    nearest, r the nearest's range.

    Squared ranges in and out (so spread r^2 is `spread * first`); Inf where the slot
    holds no point.
    """
    first = nearest[:, :1].astype(np.float64)
    with np.errstate(invalid='ignore'):
        limit = (np.sqrt(first) + spread * first) ** 2
        within = nearest <= limit
    # rows are ascending, so the points within are a prefix: its last is the farthest
    last = np.maximum(within.sum(axis=1) - 1, 0)
    picked: F32 = nearest[np.arange(nearest.shape[0]), last]
    return picked


def _depth_interval(
    a_z: F64,
    b_top: float | F64,
    b_bottom: float | F64,
    *,
    min_obstacle_height: float,
    max_obstacle_height: float,
    range_min: float,
    range_max: float,
    bottom_noise: float = 0.0,
) -> tuple[F64, F64]:
    """Per pixel [lo, hi] of depths Z whose point is inside the slab and the range limits.

    The point at depth Z is a_z Z + b above the ground: b = `b_top` where the line of sight
    is at the slab's top, `b_bottom` where it is at its bottom (they differ over a ramp).
    The bottom stands `bottom_noise` |a_z| Z^2 higher (`slab_noise_sigmas` sigmas of the
    reading's height: its depth's noise, `depth_noise` Z^2 along the ray, moves the point's
    height by a_z per metre of depth), so the bottom's test is
    c Z^2 - a_z Z + (min_obstacle_height - b_bottom) <= 0, c = bottom_noise |a_z|: between
    the roots. lo > hi where the pixel can never see an obstacle (its ray misses the slab).
    """
    rising = a_z > _LEVEL_RAY
    falling = a_z < -_LEVEL_RAY
    constant = min_obstacle_height - b_bottom
    with np.errstate(divide='ignore', invalid='ignore'):
        at_top = (max_obstacle_height - b_top) / a_z
        if bottom_noise > 0.0:
            curve = bottom_noise * np.abs(a_z)
            discriminant = a_z * a_z - 4.0 * curve * constant
            # The roots as q / c and constant / q: neither cancels (q has a_z's sign).
            q = 0.5 * (a_z + np.copysign(np.sqrt(np.maximum(discriminant, 0.0)), a_z))
            first, second = q / curve, constant / q
            real = discriminant >= 0.0
            bottom_lo = np.where(real, np.minimum(first, second), np.inf)
            bottom_hi = np.where(real, np.maximum(first, second), -np.inf)
        else:
            at_bottom = constant / a_z
            bottom_lo = np.where(rising, at_bottom, -np.inf)
            bottom_hi = np.where(falling, at_bottom, np.inf)
        lo = np.maximum(np.where(falling, at_top, -np.inf), bottom_lo)
        hi = np.minimum(np.where(rising, at_top, np.inf), bottom_hi)
    level_inside = (min_obstacle_height <= b_bottom) & (b_top <= max_obstacle_height)
    level = ~(rising | falling)
    lo = np.where(level, np.where(level_inside, -np.inf, np.inf), lo)
    hi = np.where(level, np.where(level_inside, np.inf, -np.inf), hi)
    lo = np.maximum(lo, range_min)
    hi = np.minimum(hi, range_max)
    no_ray = ~np.isfinite(a_z)
    lo[no_ray] = np.inf
    hi[no_ray] = -np.inf
    return lo, hi


@dataclass(frozen=True)
class DropLimits:
    """When a depth reading is a drop-off (see the module docstring); None: no drops."""

    min_depth: float  # metres below the floor plane
    min_width: float  # metres the line of sight runs beyond the floor's edge
    noise: float  # depth noise sigma = noise * Z^2 (1/m)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_depth) and self.min_depth > 0.0):
            msg = (
                f'drop_min_depth must be positive and finite (metres below the floor a point '
                f'must lie to be a drop-off), got {self.min_depth}'
            )
            raise InputError(msg)
        for name, value in (('drop_min_width', self.min_width), ('depth_noise', self.noise)):
            if not (math.isfinite(value) and value >= 0.0):
                msg = f'{name} must be finite and at least 0, got {value}'
                raise InputError(msg)


def _drop_interval(
    a_z: F64,
    b_z: float | F64,
    horizontal: F64,
    limits: DropLimits,
    range_min: float,
    range_max: float,
    lowest: F64 | None = None,
) -> tuple[F64, F64, F64]:
    """Per pixel the depths [lo, hi] that are drop-offs and the floor crossing depth Z0.

    `horizontal` is the horizontal distance the pixel's point moves per unit of Z.
    lo > hi (and Z0 NaN) where the pixel cannot see a drop: its ray does not go down, or
    meets the floor outside the range limits. `lowest`: b_z of the lowest the ground may be
    (a ramp's profile, `GroundProfile.lows`): a drop lies beyond where the ray meets it.
    """
    with np.errstate(divide='ignore', invalid='ignore'):
        floor = -b_z / a_z
        beneath = floor if lowest is None else -lowest / a_z
        possible = (a_z < -_LEVEL_RAY) & (floor >= range_min) & (floor <= range_max)
        below = limits.min_depth / -a_z
        beyond = np.where(limits.min_width > 0.0, limits.min_width / horizontal, 0.0)
    noise = DROP_NOISE_SIGMAS * limits.noise * floor * floor
    margin = np.maximum(np.maximum(below, beyond), noise)
    # Where the line of sight meets the lowest ground beyond the range, the ground may be
    # there: no drop within it.
    possible &= np.isfinite(margin) & (beneath <= range_max)
    lo = np.where(possible, np.maximum(beneath, floor) + margin, np.inf)
    hi = np.where(possible, np.inf, -np.inf)
    return lo, hi, np.where(possible, floor, np.nan)


def _millimetre_interval(lo: F64, hi: F64) -> tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint16]]:
    """[lo, hi] metres as inclusive uint16 millimetres; 0 (no measurement) never inside."""
    lo_mm = np.ceil(np.clip(lo / MILLIMETRE - _MM_ROUNDING, 1.0, UINT16_MAX))
    hi_mm = np.floor(np.clip(hi / MILLIMETRE + _MM_ROUNDING, 0.0, UINT16_MAX))
    empty = lo_mm > hi_mm
    lo_mm[empty] = UINT16_MAX
    hi_mm[empty] = 0.0
    return lo_mm.astype(np.uint16), hi_mm.astype(np.uint16)


def _mod_turn(values: F64) -> F64:
    """`np.mod(values, TWO_PI)`, bit for bit, without its slow general loop.

    Within [-TWO_PI, 2 TWO_PI) np.mod is fmod (exact) plus TWO_PI where that is negative
    (one rounding): so is this (x - TWO_PI is exact there by Sterbenz's lemma, and + 0.0
    makes -0.0 the +0.0 np.mod gives). Other values go through np.mod.
    """
    # (a select of three branches, np.where, is slower than np.mod on unordered data)
    turns = (values < 0.0).astype(np.float64) - (values >= TWO_PI)
    out: F64 = values + TWO_PI * turns
    far = (values < -TWO_PI) | (values >= 2.0 * TWO_PI)  # NaN: neither, and stays NaN
    if far.any():
        with np.errstate(invalid='ignore'):
            out[far] = np.mod(values[far], TWO_PI)
    return out


def _slot_coordinate(angle: F64, grid: AngleGrid) -> F64:
    """Angle as a continuous slot position in [0, turn): slot k covers [k, k + 1)."""
    increment = grid.angle_increment
    if increment > 0.0:
        offset = _mod_turn(angle - grid.angle_min + 0.5 * increment)
    else:
        offset = _mod_turn(-(angle - grid.angle_min) - 0.5 * increment)
    coordinate: F64 = offset / abs(increment)
    return coordinate


def _pixel_arcs(near: tuple[F64, F64], far: tuple[F64, F64], grid: AngleGrid) -> tuple[F64, F64]:
    """Slot-coordinate interval [first, last] swept by each segment near -> far.

    Each pixel sees obstacles along a segment of its ray (from its lo to its hi
    depth); seen from the LiDAR's origin the segment sweeps the shorter arc
    between its ends (a segment not through the origin subtends less than pi).
    With an off-centre camera the near end can lie far to the side of the far
    end, so both ends count, not the ray's direction alone. `first` is in
    (-turn / 2, turn), `last - first` below turn / 2; NaN where near is NaN.
    """
    near_angle = np.arctan2(near[1], near[0])
    far_angle = np.arctan2(far[1], far[0])
    sweep = _mod_turn(far_angle - near_angle + math.pi) - math.pi
    sign = 1.0 if grid.angle_increment > 0.0 else -1.0
    start = _slot_coordinate(near_angle, grid)
    end = start + sign * sweep / abs(grid.angle_increment)
    return np.minimum(start, end), np.maximum(start, end)


def _tile_arcs(
    first: F64, last: F64, shape: tuple[int, int], tile: int, turn: float
) -> tuple[F64, F64]:
    """Union [first, last] of the arcs of the pixels of each tile x tile block, row-major.

    NaN for a tile none of whose pixels can see the slab.
    """
    rows, columns = shape
    tiles_down, tiles_across = -(-rows // tile), -(-columns // tile)

    def blocks(values: F64) -> F64:
        padded = np.full((tiles_down * tile, tiles_across * tile), np.nan)
        padded[:rows, :columns] = values.reshape(shape)
        grouped: F64 = padded.reshape(tiles_down, tile, tiles_across, tile).transpose(0, 2, 1, 3)
        return grouped.reshape(tiles_down * tiles_across, tile * tile)

    first_blocks, last_blocks = blocks(first), blocks(last)
    has_arc = ~np.isnan(first_blocks)
    anchor = np.take_along_axis(first_blocks, np.argmax(has_arc, axis=1)[:, None], axis=1)
    # Move each arc by whole turns next to its tile's anchor, so no union crosses the seam.
    shift = turn * np.round((anchor - first_blocks) / turn)
    # fmin/fmax skip NaN (pixels that see nothing) and give NaN for tiles of only those.
    tile_first: F64 = np.fmin.reduce(first_blocks + shift, axis=1)
    tile_last: F64 = np.fmax.reduce(last_blocks + shift, axis=1)
    return tile_first, tile_last


def _segment_reach(near: tuple[F64, F64], far: tuple[F64, F64]) -> float:
    """The least distance from the origin to any pixel's segment near -> far (inf: none)."""
    dx, dy = far[0] - near[0], far[1] - near[1]
    with np.errstate(invalid='ignore', divide='ignore'):
        along = np.clip(-(near[0] * dx + near[1] * dy) / (dx * dx + dy * dy), 0.0, 1.0)
        along = np.where(np.isfinite(along), along, 0.0)  # a segment of one point
        reach = np.hypot(near[0] + along * dx, near[1] + along * dy)
    finite = reach[np.isfinite(reach)]
    return float(finite.min()) if finite.size else math.inf


def _arc_pieces(
    first: F64, last: F64, grid: AngleGrid
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """(owner, first slot, last slot + 1) of every arc's slot runs, arcs split at the seam."""
    turn = TWO_PI / abs(grid.angle_increment)
    owner = np.arange(first.size)
    known = ~np.isnan(first)
    first, last, owner = first[known], last[known], owner[known]
    # Bring each arc to start in [0, turn); it may then run past turn once.
    shift = turn * np.floor(first / turn)
    first, last = first - shift, last - shift
    wrapped = last >= turn
    piece_owner = np.concatenate([owner, owner[wrapped]])
    piece_first = np.concatenate([first, np.zeros(int(wrapped.sum()))])
    piece_last = np.concatenate([np.minimum(last, turn), last[wrapped] - turn])
    first_slot = np.floor(piece_first).astype(np.int64)
    last_slot = np.minimum(np.floor(piece_last).astype(np.int64), grid.count - 1)
    used = first_slot <= last_slot
    return piece_owner[used], first_slot[used], last_slot[used] + 1


def _tile_gaps(first: F64, last: F64, grid: AngleGrid) -> tuple[F64, F64]:
    """Per tile arc [first, last] (slot coordinates) how far it lies past the grid's end and
    before its start, in slots: (after, before); 0 for an arc that meets the grid.

    Around the turn an arc that misses the grid's slots [0, count) lies in the gap between
    the grid's end and its start one turn on: `after` slots past the end, `before` slots
    short of the start. Turned by d slots (d > 0 in the grid's direction) and widened by m
    slots each way it can meet the grid only when after + d <= m or before - d <= m (it
    reaches back to the end, or on to the start); a meeting arc (both 0) always passes.
    That is `_arc_pieces` of the moved arc finding a piece, up to rounding at equality.
    Inf for a tile without an arc (NaN).
    """
    turn = TWO_PI / abs(grid.angle_increment)
    known = ~np.isnan(first)
    start = np.mod(np.where(known, first, 0.0), turn)
    end = start + np.where(known, last - first, 0.0)
    misses = (start >= grid.count) & (end < turn)
    after: F64 = np.where(known, np.where(misses, start - grid.count, 0.0), np.inf)
    before: F64 = np.where(known, np.where(misses, turn - end, 0.0), np.inf)
    return after, before


def _runs_to_mask(starts: npt.NDArray[np.int64], ends: npt.NDArray[np.int64], count: int) -> Mask:
    """Slots inside any run [start, end): +1 where a run starts, -1 where it ends, summed."""
    marks = np.bincount(starts, minlength=count + 1) - np.bincount(ends, minlength=count + 1)
    mask: Mask = np.cumsum(marks[:count]) > 0
    return mask


@dataclass(frozen=True)
class ViewCoverage:
    """Which LiDAR slots the camera covers, per block of pixels (tile x tile).

    A slot is in view when some pixel's segment of sight through the collision
    slab (within the range limits) crosses it. Per frame a slot counts as seen,
    and reads +Inf when nothing is in it, when a tile covering it has valid
    depth at its centre pixel; without valid depth it stays NaN (no information).
    """

    tile: int
    rows: npt.NDArray[np.intp]
    columns: npt.NDArray[np.intp]
    owner: npt.NDArray[np.int64]
    starts: npt.NDArray[np.int64]
    ends: npt.NDArray[np.int64]
    in_view: Mask

    @staticmethod
    def tile_for(shape: tuple[int, int], tile_pixels: int = 20_000) -> int:
        """The tile side for an image of `shape`: about `tile_pixels` tiles."""
        return max(1, math.ceil(math.sqrt(shape[0] * shape[1] / tile_pixels)))

    @classmethod
    def build(
        cls,
        near: tuple[F64, F64],
        far: tuple[F64, F64],
        shape: tuple[int, int],
        grid: AngleGrid,
    ) -> ViewCoverage:
        """The coverage of the pixels' segments near -> far (flattened images of `shape`)."""
        tile = cls.tile_for(shape)
        first, last = _pixel_arcs(near, far, grid)
        turn = TWO_PI / abs(grid.angle_increment)
        return cls.from_tile_arcs(*_tile_arcs(first, last, shape, tile, turn), shape, grid, tile)

    @classmethod
    def from_tile_arcs(
        cls, tile_first: F64, tile_last: F64, shape: tuple[int, int], grid: AngleGrid, tile: int
    ) -> ViewCoverage:
        """The coverage from each tile's arc (`_tile_arcs`, tiles row-major)."""
        owner, starts, ends = _arc_pieces(tile_first, tile_last, grid)
        centre_rows = np.minimum(np.arange(0, shape[0], tile) + tile // 2, shape[0] - 1)
        centre_columns = np.minimum(np.arange(0, shape[1], tile) + tile // 2, shape[1] - 1)
        return cls(
            tile=tile,
            rows=centre_rows,
            columns=centre_columns,
            owner=owner,
            starts=starts,
            ends=ends,
            in_view=_runs_to_mask(starts, ends, grid.count),
        )

    def seen(self, valid_centres: Mask) -> Mask:
        """Slots covered by the tiles whose centre pixel holds valid depth (row-major flags)."""
        used = valid_centres.ravel()[self.owner]
        return _runs_to_mask(self.starts[used], self.ends[used], self.in_view.size)


class ObstacleProjector:
    """Depth images of one camera, mounted one way, to scans on one LiDAR grid.

    Build once (tables, field of view, compiled kernel), then call `scan` per frame: the
    constructor does all per-camera work (tens of milliseconds at 1280x720, the kernel
    loaded from numba's cache), so build it as soon as the CameraInfo is known.
    `threads` > 1 splits each frame's columns over that many threads (numba's thread
    pool); the scan is the same. The compiled kernel is `obstacle_kernel`; this module's
    numpy reduction (`reference=True`, or without numba) is its reference.
    `drops` (a `DropLimits`) also reports drop-offs (see the module docstring); None: off.
    `bottom_noise` raises the slab's bottom per pixel with its noise (`_depth_interval`).
    """

    def __init__(
        self,
        camera: CameraModel,
        extrinsics: Extrinsics,
        lidar_grid: AngleGrid,
        *,
        min_obstacle_height: float,
        max_obstacle_height: float,
        range_min: float,
        range_max: float,
        min_points: int = 1,
        cluster_spread: float = math.inf,
        use_kernel: bool = True,
        threads: int = 1,
        drops: DropLimits | None = None,
        bottom_noise: float = 0.0,
    ) -> None:
        _check_limits(min_obstacle_height, max_obstacle_height, range_min, range_max)
        if not (math.isfinite(bottom_noise) and bottom_noise >= 0.0):
            msg = (
                f'bottom_noise must be finite and at least 0 (the slab bottom rises by it '
                f'times |a_z| Z^2), got {bottom_noise}'
            )
            raise InputError(msg)
        self.bottom_noise = float(bottom_noise)
        self.min_obstacle_height = float(min_obstacle_height)
        self.max_obstacle_height = float(max_obstacle_height)
        if not 1 <= threads <= MAX_THREADS:
            msg = f'threads must be 1 to {MAX_THREADS} (1: no thread pool), got {threads}'
            raise InputError(msg)
        self.threads = int(threads)
        if min_points < 1:
            msg = f'min_points must be at least 1 (1 reports the nearest point), got {min_points}'
            raise InputError(msg)
        self.min_points = int(min_points)
        if not cluster_spread > 0.0:
            msg = (
                f'cluster_spread must be positive (the window behind the nearest point is '
                f'cluster_spread * range^2; inf: the k-th nearest point), got {cluster_spread}'
            )
            raise InputError(msg)
        self.cluster_spread = float(cluster_spread)
        self.camera = camera
        self.extrinsics = extrinsics
        self.grid = lidar_grid
        self.range_min = float(range_min)
        self.range_max = float(range_max)
        self.drops = drops
        self._kernel = _KERNEL if use_kernel else None

        shape = (camera.height, camera.width)
        pixels = shape[0] * shape[1]
        tile = ViewCoverage.tile_for(shape)
        turn = TWO_PI / abs(lidar_grid.angle_increment)
        x_table, y_table = (np.asarray(c).ravel() for c in camera.normalized_coordinates)
        base_rotation = extrinsics.base_to_camera_optical.rotation_matrix
        laser = extrinsics.laser_to_camera_optical
        rotation = laser.rotation_matrix
        b_x, b_y = laser.translation[0], laser.translation[1]
        self._b = (np.float32(b_x), np.float32(b_y))
        # lo, hi, a_x, a_y, then where the drop interval starts (it ends at the largest
        # finite depth, `_DROP_TOP`) and the floor crossing depth Z0 (NaN: cannot see drops).
        self._metres: tuple[npt.NDArray[Any], ...] = tuple(
            np.empty(pixels, dtype=np.float32) for _ in range(6)
        )
        u16, f32 = np.uint16, np.float32
        self._millimetres: tuple[npt.NDArray[Any], ...] = tuple(
            np.empty(pixels, dtype=dtype) for dtype in (u16, u16, f32, f32, u16, f32)
        )
        typical = np.empty(shape[0])
        tile_arcs: list[tuple[F64, F64]] = []
        nearest_reach = math.inf  # metres from the LiDAR's origin of the nearest possible point
        # Bands of whole tile rows, about 64k pixels each: every step below is per pixel
        # (per tile for the arcs), so banding changes no value, but the temporaries stay in
        # cache and are reused instead of faulting in fresh pages of a full-frame array each.
        band = tile * max(1, -(-65_536 // (tile * shape[1])))
        self._band = band
        self._drop_horizontal = np.empty(pixels if drops is not None else 0, dtype=np.float32)
        self.ground = GroundPlane.of_mounting(extrinsics.base_to_camera_optical)
        self.ground_refreshes = 0  # times the height tables were rebuilt for a new ground
        self._profiled = False  # the tables hold a profile's ramps, not one plane
        for top in range(0, shape[0], band):
            rows = min(band, shape[0] - top)
            part = slice(top * shape[1], (top + rows) * shape[1])
            x_n = x_table[part].astype(np.float64)
            y_n = y_table[part].astype(np.float64)
            a_x = rotation[0, 0] * x_n + rotation[0, 1] * y_n + rotation[0, 2]
            a_y = rotation[1, 0] * x_n + rotation[1, 1] * y_n + rotation[1, 2]
            if drops is not None:
                self._drop_horizontal[part] = np.hypot(
                    base_rotation[0, 0] * x_n + base_rotation[0, 1] * y_n + base_rotation[0, 2],
                    base_rotation[1, 0] * x_n + base_rotation[1, 1] * y_n + base_rotation[1, 2],
                )
            lo, hi, drop_lo, drop_hi, floor = self._height_intervals(part, x_n, y_n, self.ground)
            with np.errstate(invalid='ignore'):
                sees_slab = lo <= hi
                # A pixel that can see a drop sees up to its floor crossing.
                sees_drop = drop_lo <= drop_hi
                sight = np.where(sees_slab | sees_drop, 1.0, np.nan)
            near_z = np.where(sees_slab, lo, floor)
            far_z = np.where(sees_drop, floor, hi)
            near = ((a_x * near_z + b_x) * sight, (a_y * near_z + b_y) * sight)
            far = ((a_x * far_z + b_x) * sight, (a_y * far_z + b_y) * sight)
            first, last = _pixel_arcs(near, far, lidar_grid)
            nearest_reach = min(nearest_reach, _segment_reach(near, far))
            tile_arcs.append(_tile_arcs(first, last, (rows, shape[1]), tile, turn))
            self._metres[2][part] = a_x
            self._metres[3][part] = a_y
            self._millimetres[2][part] = a_x * MILLIMETRE
            self._millimetres[3][part] = a_y * MILLIMETRE
            self._store_heights(part, lo, hi, drop_lo, drop_hi, floor)
            typical[top : top + rows] = _row_typical(lo.reshape(rows, -1), hi.reshape(rows, -1))
        tile_first = np.concatenate([arcs[0] for arcs in tile_arcs])
        tile_last = np.concatenate([arcs[1] for arcs in tile_arcs])
        self.coverage = ViewCoverage.from_tile_arcs(tile_first, tile_last, shape, lidar_grid, tile)
        self.in_view = self.coverage.in_view
        # The centre pixel (flat index) of each run's tile, for the compiled `_seen`.
        across = self.coverage.columns.size
        self._run_centres = (
            self.coverage.rows[self.coverage.owner // across] * shape[1]
            + self.coverage.columns[self.coverage.owner % across]
        ).astype(np.int64)
        # Whether a point can land on this grid at all: the tiles' arcs widened by one slot
        # each way (the kernel's float32 points against these float64 arcs differ by far
        # less). A fragment of a revolution the camera cannot see (issue 12: 6 messages per
        # turn, each fused on its own) then costs no pass over the image: its scan is NaN.
        # Per tile the same test leaves out of the pass the tiles that cannot reach the grid
        # (`_spans`), so a fragment the camera sees in part reads only that part.
        tiles_shape = (-(-shape[0] // tile), -(-shape[1] // tile))
        after, before = _tile_gaps(tile_first, tile_last, lidar_grid)
        self._tile_gaps = (after.reshape(tiles_shape), before.reshape(tiles_shape))
        self._least_gap = float(np.minimum(after, before).min(initial=math.inf))
        self.sees_grid = self._least_gap <= 1.0
        self._nearest_reach = nearest_reach
        self._tile = tile
        # The last (turn, margin)'s row spans (`_spans`): a frame without motion reuses them.
        self._span_key = (math.nan, math.nan)
        self._row_spans = np.zeros((shape[0], 2), dtype=np.int64)
        self.frames_converted = 0  # frames whose pixels went through the kernel or numpy

        self._best = np.empty(lidar_grid.count, dtype=np.float32)
        self._drop_slots = np.zeros(lidar_grid.count, dtype=np.bool_)
        # Rows of the slab's points per slot, then rows of the drops' points.
        self._nearest = np.empty((2 * lidar_grid.count, self.min_points), dtype=np.float32)
        limits_mm = _millimetre_interval(np.array([range_min]), np.array([range_max]))
        self._millimetre_limits = (int(limits_mm[0][0]), int(limits_mm[1][0]))
        self.lookup = SlotLookup.for_grid(lidar_grid)
        # Rows by the mean far end of their pixels' slab intervals, nearest first: see
        # `_row_typical`; rows that cannot see the slab go last.
        self._rows = np.argsort(typical, kind='stable')
        block = self._kernel.BLOCK if self._kernel is not None else camera.width
        # Threads split the columns this grid's points can come from (a fragment of a turn:
        # its side of the image), not the whole width: each gets a like share of the work.
        still = self._spans(0.0, 1.0) if self._kernel is not None else np.zeros((1, 2), np.int64)
        reads = still[:, 1] > still[:, 0]
        columns = (
            (int(still[reads, 0].min()), int(still[reads, 1].max()))
            if reads.any()
            else (0, camera.width)
        )
        self._bands = _column_bands(camera.width, self.threads, block, columns)
        self._block_extremes = self._extremes()
        self._part_nearest = np.empty((self.threads, *self._nearest.shape), dtype=np.float32)
        self._bound = np.empty((self.threads, 2 * self.lookup.first.size), dtype=np.float32)
        self._warm_up()

    def _height_intervals(
        self, part: slice, x_n: F64, y_n: F64, ground: GroundPlane, lifts: F64 | None = None
    ) -> tuple[F64, F64, F64, F64, F64]:
        """Per pixel of `part` the slab interval [lo, hi], the drop interval [drop_lo,
        drop_hi] and the floor crossing depth, for heights above `ground`; with `lifts`
        (4 x pixels of `part`: `GroundProfile.slab_lifts` per pixel) above the ground under the
        points where the line of sight is at the slab's top, at its bottom, meets the ground
        (a ramp's height there) and meets the lowest ground the ground may be (a drop lies
        beyond that)."""
        normal = ground.normal
        a_z = normal[0] * x_n + normal[1] * y_n + normal[2]
        b_z: float | F64 = ground.offset
        limits = {
            'min_obstacle_height': self.min_obstacle_height,
            'max_obstacle_height': self.max_obstacle_height,
            'range_min': self.range_min,
            'range_max': self.range_max,
            'bottom_noise': self.bottom_noise,
        }
        if lifts is None:
            lo, hi = _depth_interval(a_z, b_z, b_z, **limits)
        else:
            # The slab's top and bottom each above the ground under the line of sight there.
            lo, hi = _depth_interval(
                a_z, ground.offset - lifts[0], ground.offset - lifts[1], **limits
            )
            b_z = ground.offset - lifts[2]
        if self.drops is None:
            drop_lo = np.full(a_z.shape, np.inf)
            return lo, hi, drop_lo, -drop_lo, np.full(a_z.shape, np.nan)
        horizontal = self._drop_horizontal[part].astype(np.float64)
        drop_lo, drop_hi, floor = _drop_interval(
            a_z, b_z, horizontal, self.drops, self.range_min, self.range_max,
            lowest=None if lifts is None else ground.offset - lifts[3],
        )  # fmt: skip
        return lo, hi, drop_lo, drop_hi, floor

    def _store_heights(
        self, part: slice, lo: F64, hi: F64, drop_lo: F64, drop_hi: F64, floor: F64
    ) -> None:
        """Write the height tables of `part` (metres and millimetres)."""
        for index, values in ((0, lo), (1, hi), (4, drop_lo), (5, floor)):
            self._metres[index][part] = values
        lo_mm, hi_mm = _millimetre_interval(lo, hi)
        self._millimetres[0][part] = lo_mm
        self._millimetres[1][part] = hi_mm
        self._millimetres[4][part] = _millimetre_interval(drop_lo, drop_hi)[0]
        self._millimetres[5][part] = floor / MILLIMETRE

    def _extremes(self) -> dict[np.dtype[Any], tuple[npt.NDArray[Any], ...]]:
        """Per table dtype the blocks' least lo, greatest hi and least drop_lo
        (`_block_extremes`): the kernel skips a block whose depths are all outside."""
        shape = (self.camera.height, self.camera.width)
        block = self._kernel.BLOCK if self._kernel is not None else self.camera.width
        return {
            np.dtype(tables[0].dtype): (
                *_block_extremes(tables[0], tables[1], shape, self._bands, block),
                _block_extremes(tables[4], tables[4], shape, self._bands, block)[0],
            )
            for tables in (self._millimetres, self._metres)
        }

    def _numpy_heights(self, ground: GroundPlane, lifts: Lifts | None) -> None:
        """The height tables and the blocks' extremes for `ground` (and `lifts`), in numpy
        (the reference of `_compiled_heights`, and the way without numba)."""
        x_table, y_table = (np.asarray(c).ravel() for c in self.camera.normalized_coordinates)
        width = self.camera.width
        per_pixel = None if lifts is None else lifts.per_pixel(self.camera.height, width)
        for top in range(0, self.camera.height, self._band):
            rows = min(self._band, self.camera.height - top)
            part = slice(top * width, (top + rows) * width)
            x_n = x_table[part].astype(np.float64)
            y_n = y_table[part].astype(np.float64)
            intervals = self._height_intervals(
                part, x_n, y_n, ground, None if per_pixel is None else per_pixel[:, part]
            )
            self._store_heights(part, *intervals)
        self._block_extremes = self._extremes()

    def _compiled_heights(self, ground: GroundPlane, lifts: Lifts | None) -> None:
        """`_numpy_heights` in one compiled pass (`height_kernel`)."""
        x_table, y_table = (np.asarray(c).ravel() for c in self.camera.normalized_coordinates)
        drops = self.drops
        height_kernel.tables(
            x_table, y_table, self.camera.width, self._drop_horizontal,
            np.array(ground.normal), ground.offset,
            np.empty((4, 0, 0)) if lifts is None else lifts.coarse,
            1 if lifts is None else lifts.stride,
            np.array([self.min_obstacle_height, self.max_obstacle_height, self.range_min,
                      self.range_max, self.bottom_noise]),
            np.zeros(4) if drops is None else np.array(
                [1.0, drops.min_depth, drops.min_width, drops.noise]
            ),
            *(self._metres[index] for index in (0, 1, 4, 5)),
            *(self._millimetres[index] for index in (0, 1, 4, 5)),
        )  # fmt: skip
        height, width = self.camera.height, self.camera.width
        block = self._kernel.BLOCK if self._kernel is not None else width
        for tables in (self._millimetres, self._metres):
            height_kernel.extremes(
                tables[0], tables[1], tables[4], height, width, self._bands, block,
                *self._block_extremes[np.dtype(tables[0].dtype)],
            )  # fmt: skip

    def use_ground(self, ground: GroundPlane, profile: GroundProfile | None = None) -> bool:
        """Measure heights above `ground` (and `profile`'s ramps) from now on; True when the
        tables were rebuilt.

        Within `GROUND_TOLERANCE` of the plane the tables hold (no height within
        range_max of the camera moves by more), and without a profile, the tables stay: a
        steady estimate costs nothing, and a flat floor with the right mounting gives
        exactly the mounting's scan. A profile rebuilds them every frame it is given.
        The slab's view (`in_view`) and the order rows are read in stay the mounting's.
        """
        if (
            profile is None
            and not self._profiled
            and ground.height_change(self.ground, self.range_max) <= GROUND_TOLERANCE
        ):
            return False
        lifts = (
            None
            if profile is None
            else profile.slab_lifts(
                self.camera, self.range_max, self.min_obstacle_height, self.max_obstacle_height
            )
        )
        if self._kernel is not None:
            self._compiled_heights(ground, lifts)
        else:
            self._numpy_heights(ground, lifts)
        self.ground = ground
        self._profiled = profile is not None
        self.ground_refreshes += 1
        return True

    def _seen(self, depth: npt.NDArray[Any]) -> Mask:
        """`ViewCoverage.seen` of this frame's valid tile centres, compiled when it can be."""
        coverage = self.coverage
        if self._kernel is None or depth.dtype not in (np.uint16, np.float32):
            return coverage.seen(self._valid_centres(depth))
        if depth.dtype == np.uint16:
            low, high = (np.uint16(limit) for limit in self._millimetre_limits)
        else:
            # numpy compares float32 with a Python float in float32 (NEP 50): so does this.
            low, high = np.float32(self.range_min), np.float32(self.range_max)
        seen = np.empty(self.grid.count, dtype=np.bool_)
        self._kernel.seen_slots(
            depth.ravel(), self._run_centres, low, high, coverage.starts, coverage.ends, seen
        )
        return seen

    def _valid_centres(self, depth: npt.NDArray[Any]) -> Mask:
        """Whether each tile's centre pixel holds a depth inside the range limits."""
        coverage = self.coverage
        centres = depth[np.ix_(coverage.rows, coverage.columns)]
        if depth.dtype == np.uint16:
            low, high = self._millimetre_limits
            return (centres >= low) & (centres <= high)
        with np.errstate(invalid='ignore'):
            return (centres >= self.range_min) & (centres <= self.range_max)

    @property
    def drop_slots(self) -> Mask:
        """The slots whose reading in the last frame is a drop-off's edge (a copy)."""
        slots: Mask = self._drop_slots.copy()
        return slots

    @property
    def uses_kernel(self) -> bool:
        """True when frames go through the compiled numba kernel."""
        return self._kernel is not None

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels now, not on the first frame."""
        if self._kernel is None:
            return
        shape = (self.camera.height, self.camera.width)
        for blank in (np.zeros(shape, dtype=np.uint16), np.full(shape, np.nan, dtype=np.float32)):
            self.nearest_squared(blank.ravel())
            self._seen(blank)

    def nearest_squared(
        self,
        depth: npt.NDArray[Any],
        *,
        reference: bool = False,
        motion: PlanarMotion = IDENTITY_MOTION,
    ) -> F32:
        """Per slot the reported squared horizontal range (Inf: fewer than k points).

        k is `min_points`: of the slot's k nearest slab points the farthest within
        `cluster_spread` r^2 of the nearest, or its nearest drop crossing (`drop_slots`).

        `depth` is the flattened image, uint16 millimetres or float32 metres.
        `reference=True` runs the numpy version whatever the kernel.
        `motion` moves every point before it is binned (motion compensation).
        """
        pixels = self.camera.width * self.camera.height
        if depth.ndim != 1 or depth.size != pixels or depth.dtype not in (np.uint16, np.float32):
            msg = (
                f'nearest_squared takes the flattened image: {pixels} uint16 or float32 '
                f'values, got shape {depth.shape} of {depth.dtype}; scan() takes the image'
            )
            raise InputError(msg)
        tables = self._millimetres if depth.dtype == np.uint16 else self._metres
        lo, hi, a_x, a_y, drop_lo, floor = tables
        top = _DROP_TOP[depth.dtype]
        b_x, b_y = self._b
        moved = _motion32(motion)
        lookup = self.lookup
        kernel = self._kernel
        if kernel is None or reference:
            _nearest_squared_numpy(
                depth, lo, hi, a_x, a_y, b_x, b_y, moved, lookup, self._nearest,
                None if self.drops is None else (drop_lo, top, floor),
            )  # fmt: skip
            _pick(self._nearest, self.cluster_spread, self._best, self._drop_slots)
            return self._best
        depth = np.ascontiguousarray(depth)
        slots = (lookup.scale, lookup.first, lookup.second, lookup.before, lookup.middle)
        extremes = (*self._block_extremes[depth.dtype], self.drops is not None)
        spans = self._spans(*self._margin(motion))
        if self.threads == 1:
            kernel.nearest_squared(
                depth, lo, hi, a_x, a_y, drop_lo, top, floor, b_x, b_y, *moved, self._rows,
                self.camera.width, spans, *extremes, *slots, lookup.after, self.cluster_spread,
                self._nearest, self._bound[0], self._best, self._drop_slots,
            )  # fmt: skip
        else:
            kernel.nearest_squared_parallel(
                depth, lo, hi, a_x, a_y, drop_lo, top, floor, b_x, b_y, *moved, self._rows,
                self.camera.width, spans, self._bands, *extremes, *slots, lookup.after,
                self.cluster_spread, self._part_nearest, self._bound, self._best,
                self._drop_slots,
            )  # fmt: skip
            self._nearest[:] = self._part_nearest[0]
        return self._best

    def _margin(self, motion: PlanarMotion) -> tuple[float, float]:
        """How a pixel's point, moved by `motion`, may land beside its tile's arc: (turn,
        margin) in slots, the arc turned by `turn` and widened by `margin` each way.

        The motion turns every bearing by its angle (angle / angle_increment slots) and then
        shifts a point at r metres by at most asin(|t| / r) (t: its translation), r at least
        the nearest reach of any pixel's slab segment (times the motion's scale, 1 for a
        rotation): the arcs so moved and widened, plus one slot, cover every point. An
        infinite margin: any bearing.
        """
        if motion.is_identity:
            return 0.0, 1.0
        shift = math.hypot(motion.tx, motion.ty)
        reach = self._nearest_reach * math.hypot(motion.cos, motion.sin)
        if not shift < reach:
            return 0.0, math.inf  # a point may pass the origin (or the motion is not finite)
        turn = motion.angle / self.grid.angle_increment
        margin = 1.0 + math.asin(shift / reach) / abs(self.grid.angle_increment)
        if not math.isfinite(turn + margin):
            return 0.0, math.inf
        return turn, margin

    def _spans(self, turn: float, margin: float) -> npt.NDArray[np.int64]:
        """Per image row the columns [start, stop) the kernel reads: the tiles whose arcs,
        turned by `turn` and widened by `margin` slots, meet the grid
        (`obstacle_kernel.row_spans`)."""
        if (turn, margin) != self._span_key and self._kernel is not None:
            self._kernel.row_spans(
                *self._tile_gaps, turn, margin, self._tile, self.camera.width, self._row_spans
            )
            self._span_key = (turn, margin)
        return self._row_spans

    def reaches(self, motion: PlanarMotion = IDENTITY_MOTION) -> bool:
        """Whether a point of a frame, moved by `motion`, can land on this grid at all.

        Some tile's arc, moved as `_margin(motion)` says, may meet the grid (`_tile_gaps`:
        within the margin plus the turn either way, one test for all tiles).
        """
        turn, margin = self._margin(motion)
        return self._least_gap <= margin + abs(turn)

    def scan(
        self,
        depth: npt.NDArray[np.generic],
        motion: PlanarMotion = IDENTITY_MOTION,
        ground: GroundPlane | None = None,
        profile: GroundProfile | None = None,
    ) -> Scan:
        """The obstacle scan of one depth image (uint16 mm, 0 invalid; float m, NaN invalid).

        `motion` takes points from the LiDAR frame at the image's stamp to the LiDAR frame
        at the scan's stamp (motion compensation); the camera's view turns with it by whole
        slots (its shift by the translation is below a slot at the offsets paired).

        On the LiDAR's grid: per slot the horizontal range from the LiDAR's origin of the
        `min_points`-th nearest point in the slab; +Inf where the camera saw valid depth in
        the slot and fewer than `min_points` points in the slab; NaN outside the camera's
        view or where it has no valid depth; REP-117 -Inf for an obstacle nearer than
        range_min, +Inf beyond range_max.
        `ground` (the frame's floor, `ground.GroundTracker`) is where heights are measured
        from (`use_ground`); None: the plane the tables hold (the mounting's, until a ground
        is given).
        `frame_id` and `stamp_ns` are left for the caller (the LiDAR's).
        """
        self.camera.check_depth(depth)
        if ground is not None:
            self.use_ground(ground, profile)
        if not all(map(math.isfinite, (motion.cos, motion.sin, motion.tx, motion.ty))):
            msg = f'motion must be finite (cos, sin, tx, ty), got {motion}; check the odometry'
            raise InputError(msg)
        grid = self.grid
        if not self.reaches(motion):
            # No pixel's arc reaches this grid, moved by `motion`: every slot is out of view,
            # so NaN, as the full pass would give.
            self._best[:] = np.inf
            self._drop_slots[:] = False
            return Scan(
                angle_min=grid.angle_min,
                angle_max=grid.angle_max,
                angle_increment=grid.angle_increment,
                range_min=self.range_min,
                range_max=self.range_max,
                # (to_rep117 leaves NaN as it is)
                ranges=np.full(grid.count, np.nan, dtype=np.float32),
            )
        if depth.dtype != np.uint16:
            depth = depth.astype(np.float32, copy=False)
        depth = np.ascontiguousarray(depth)
        flat = depth.ravel()
        self.frames_converted += 1
        best = self.nearest_squared(flat, motion=motion)
        seen = self._seen(depth)
        if not motion.is_identity:
            seen = _turn_slots(seen, motion.angle, self.grid)
        empty = np.where(seen, np.float32(np.inf), np.float32(np.nan))
        ranges = np.where(np.isfinite(best), np.sqrt(best), empty)
        ranges = to_rep117(ranges, self.range_min, self.range_max)
        return Scan(
            angle_min=grid.angle_min,
            angle_max=grid.angle_max,
            angle_increment=grid.angle_increment,
            range_min=self.range_min,
            range_max=self.range_max,
            ranges=ranges,
        )


def _row_typical(lo: F64, hi: F64) -> F64:
    """Per image row the mean far end of its pixels' slab intervals (Inf: none sees it).

    The kernel visits rows nearest first: near points fill each slot's k nearest early,
    so fewer of the farther points that follow are inserted (the result is the same in
    any order). The far end is where a ray looking down leaves the slab into the floor,
    where its points cluster (the floor's noise, what stands on it).
    """
    with np.errstate(invalid='ignore'):
        sees = lo <= hi
    seen = sees.sum(axis=1)
    total = np.where(sees, hi, 0.0).sum(axis=1)
    typical: F64 = np.divide(total, seen, out=np.full(total.shape, np.inf), where=seen > 0)
    return typical


def _column_bands(
    width: int, parts: int, block: int, columns: tuple[int, int] | None = None
) -> npt.NDArray[np.int64]:
    """`parts` bands of image columns: rows [start, stop, first block].

    The bands cut `columns` [start, stop) (default: all) as equally as can be; the first
    and the last band reach on to the image's edges, so together they hold every column.
    The kernel cuts each band into blocks of `block` columns from its start; the first
    block is the index of the band's first block among the row's blocks.
    """
    start, stop = (0, width) if columns is None else columns
    edges = np.linspace(start, stop, parts + 1).round().astype(np.int64)
    edges[0], edges[-1] = 0, width
    blocks = -(-(edges[1:] - edges[:-1]) // block)
    first = np.concatenate([[0], np.cumsum(blocks)[:-1]])
    bands: npt.NDArray[np.int64] = np.stack([edges[:-1], edges[1:], first], axis=1)
    return bands


def _block_extremes(
    lo: npt.NDArray[Any],
    hi: npt.NDArray[Any],
    shape: tuple[int, int],
    bands: npt.NDArray[np.int64],
    block: int,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """Per row and block of each band (`_column_bands`) the least lo and greatest hi.

    Columns past a band's end pad its last block with an empty interval (lo > hi).
    """
    empty_lo, empty_hi = (UINT16_MAX, 0) if lo.dtype == np.uint16 else (np.inf, -np.inf)
    least: list[npt.NDArray[Any]] = []
    greatest: list[npt.NDArray[Any]] = []
    for start, stop, _ in bands:
        blocks = -(-(stop - start) // block)
        for table, fill, reduce, out in (
            (lo, empty_lo, np.min, least),
            (hi, empty_hi, np.max, greatest),
        ):
            padded = np.full((shape[0], blocks * block), fill, dtype=table.dtype)
            padded[:, : stop - start] = table.reshape(shape)[:, start:stop]
            out.append(reduce(padded.reshape(shape[0], blocks, block), axis=2))
    return np.ascontiguousarray(np.concatenate(least, axis=1)), np.ascontiguousarray(
        np.concatenate(greatest, axis=1)
    )


def _motion32(motion: PlanarMotion) -> tuple[np.float32, np.float32, np.float32, np.float32]:
    return (
        np.float32(motion.cos),
        np.float32(motion.sin),
        np.float32(motion.tx),
        np.float32(motion.ty),
    )


def _turn_slots(mask: Mask, angle: float, grid: AngleGrid) -> Mask:
    """`mask` of slots turned by `angle` (whole slots; wraps on a grid that fills the turn)."""
    shift = round(angle / grid.angle_increment)
    if shift == 0:
        return mask
    if abs(grid.count * grid.angle_increment) >= TWO_PI - abs(grid.angle_increment) / 2:
        return np.roll(mask, shift)
    turned = np.zeros_like(mask)
    if abs(shift) < mask.size:
        if shift > 0:
            turned[shift:] = mask[:-shift]
        else:
            turned[:shift] = mask[-shift:]
    return turned


def _check_limits(
    min_obstacle_height: float, max_obstacle_height: float, range_min: float, range_max: float
) -> None:
    values = {
        'min_obstacle_height': min_obstacle_height,
        'max_obstacle_height': max_obstacle_height,
        'range_min': range_min,
        'range_max': range_max,
    }
    for name, value in values.items():
        if not math.isfinite(value):
            msg = f'{name} must be finite, got {value}'
            raise InputError(msg)
    if range_min < 0.0 or range_min >= range_max:
        msg = f'need 0 <= range_min < range_max, got range_min={range_min}, range_max={range_max}'
        raise InputError(msg)
    if min_obstacle_height >= max_obstacle_height:
        msg = (
            f'min_obstacle_height ({min_obstacle_height}) must be below max_obstacle_height '
            f'({max_obstacle_height}): they bound the collision slab above the floor'
        )
        raise InputError(msg)


def obstacle_scan(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    extrinsics: Extrinsics,
    lidar_grid: AngleGrid,
    *,
    min_obstacle_height: float,
    max_obstacle_height: float,
    range_min: float,
    range_max: float,
    min_points: int = 1,
    cluster_spread: float = math.inf,
    drops: DropLimits | None = None,
) -> Scan:
    """One-off obstacle scan; build an `ObstacleProjector` to convert many frames."""
    projector = ObstacleProjector(
        camera,
        extrinsics,
        lidar_grid,
        min_obstacle_height=min_obstacle_height,
        max_obstacle_height=max_obstacle_height,
        range_min=range_min,
        range_max=range_max,
        min_points=min_points,
        cluster_spread=cluster_spread,
        drops=drops,
    )
    return projector.scan(depth)
