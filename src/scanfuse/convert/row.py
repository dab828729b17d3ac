"""Algorithm 1 (depth row to scan) and the depthimage_to_laserscan-compatible band.

Default mode is the paper's row method with the defects of
ros-perception/depthimage_to_laserscan fixed:

- the angular grid is built from the pixel columns themselves (increment = the
  widest spacing between neighbouring columns, at the principal point), so no
  slot is left empty by the mismatch between an evenly spaced angle grid and
  pixel columns evenly spaced in tangent;
- values follow REP-117 (+Inf beyond range_max or on the floor, -Inf closer than
  range_min, NaN no measurement) and the `use_point` reduction is made independent
  of pixel order: per slot the nearest finite in-range value, else -Inf, else +Inf,
  else NaN.

`d2l_compat=True` reproduces the upstream node bit for bit instead, order
dependence included (see `_d2l_scan`).

Everything that depends only on the camera and the scan parameters (slot of each
column, range per metre of depth, depth-code thresholds) is computed once in a
`RowPlan`; per frame only a few vectorised passes over the band remain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.convert.floor import FloorGuard, check_floor_pose, floor_range_limits
from scanfuse.errors import ConfigError, InputError
from scanfuse.scan import Scan

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

    from scanfuse.camera import CameraModel

    FloatArray = npt.NDArray[np.float32]
    Float64Array = npt.NDArray[np.float64]
    IntArray = npt.NDArray[np.int64]
    BoolArray = npt.NDArray[np.bool_]

__all__ = ['RowPlan', 'band_rows', 'row_plan', 'row_scan']

MILLIMETRE = np.float32(0.001)  # 16UC1 depth unit (REP-118), as camera.depth_in_metres
CODE_LIMIT = 65536  # one past the largest 16UC1 depth code
# Per-column outcomes as one float so that a plain minimum applies the REP-117
# preference: finite in-range value < too close (-Inf) < beyond (+Inf) < nothing (NaN).
SCORE_TOO_CLOSE = np.float32(3.0e38)
SCORE_BEYOND = np.float32(3.2e38)
SCORE_NOTHING = np.float32(np.inf)
FALLBACK_SCORES = np.array(
    [SCORE_NOTHING, SCORE_BEYOND, SCORE_TOO_CLOSE, SCORE_TOO_CLOSE], dtype=np.float32
)
FALLBACK_SCORES.setflags(write=False)
OUTCOME_SCORES = np.array([SCORE_TOO_CLOSE, SCORE_BEYOND, SCORE_NOTHING], dtype=np.float32)
OUTCOME_SCORES.setflags(write=False)
OUTCOME_RANGES = np.array([np.nan, -np.inf, np.inf, np.nan], dtype=np.float32)
OUTCOME_RANGES.setflags(write=False)
LARGEST_RANGE = 1.0e30  # keeps every in-range value below the outcome scores


@dataclass(frozen=True, eq=False)
class RowPlan:
    """Per-camera tables of the row method for one band and one set of range limits."""

    row_start: int
    row_stop: int
    angle_min: float
    angle_increment: float
    count: int
    column_order: IntArray | slice  # columns sorted by slot (a reversal without distortion)
    group_starts: IntArray  # where each slot's columns start in column_order
    group_slots: IntArray  # slot of each group
    range_per_depth: FloatArray  # (width,) r / Z = sqrt(1 + x_n^2), equation 3
    range_min: np.float32
    range_max: np.float32
    max_value_range: FloatArray  # (1 or rows, width) largest range reported as a value
    lowest_code16: npt.NDArray[np.uint16]  # (width,) smallest code with r >= range_min, capped
    value_span: IntArray  # (width,) highest - lowest in-range code; negative if none is in range
    close_below: IntArray  # (width,) lowest in-range code - 1: valid codes under it are too close
    highest_code: IntArray  # (width,) largest 16UC1 code with r <= range_max
    floor_code: npt.NDArray[np.uint16] | None  # (rows, width) largest code neither beyond nor floor
    pixel_slots: IntArray | None  # (rows, width) when rays bend along a column (distortion)
    pixel_range_per_depth: FloatArray | None  # (rows, width), idem

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.count - 1)

    def ranges(self, band: npt.NDArray[np.generic]) -> FloatArray:
        """REP-117 ranges of the slots from the band's pixels (rows row_start:row_stop)."""
        if self.pixel_slots is not None:
            return self._ranges_per_pixel(_metres(band))
        if band.dtype == np.uint16:
            scores = self._column_scores_mm(band)  # type: ignore[arg-type]
        else:
            scores = self._column_scores_metres(band.astype(np.float32, copy=False))
        best = np.minimum.reduceat(scores[self.column_order], self.group_starts)
        if self.group_slots.size == self.count:
            return _decode(best)  # every slot has columns: the default grid guarantees it
        ranges = np.full(self.count, np.nan, dtype=np.float32)
        ranges[self.group_slots] = _decode(best)
        return ranges

    def _column_scores_mm(self, band: npt.NDArray[np.uint16]) -> FloatArray:
        """Outcome of each column from 16UC1 codes, without converting every pixel to metres.

        Range grows with the code within a column, so each range limit is a code
        threshold per column and the reduction runs on uint16 with wrap-around
        subtraction: `code - lowest` wraps the codes below `lowest` past every code
        at or above it, and `code - 1` wraps the invalid code 0 to the top.
        """
        if self.floor_code is not None:
            # Floor and beyond-range codes become 0 (no measurement) once noted; a
            # multiply by the mask is several times faster than np.where on uint16.
            inside = band <= self.floor_code
            has_beyond = ~_all_row(inside)
            kept = band * inside
        else:
            kept = band
            has_beyond = np.asarray(_max_row(kept) > self.highest_code)
        offset = _min_row(kept - self.lowest_code16)
        has_value = np.asarray(offset <= self.value_span)
        has_close = np.asarray(_min_row(kept - np.uint16(1)) < self.close_below)
        nearest = offset + self.lowest_code16  # wraps back to the code itself
        values = (nearest.astype(np.float32) * MILLIMETRE) * self.range_per_depth
        return _scores(values, has_value, has_close, has_beyond)

    def _column_scores_metres(self, depth: FloatArray) -> FloatArray:
        ranges = _pixel_ranges(depth, self.range_per_depth)
        nearest, has_close, has_beyond = _classify(
            ranges, self.range_min, self.max_value_range, axis=0
        )
        return _scores(nearest, np.isfinite(nearest), has_close, has_beyond)

    def _ranges_per_pixel(self, depth: FloatArray) -> FloatArray:
        """General path for rays whose angle changes along a column (lens distortion)."""
        assert self.pixel_slots is not None
        assert self.pixel_range_per_depth is not None
        ranges = _pixel_ranges(depth, self.pixel_range_per_depth)
        with np.errstate(invalid='ignore'):
            in_range = (ranges >= self.range_min) & (ranges <= self.max_value_range)
            close = (ranges < self.range_min) & (ranges <= self.max_value_range)
            beyond = ranges > self.max_value_range
        scores = np.where(in_range, ranges, SCORE_NOTHING)
        scores = np.where(close, SCORE_TOO_CLOSE, scores)
        scores = np.where(beyond, SCORE_BEYOND, scores).astype(np.float32, copy=False)
        inside = self.pixel_slots >= 0
        best = np.full(self.count, SCORE_NOTHING, dtype=np.float32)
        np.minimum.at(best, self.pixel_slots[inside], scores[inside])
        return _decode(best)


def _min_row(array: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    # A one-row band needs no reduction; skipping it matters at scan_height 1.
    return array[0] if array.shape[0] == 1 else np.asarray(array.min(axis=0))


def _max_row(array: npt.NDArray[np.uint16]) -> npt.NDArray[np.uint16]:
    return array[0] if array.shape[0] == 1 else np.asarray(array.max(axis=0))


def _all_row(array: BoolArray) -> BoolArray:
    return array[0] if array.shape[0] == 1 else np.asarray(array.all(axis=0))


def _metres(band: npt.NDArray[np.generic]) -> FloatArray:
    if band.dtype == np.uint16:
        metres: FloatArray = band.astype(np.float32) * MILLIMETRE
        metres[band == 0] = np.nan
        return metres
    return band.astype(np.float32, copy=False)


def _pixel_ranges(depth: FloatArray, range_per_depth: FloatArray) -> FloatArray:
    """Equation 3 per pixel, r = Z sqrt(1 + x_n^2); NaN where there is no measurement.

    +-Inf depths keep their REP-118 meaning; zero or negative depths carry none.
    """
    with np.errstate(invalid='ignore'):
        measured = (depth > 0.0) | (depth == -np.inf)
        return np.where(measured, depth * range_per_depth, np.float32(np.nan))


def _classify(
    ranges: FloatArray, range_min: np.float32, max_value_range: FloatArray, axis: int
) -> tuple[FloatArray, BoolArray, BoolArray]:
    """Nearest value in range, and whether anything is too close or beyond, along `axis`."""
    with np.errstate(invalid='ignore'):
        in_range = (ranges >= range_min) & (ranges <= max_value_range)
        nearest = np.where(in_range, ranges, np.float32(np.inf)).min(axis=axis)
        has_close = ((ranges < range_min) & (ranges <= max_value_range)).any(axis=axis)
        has_beyond = (ranges > max_value_range).any(axis=axis)
    return nearest, np.asarray(has_close), np.asarray(has_beyond)


def _scores(
    values: FloatArray, has_value: BoolArray, has_close: BoolArray, has_beyond: BoolArray
) -> FloatArray:
    # Index 2 * close + beyond into the outcome without a value: close wins over beyond.
    fallback = FALLBACK_SCORES[(has_close << 1) | has_beyond]
    scores: FloatArray = np.where(has_value, values, fallback)
    return scores


def _decode(scores: FloatArray) -> FloatArray:
    """Outcome scores back to REP-117 values: one lookup, no per-outcome passes."""
    outcome = np.searchsorted(OUTCOME_SCORES, scores, side='right')  # 0 for a value
    ranges: FloatArray = np.where(outcome == 0, scores, OUTCOME_RANGES[outcome])
    return ranges


def _column_angles(x_n: Float64Array) -> Float64Array:
    """Equation 1 on the pixel rays: theta = atan(X / Z) = atan(x_n), counter-clockwise
    positive about z-up, so the image's right (+x) is negative.

    math.atan rather than np.arctan: the per-pixel reference gives the same bits.
    """
    flat = [-math.atan(float(value)) for value in x_n.ravel()]
    return np.asarray(flat, dtype=np.float64).reshape(x_n.shape)


def slot_grid(column_angles: Float64Array) -> tuple[float, float, int]:
    """(angle_min, angle_increment, count) of the default mode's grid from one row's columns.

    The increment is at least the widest spacing between neighbouring columns (the
    pair at the principal point), so every slot holds at least one column. Columns
    without a ray (NaN: lens distortion not invertible there) take no part.
    """
    angles = column_angles[np.isfinite(column_angles)]
    if angles.size == 0:
        msg = (
            'no pixel of the scan row has a ray: the lens distortion is not invertible '
            'anywhere along it; choose a row nearer the principal point (scan_row) or '
            'check the CameraInfo distortion coefficients'
        )
        raise InputError(msg)
    if angles.size < 2:
        # One column: one slot as wide as that pixel, an arbitrary but honest width.
        return float(angles.min()), 1.0e-3, 1
    low = float(angles.min())
    high = float(angles.max())
    spacing = float(np.abs(np.diff(angles)).max())
    if not spacing > 0.0:
        msg = (
            f'the columns of the scan row all have the bearing {low} rad: the focal length '
            'is too long for their angles to differ; check the CameraInfo (fx)'
        )
        raise InputError(msg)
    count = math.floor((high - low) / spacing) + 1
    return low, (high - low) / (count - 1), count


def slot_of(angles: Float64Array, angle_min: float, increment: float, count: int) -> IntArray:
    """Equation 2, n = N (theta - alpha) / (beta - alpha), with [alpha, beta] the outer
    edges of the N slots, so that the floor is the slot with the nearest centre.

    -1 for angles outside the grid and for NaN (a pixel without a ray).
    """
    alpha = angle_min - 0.5 * increment
    beta = angle_min + (count - 0.5) * increment
    with np.errstate(invalid='ignore'):
        position = np.floor(count * (angles - alpha) / (beta - alpha))
        inside = (position >= 0) & (position < count)
    return np.where(inside, np.where(inside, position, 0).astype(np.int64), -1)


def _smallest_code(predicate: Callable[[IntArray], BoolArray], shape: tuple[int, ...]) -> IntArray:
    """Per element, the smallest code in [0, 65536] where a monotone predicate holds.

    Binary search; 65536 means it holds for no 16UC1 code.
    """
    low = np.zeros(shape, dtype=np.int64)
    high = np.full(shape, CODE_LIMIT, dtype=np.int64)
    while np.any(low < high):
        middle = (low + high) // 2
        holds = predicate(middle)
        high = np.where(holds, middle, high)
        low = np.where(holds, low, middle + 1)
    return low


def _code_range(codes: IntArray, range_per_depth: FloatArray) -> FloatArray:
    """Range of 16UC1 codes, with exactly the arithmetic of the per-frame path."""
    ranges: FloatArray = (codes.astype(np.float32) * MILLIMETRE) * range_per_depth
    return ranges


@lru_cache(maxsize=64)
def row_plan(
    camera: CameraModel,
    *,
    row_start: int,
    row_stop: int,
    scan_row: int,
    range_min: float,
    range_max: float,
    floor_guard: FloorGuard | None,
) -> RowPlan:
    """Build (once per camera and parameters) the tables of `row_scan`'s default mode."""
    x_table, y_table = camera.normalized_coordinates
    x_band = x_table[row_start:row_stop].astype(np.float64)
    angle_min, increment, count = slot_grid(_column_angles(x_table[scan_row].astype(np.float64)))
    rows_alike = bool(np.all(x_band == x_band[scan_row - row_start]))
    x_row = x_table[scan_row].astype(np.float64)
    range_per_depth = np.sqrt(1.0 + x_row * x_row).astype(np.float32)

    column_slots = slot_of(_column_angles(x_row), angle_min, increment, count)
    # Columns without a ray (slot -1) take no part.
    with_ray = np.flatnonzero(column_slots >= 0)
    order: IntArray | slice = with_ray[np.argsort(column_slots[with_ray], kind='stable')]
    if with_ray.size == column_slots.size and np.all(np.diff(column_slots) <= 0):
        # Angles fall from left to right: reversing the columns sorts them, with no gather.
        order = slice(None, None, -1)
    sorted_slots = column_slots[order]
    starts = np.flatnonzero(np.r_[True, sorted_slots[1:] != sorted_slots[:-1]]).astype(np.int64)
    groups = sorted_slots[starts]

    range_min32, range_max32 = np.float32(range_min), np.float32(range_max)
    rows = row_stop - row_start
    if floor_guard is None:
        floor_cut = np.full((1, camera.width), np.inf, dtype=np.float32)
    else:
        limits = floor_range_limits(
            x_band, y_table[row_start:row_stop], floor_guard.camera_height, floor_guard.camera_pitch
        )
        floor_cut = (limits - floor_guard.margin).astype(np.float32)
    # Floor pixels are those with r >= cut: the largest value kept is just below the cut.
    max_value_range = np.minimum(range_max32, np.nextafter(floor_cut, np.float32(-np.inf)))

    def at_least_min(codes: IntArray) -> BoolArray:
        return np.asarray(_code_range(codes, range_per_depth) >= range_min32)

    def beyond_max(codes: IntArray) -> BoolArray:
        return np.asarray(_code_range(codes, range_per_depth) > range_max32)

    lowest = np.maximum(_smallest_code(at_least_min, (camera.width,)), 1)
    highest = _smallest_code(beyond_max, (camera.width,)) - 1
    floor_code = None
    if floor_guard is not None:

        def on_floor(codes: IntArray) -> BoolArray:
            return np.asarray(_code_range(codes, range_per_depth) >= floor_cut)

        first_floor = _smallest_code(on_floor, (rows, camera.width))
        # 0 when even the nearest code is on the floor (a margin larger than the limit).
        floor_code = np.clip(np.minimum(first_floor - 1, highest), 0, None).astype(np.uint16)

    pixel_slots = pixel_range_per_depth = None
    if not rows_alike:
        pixel_slots = slot_of(_column_angles(x_band), angle_min, increment, count)
        pixel_range_per_depth = np.sqrt(1.0 + x_band * x_band).astype(np.float32)
    return RowPlan(
        row_start=row_start,
        row_stop=row_stop,
        angle_min=angle_min,
        angle_increment=increment,
        count=count,
        column_order=order,
        group_starts=starts,
        group_slots=groups,
        range_per_depth=range_per_depth,
        range_min=range_min32,
        range_max=range_max32,
        max_value_range=max_value_range.astype(np.float32),
        lowest_code16=np.minimum(lowest, CODE_LIMIT - 1).astype(np.uint16),
        value_span=highest - lowest,
        close_below=lowest - 1,
        highest_code=highest,
        floor_code=floor_code,
        pixel_slots=pixel_slots,
        pixel_range_per_depth=pixel_range_per_depth,
    )


def default_scan_row(camera: CameraModel) -> int:
    """The principal-point row, round(cy), kept inside the image."""
    return min(max(round(camera.cy), 0), camera.height - 1)


def band_rows(height: int, scan_row: int, scan_height: int) -> tuple[int, int]:
    """Rows [start, stop) of a band of `scan_height` rows centred on `scan_row`.

    A band that would cross the top or bottom edge is shifted inside the image.
    """
    start = scan_row - scan_height // 2
    start = min(max(start, 0), height - scan_height)
    return start, start + scan_height


def _check_depth(depth: npt.NDArray[np.generic], camera: CameraModel) -> None:
    if not isinstance(depth, np.ndarray):
        msg = f'depth image must be a numpy array, got {type(depth).__name__}'
        raise InputError(msg)
    if depth.size == 0:
        msg = f'depth image is empty (shape {depth.shape}); pass a full frame from the camera'
        raise InputError(msg)
    camera.check_depth(depth)


def _check_limits(range_min: float, range_max: float) -> None:
    if not (math.isfinite(range_min) and math.isfinite(range_max)):
        msg = f'range_min and range_max must be finite metres, got {range_min} and {range_max}'
        raise ConfigError(msg)
    if range_min < 0.0 or range_max > LARGEST_RANGE:
        msg = (
            f'range limits must lie in [0, {LARGEST_RANGE:g}] metres, got {range_min}, {range_max}'
        )
        raise ConfigError(msg)
    if range_min >= range_max:
        msg = f'range_min ({range_min}) must be smaller than range_max ({range_max})'
        raise ConfigError(msg)


def _check_band(camera: CameraModel, scan_row: int | None, scan_height: int) -> None:
    if scan_height < 1 or scan_height > camera.height:
        msg = (
            f'scan_height {scan_height} must be between 1 and the image height '
            f'({camera.height} rows)'
        )
        raise ConfigError(msg)
    if scan_row is not None and not 0 <= scan_row < camera.height:
        msg = (
            f'scan_row {scan_row} is outside the image rows 0..{camera.height - 1}; '
            'leave it unset for the principal-point row'
        )
        raise ConfigError(msg)


def _check_floor_guard(floor_guard: FloorGuard) -> None:
    check_floor_pose(floor_guard.camera_height, floor_guard.camera_pitch)
    if not math.isfinite(floor_guard.margin) or floor_guard.margin < 0.0:
        msg = (
            f'floor guard margin must be a non-negative number of metres, got {floor_guard.margin}'
        )
        raise ConfigError(msg)


def row_scan(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    *,
    scan_row: int | None = None,
    scan_height: int = 1,
    range_min: float,
    range_max: float,
    d2l_compat: bool = False,
    floor_guard: FloorGuard | None = None,
) -> Scan:
    """Algorithm 1: a LaserScan from one image row, or a band of `scan_height` rows.

    `depth` is the raw image: uint16 millimetres (0 = no measurement) or float32
    metres (NaN = no measurement, +-Inf as REP-118). `scan_row` defaults to the
    principal-point row. With `floor_guard`, pixels at or past the range where their
    line of sight meets the floor (less the margin) are reported as +Inf, so the floor
    is never an obstacle. With `d2l_compat`, the output is that of
    depthimage_to_laserscan (ros2 branch), which only knows the band centred on cy.
    """
    _check_depth(depth, camera)
    _check_limits(range_min, range_max)
    _check_band(camera, scan_row, scan_height)
    if d2l_compat:
        if scan_row is not None:
            msg = (
                'd2l_compat reproduces depthimage_to_laserscan, whose band is always centred '
                'on cy; leave scan_row unset or turn d2l_compat off'
            )
            raise ConfigError(msg)
        if floor_guard is not None:
            msg = (
                'd2l_compat reproduces depthimage_to_laserscan, which has no floor guard; '
                'set floor_guard off or turn d2l_compat off'
            )
            raise ConfigError(msg)
        return _d2l_scan(depth, camera, scan_height, float(range_min), float(range_max))
    if floor_guard is not None:
        _check_floor_guard(floor_guard)
    row = default_scan_row(camera) if scan_row is None else scan_row
    start, stop = band_rows(camera.height, row, scan_height)
    plan = row_plan(
        camera,
        row_start=start,
        row_stop=stop,
        scan_row=row,
        range_min=float(range_min),
        range_max=float(range_max),
        floor_guard=floor_guard,
    )
    return Scan(
        angle_min=plan.angle_min,
        angle_max=plan.angle_max,
        angle_increment=plan.angle_increment,
        range_min=float(range_min),
        range_max=float(range_max),
        ranges=plan.ranges(depth[start:stop]),
        frame_id=camera.frame_id,
    )


# depthimage_to_laserscan compatibility -------------------------------------------------


@dataclass(frozen=True, eq=False)
class D2lPlan:
    """What depthimage_to_laserscan derives from CameraInfo, in its own float precision."""

    angle_min: np.float32
    angle_max: np.float32
    angle_increment: np.float32
    column_offset: FloatArray  # (width,) float(u) - center_x, in float
    constant_x: np.float32
    column_order: IntArray  # columns with an in-bounds index, sorted by index
    group_starts: IntArray
    group_slots: IntArray


def _angle_between_rays(
    ray1: tuple[float, float, float], ray2: tuple[float, float, float]
) -> float:
    dot = ray1[0] * ray2[0] + ray1[1] * ray2[1] + ray1[2] * ray2[2]
    magnitude1 = math.sqrt(ray1[0] ** 2 + ray1[1] ** 2 + ray1[2] ** 2)
    magnitude2 = math.sqrt(ray2[0] ** 2 + ray2[1] ** 2 + ray2[2] ** 2)
    return math.acos(dot / (magnitude1 * magnitude2))


@lru_cache(maxsize=16)
def d2l_plan(camera: CameraModel, unit_scaling: float) -> D2lPlan:
    """Upstream's angle limits and per-column scan index (they depend on the encoding's unit)."""
    # projectPixelTo3dRay of the unrectified pixels (0, cy), (width-1, cy), (cx, cy):
    # image_geometry leaves points as they are when the distortion is all zero.
    left = ((0.0 - camera.cx) / camera.fx, 0.0, 1.0)
    right = ((camera.width - 1 - camera.cx) / camera.fx, 0.0, 1.0)
    centre = ((camera.cx - camera.cx) / camera.fx, 0.0, 1.0)
    if camera.width < 2:
        msg = (
            f'd2l_compat needs an image at least 2 pixels wide, got {camera.width}: '
            'depthimage_to_laserscan divides its field of view by width - 1; '
            'turn d2l_compat off for this camera'
        )
        raise InputError(msg)
    # LaserScan's angle fields are float32.
    angle_max = np.float32(_angle_between_rays(left, centre))
    angle_min = np.float32(-_angle_between_rays(centre, right))
    increment = np.float32((angle_max - angle_min) / np.float32(camera.width - 1))
    if not increment > 0.0:
        msg = (
            f'with fx={camera.fx} the image spans {float(angle_max - angle_min)} rad, too '
            'little for float32 angles to tell its columns apart (depthimage_to_laserscan '
            'divides by the increment); check the CameraInfo or turn d2l_compat off'
        )
        raise InputError(msg)
    center_x = np.float32(camera.cx)
    constant_x = np.float32(unit_scaling / camera.fx)
    column_offset = np.arange(camera.width, dtype=np.float32) - center_x
    index = np.empty(camera.width, dtype=np.int64)
    for u in range(camera.width):
        # th = -atan2((u - center_x) * constant_x, unit_scaling); index truncated to int.
        th = -math.atan2(float(column_offset[u]) * float(constant_x), unit_scaling)
        index[u] = int((th - float(angle_min)) / float(increment))
    # Upstream writes out of bounds for an index outside the scan; such columns are dropped.
    inside = np.flatnonzero((index >= 0) & (index < camera.width))
    order = inside[np.argsort(index[inside], kind='stable')]
    sorted_index = index[order]
    starts = np.flatnonzero(np.r_[True, sorted_index[1:] != sorted_index[:-1]])
    return D2lPlan(
        angle_min=angle_min,
        angle_max=angle_max,
        angle_increment=increment,
        column_offset=column_offset,
        constant_x=constant_x,
        column_order=order.astype(np.int64),
        group_starts=starts.astype(np.int64),
        group_slots=sorted_index[starts],
    )


def d2l_band(camera: CameraModel, scan_height: int) -> tuple[int, int]:
    """Upstream's band: its scan_height check, then offset = int(cy - scan_height / 2.0)."""
    half = scan_height // 2  # integer division, as upstream
    if half > camera.cy or half > camera.height - camera.cy:
        msg = f'scan_height ( {scan_height} pixels) is too large for the image height.'
        raise ConfigError(msg)
    # With 1 <= scan_height <= height (checked before), the check above keeps the band
    # inside the image; a taller band would pass it and upstream would read past the buffer.
    offset = int(camera.cy - scan_height / 2.0)
    return offset, offset + scan_height


def _d2l_pixel_ranges(band: npt.NDArray[np.generic], plan: D2lPlan) -> FloatArray:
    """Upstream's r per pixel, in its precision: x and z in float, r in double, stored float."""
    if band.dtype == np.uint16:
        depth = band.astype(np.float32)
        z = depth * MILLIMETRE  # DepthTraits<uint16_t>::toMeters
        x = (plan.column_offset * depth) * plan.constant_x
        # An invalid code 0 gives r = 0, exactly as upstream computes it.
        ranges: FloatArray = np.sqrt(x.astype(np.float64) ** 2 + z.astype(np.float64) ** 2).astype(
            np.float32
        )
        return ranges
    depth = band.astype(np.float32, copy=False)
    with np.errstate(invalid='ignore', over='ignore'):
        x = (plan.column_offset * depth) * plan.constant_x
        r = np.sqrt(x.astype(np.float64) ** 2 + depth.astype(np.float64) ** 2).astype(np.float32)
    # NaN and +-Inf pass through unchanged (DepthTraits<float>::valid is isfinite).
    passed: FloatArray = np.where(np.isfinite(depth), r, depth)
    return passed


def _d2l_scan(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    scan_height: int,
    range_min: float,
    range_max: float,
) -> Scan:
    """depthimage_to_laserscan's convert_msg, vectorised.

    Its use_point, applied pixel by pixel (rows outer, columns inner) from NaN,
    leaves in each slot: the smallest finite value within [range_min, range_max]
    if there is one (such a value is never replaced by a non-finite one); otherwise
    the last +-Inf met (a +-Inf replaces NaN and +-Inf, never a finite value);
    otherwise NaN. Finite values out of limits never enter.
    """
    start, stop = d2l_band(camera, scan_height)
    band = depth[start:stop]
    # unit_scaling = DepthTraits<T>::toMeters(T(1)): 0.001f widened to double for 16UC1.
    plan = d2l_plan(camera, float(MILLIMETRE) if band.dtype == np.uint16 else 1.0)
    ranges = _d2l_pixel_ranges(band, plan)
    range_min32, range_max32 = np.float32(range_min), np.float32(range_max)
    with np.errstate(invalid='ignore'):
        in_limits = (ranges >= range_min32) & (ranges <= range_max32)
    column_min = np.where(in_limits, ranges, np.float32(np.inf)).min(axis=0)
    row_index = np.arange(band.shape[0], dtype=np.int64)[:, np.newaxis]
    last_inf_row = np.where(np.isinf(ranges), row_index, -1).max(axis=0)
    width = camera.width
    # Position of the last +-Inf in upstream's visiting order (row-major).
    last_inf_key = np.where(last_inf_row >= 0, last_inf_row * width + np.arange(width), -1)

    slot_min = np.minimum.reduceat(column_min[plan.column_order], plan.group_starts)
    slot_key = np.maximum.reduceat(last_inf_key[plan.column_order], plan.group_starts)
    infinities = ranges.ravel()[np.maximum(slot_key, 0)]
    slot_values = np.where(
        np.isfinite(slot_min),
        slot_min,
        np.where(slot_key >= 0, infinities, np.float32(np.nan)),
    )
    out = np.full(width, np.nan, dtype=np.float32)
    out[plan.group_slots] = slot_values
    return Scan(
        angle_min=float(plan.angle_min),
        angle_max=float(plan.angle_max),
        angle_increment=float(plan.angle_increment),
        range_min=range_min,
        range_max=range_max,
        ranges=out,
        frame_id=camera.frame_id,
    )
