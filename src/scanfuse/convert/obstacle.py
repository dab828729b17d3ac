"""Height-filtered full-frame obstacle scan: every depth pixel, kept inside the collision slab.

Beyond the paper (which converts one image row): each pixel becomes a 3D point
in the base frame; points whose height above the floor (base z = 0) lies in
[min_obstacle_height, max_obstacle_height] are obstacles; they are binned by
their direction seen from the LiDAR's origin into the LiDAR's own slots, and the
nearest horizontal range per slot is reported.

All geometry that does not depend on the depth values is folded into per-pixel
tables when the projector is built. A pixel with ray (x_n, y_n, 1) and depth Z
(along the optical axis) is at

    height = a_z Z + b_z,   x_laser = a_x Z + b_x,   y_laser = a_y Z + b_y

so the height test and the range limits on Z together become one interval
lo <= Z <= hi per pixel, and per frame only two compares per pixel remain, plus
two multiply-adds, an atan2 and a minimum for the pixels that pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.camera import MILLIMETRE
from scanfuse.errors import InputError
from scanfuse.scan import TWO_PI, AngleGrid, Scan, to_rep117

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.transforms import Extrinsics

    F32 = npt.NDArray[np.float32]
    F64 = npt.NDArray[np.float64]

# A ray this close to horizontal keeps one height whatever its depth.
_LEVEL_RAY = 1e-12
# uint16 millimetre limits are rounded towards inclusion by this much.
_MM_ROUNDING = 1e-6
UINT16_MAX = 65535


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
        increment = abs(grid.angle_increment)
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


def _nearest_squared_loop(  # noqa: PLR0917 - numba kernels take plain arrays
    depth: Any,
    lo: Any,
    hi: Any,
    a_x: Any,
    a_y: Any,
    b_x: np.float32,
    b_y: np.float32,
    scale: float,
    first: Any,
    second: Any,
    before: Any,
    middle: Any,
    after: Any,
    best: Any,
) -> None:
    """Per slot the smallest squared horizontal range of the pixels inside their [lo, hi].

    `_nearest_squared_numpy` one pixel at a time, for numba: the same arithmetic
    (float32 points, float64 pseudo-angles) in the same order, so both agree exactly.
    """
    last_bin = first.size - 1
    best[:] = np.inf
    for i in range(depth.size):
        z = depth[i]
        if z < lo[i] or z > hi[i]:  # also drops NaN (float) and 0 (uint16, lo >= 1)
            continue
        z32 = np.float32(z)
        x = a_x[i] * z32 + b_x
        y = a_y[i] * z32 + b_y
        x64 = np.float64(x)
        y64 = np.float64(y)
        norm = abs(x64) + abs(y64)
        if norm == 0.0:
            continue
        ratio = x64 / norm
        pseudo = 1.0 - ratio if y64 >= 0.0 else 3.0 + ratio
        index = min(int(pseudo * scale), last_bin)
        if pseudo >= second[index]:
            slot = after[index]
        elif pseudo >= first[index]:
            slot = middle[index]
        else:
            slot = before[index]
        if slot < 0:
            continue
        r2 = x * x + y * y
        best[slot] = min(best[slot], r2)


def _load_kernel() -> Callable[..., None] | None:
    """The numba-compiled loop, or None when numba is not installed (numpy is used then)."""
    try:
        import numba  # noqa: PLC0415
    except ImportError:  # pragma: no cover - numba is a dependency; this is the fallback
        return None
    kernel: Callable[..., None] = numba.njit(cache=True, nogil=True)(_nearest_squared_loop)
    return kernel


_KERNEL = _load_kernel()


def _nearest_squared_numpy(  # noqa: PLR0917 - mirrors the kernel's arguments
    depth: npt.NDArray[Any],
    lo: npt.NDArray[Any],
    hi: npt.NDArray[Any],
    a_x: F32,
    a_y: F32,
    b_x: np.float32,
    b_y: np.float32,
    lookup: SlotLookup,
    best: F32,
) -> None:
    """The reference (and the fallback without numba): the same reduction, vectorised."""
    keep = np.flatnonzero((depth >= lo) & (depth <= hi))
    z = depth[keep].astype(np.float32)
    x = a_x[keep] * z + b_x
    y = a_y[keep] * z + b_y
    slot = lookup.slots(x.astype(np.float64), y.astype(np.float64))
    inside = slot >= 0
    best[:] = np.inf
    np.minimum.at(best, slot[inside], (x * x + y * y)[inside])


def _depth_interval(
    a_z: F64,
    b_z: float,
    *,
    min_obstacle_height: float,
    max_obstacle_height: float,
    range_min: float,
    range_max: float,
) -> tuple[F64, F64]:
    """Per pixel [lo, hi] of depths Z whose point is inside the slab and the range limits.

    lo > hi where the pixel can never see an obstacle (its ray misses the slab).
    """
    with np.errstate(divide='ignore', invalid='ignore'):
        at_min = (min_obstacle_height - b_z) / a_z
        at_max = (max_obstacle_height - b_z) / a_z
    rising = a_z > _LEVEL_RAY
    falling = a_z < -_LEVEL_RAY
    level_inside = min_obstacle_height <= b_z <= max_obstacle_height
    lo = np.where(rising, at_min, np.where(falling, at_max, -np.inf if level_inside else np.inf))
    hi = np.where(rising, at_max, np.where(falling, at_min, np.inf if level_inside else -np.inf))
    lo = np.maximum(lo, range_min)
    hi = np.minimum(hi, range_max)
    no_ray = ~np.isfinite(a_z)
    lo[no_ray] = np.inf
    hi[no_ray] = -np.inf
    return lo, hi


def _millimetre_interval(lo: F64, hi: F64) -> tuple[npt.NDArray[np.uint16], npt.NDArray[np.uint16]]:
    """[lo, hi] metres as inclusive uint16 millimetres; 0 (no measurement) never inside."""
    lo_mm = np.ceil(np.clip(lo / MILLIMETRE - _MM_ROUNDING, 1.0, UINT16_MAX))
    hi_mm = np.floor(np.clip(hi / MILLIMETRE + _MM_ROUNDING, 0.0, UINT16_MAX))
    empty = lo_mm > hi_mm
    lo_mm[empty] = UINT16_MAX
    hi_mm[empty] = 0.0
    return lo_mm.astype(np.uint16), hi_mm.astype(np.uint16)


def _slot_coordinate(angle: F64, grid: AngleGrid) -> F64:
    """Angle as a continuous slot position in [0, turn): slot k covers [k, k + 1)."""
    increment = grid.angle_increment
    if increment > 0.0:
        offset = np.mod(angle - grid.angle_min + 0.5 * increment, TWO_PI)
    else:
        offset = np.mod(-(angle - grid.angle_min) - 0.5 * increment, TWO_PI)
    coordinate: F64 = offset / abs(increment)
    return coordinate


def _slots_in_view(
    near: tuple[F64, F64], far: tuple[F64, F64], grid: AngleGrid
) -> npt.NDArray[np.bool_]:
    """Slots swept by the segments near -> far (points in the LiDAR's xy plane).

    Each pixel sees obstacles along a segment of its ray (from its lo to its hi
    depth); seen from the LiDAR's origin the segment sweeps the shorter arc
    between its ends (a segment not through the origin subtends less than pi).
    With an off-centre camera the near end can lie far to the side of the far
    end, so both ends count, not the ray's direction alone.
    """
    near_angle = np.arctan2(near[1], near[0])
    far_angle = np.arctan2(far[1], far[0])
    sweep = np.mod(far_angle - near_angle + math.pi, TWO_PI) - math.pi
    sign = 1.0 if grid.angle_increment > 0.0 else -1.0
    start = _slot_coordinate(near_angle, grid)
    end = start + sign * sweep / abs(grid.angle_increment)
    first = np.minimum(start, end)
    last = np.maximum(start, end)
    turn = TWO_PI / abs(grid.angle_increment)
    # start is in [0, turn) and |sweep| < turn / 2: an arc may cross the seam of the
    # turn once, below 0 or above turn; such an arc is split in two pieces.
    pieces_first = np.concatenate([np.maximum(first, 0.0), first[first < 0.0] + turn])
    pieces_last = np.concatenate([np.minimum(last, turn), np.full(int((first < 0.0).sum()), turn)])
    wrapped = last >= turn
    pieces_first = np.concatenate([pieces_first, np.zeros(int(wrapped.sum()))])
    pieces_last = np.concatenate([pieces_last, last[wrapped] - turn])
    first_slot = np.floor(pieces_first).astype(np.int64)
    last_slot = np.minimum(np.floor(pieces_last).astype(np.int64), grid.count - 1)
    used = (pieces_first <= pieces_last) & (first_slot <= last_slot)
    # Difference array: +1 where a run of covered slots starts, -1 after it ends.
    marks = np.zeros(grid.count + 1, dtype=np.int64)
    np.add.at(marks, first_slot[used], 1)
    np.add.at(marks, last_slot[used] + 1, -1)
    in_view: npt.NDArray[np.bool_] = np.cumsum(marks[:-1]) > 0
    return in_view


class ObstacleProjector:
    """Depth images of one camera, mounted one way, to scans on one LiDAR grid.

    Build once (tables, field of view, compiled kernel), then call `scan` per frame.
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
        use_kernel: bool = True,
    ) -> None:
        _check_limits(min_obstacle_height, max_obstacle_height, range_min, range_max)
        self.camera = camera
        self.extrinsics = extrinsics
        self.grid = lidar_grid
        self.range_min = float(range_min)
        self.range_max = float(range_max)
        self._kernel = _KERNEL if use_kernel else None

        x_n, y_n = (np.asarray(c, dtype=np.float64).ravel() for c in camera.normalized_coordinates)
        height_row = extrinsics.base_to_camera_optical.rotation_matrix[2]
        b_z = extrinsics.base_to_camera_optical.translation[2]
        a_z = height_row[0] * x_n + height_row[1] * y_n + height_row[2]
        laser = extrinsics.laser_to_camera_optical
        rotation = laser.rotation_matrix
        a_x = rotation[0, 0] * x_n + rotation[0, 1] * y_n + rotation[0, 2]
        a_y = rotation[1, 0] * x_n + rotation[1, 1] * y_n + rotation[1, 2]
        b_x, b_y = laser.translation[0], laser.translation[1]

        lo, hi = _depth_interval(
            a_z,
            b_z,
            min_obstacle_height=min_obstacle_height,
            max_obstacle_height=max_obstacle_height,
            range_min=range_min,
            range_max=range_max,
        )
        seen = lo <= hi
        near = (a_x[seen] * lo[seen] + b_x, a_y[seen] * lo[seen] + b_y)
        far = (a_x[seen] * hi[seen] + b_x, a_y[seen] * hi[seen] + b_y)
        in_view = _slots_in_view(near, far, lidar_grid)
        self.in_view = in_view
        self._empty = np.where(in_view, np.float32(np.inf), np.float32(np.nan)).astype(np.float32)

        self._b = (np.float32(b_x), np.float32(b_y))
        self._metres = (
            lo.astype(np.float32),
            hi.astype(np.float32),
            a_x.astype(np.float32),
            a_y.astype(np.float32),
        )
        lo_mm, hi_mm = _millimetre_interval(lo, hi)
        self._millimetres = (
            lo_mm,
            hi_mm,
            (a_x * MILLIMETRE).astype(np.float32),
            (a_y * MILLIMETRE).astype(np.float32),
        )
        self._best = np.empty(lidar_grid.count, dtype=np.float32)
        self.lookup = SlotLookup.for_grid(lidar_grid)
        self._warm_up()

    @property
    def uses_kernel(self) -> bool:
        """True when frames go through the compiled numba kernel."""
        return self._kernel is not None

    def _warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernel now, not on the first frame."""
        if self._kernel is None:
            return
        pixels = self.camera.width * self.camera.height
        self.nearest_squared(np.zeros(pixels, dtype=np.uint16))
        self.nearest_squared(np.full(pixels, np.nan, dtype=np.float32))

    def nearest_squared(self, depth: npt.NDArray[Any], *, reference: bool = False) -> F32:
        """Per slot the smallest squared horizontal range (Inf: nothing), from flat depth.

        `depth` is the flattened image, uint16 millimetres or float32 metres.
        `reference=True` runs the numpy version whatever the kernel.
        """
        lo, hi, a_x, a_y = self._millimetres if depth.dtype == np.uint16 else self._metres
        best = self._best
        b_x, b_y = self._b
        lookup = self.lookup
        if self._kernel is not None and not reference:
            self._kernel(
                depth,
                lo,
                hi,
                a_x,
                a_y,
                b_x,
                b_y,
                lookup.scale,
                lookup.first,
                lookup.second,
                lookup.before,
                lookup.middle,
                lookup.after,
                best,
            )
        else:
            _nearest_squared_numpy(depth, lo, hi, a_x, a_y, b_x, b_y, lookup, best)
        return best

    def scan(self, depth: npt.NDArray[np.generic]) -> Scan:
        """The obstacle scan of one depth image (uint16 mm, 0 invalid; float m, NaN invalid).

        On the LiDAR's grid: the nearest obstacle's horizontal range from the LiDAR's
        origin per slot; +Inf where the camera sees the slot and nothing is in the slab;
        NaN outside the camera's view; REP-117 +-Inf for ranges outside the limits.
        `frame_id` and `stamp_ns` are left for the caller (the LiDAR's).
        """
        self.camera.check_depth(depth)
        if depth.dtype != np.uint16:
            depth = depth.astype(np.float32, copy=False)
        flat = np.ascontiguousarray(depth).ravel()
        best = self.nearest_squared(flat)
        hit = np.isfinite(best)
        ranges = np.where(hit, np.sqrt(best), self._empty)
        ranges = to_rep117(ranges, self.range_min, self.range_max)
        grid = self.grid
        return Scan(
            angle_min=grid.angle_min,
            angle_max=grid.angle_max,
            angle_increment=grid.angle_increment,
            range_min=self.range_min,
            range_max=self.range_max,
            ranges=ranges,
        )


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
    )
    return projector.scan(depth)
