"""Algorithm 3 (resample) and the conservative resampler.

Both bring a scan onto another scan's angular grid (the LiDAR's). The index
work depends only on the two grids, so it is done once in a plan that the
pipeline keeps; per frame only gathers and minimums remain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.config import Resampler
from scanfuse.scan import TWO_PI, AngleGrid, Scan

if TYPE_CHECKING:
    import numpy.typing as npt

    IndexArray = npt.NDArray[np.intp]
    FloatArray = npt.NDArray[np.float32]


def _source_offsets(source: AngleGrid, target_angles: npt.NDArray[np.float64]) -> np.ndarray:
    """Target angles as fractional source indices, wrapped to the turn centred on the source.

    Index 0 is the source's first reading, count - 1 its last, whatever the sign of
    its increment and whatever angle convention either grid uses.
    """
    centre = source.angle_min + 0.5 * source.angle_increment * (source.count - 1)
    relative = np.mod(target_angles - centre + math.pi, TWO_PI) - math.pi
    return relative / source.angle_increment + 0.5 * (source.count - 1)


@dataclass(frozen=True)
class LinearPlan:
    """Algorithm 3: linear interpolation between the two source readings around each target."""

    lower: IndexArray  # source index below each target; `count` (the NaN pad) outside view
    upper: IndexArray
    nearest: IndexArray
    weight: FloatArray  # share of `upper`

    @classmethod
    def build(cls, source: AngleGrid, target: AngleGrid) -> LinearPlan:
        position = _source_offsets(source, target.angles())
        last = source.count - 1
        # A hair of tolerance so the exact edge angles of the field of view count as inside.
        inside = (position >= -1e-6) & (position <= last + 1e-6)
        position = np.clip(position, 0.0, last)
        lower = np.minimum(np.floor(position).astype(np.intp), last)
        upper = np.minimum(lower + 1, last)
        weight = (position - lower).astype(np.float32)
        nearest = np.where(weight < 0.5, lower, upper)
        outside = source.count
        return cls(
            np.where(inside, lower, outside),
            np.where(inside, upper, outside),
            np.where(inside, nearest, outside),
            weight,
        )

    def apply(self, ranges: FloatArray) -> FloatArray:
        padded = np.append(ranges, np.float32(np.nan))
        low = padded[self.lower]
        high = padded[self.upper]
        with np.errstate(invalid='ignore'):
            blended = low + self.weight * (high - low)
        # Interpolating towards +-Inf or NaN means nothing (the blend is not finite
        # exactly then): take the nearer reading. Outside the view both are the NaN pad.
        out: FloatArray = np.where(np.isfinite(blended), blended, padded[self.nearest])
        return out


@dataclass(frozen=True)
class ConservativePlan:
    """Per target slot, the minimum of every source reading whose interval overlaps the slot.

    Never interpolates: across a depth edge the slot takes the nearer side, so no
    phantom range appears in the free space between a leg and the wall behind it.
    REP-117 order of the minimum: -Inf < finite < +Inf, NaN only where nothing else.
    """

    gather: npt.NDArray[np.intp]  # (width, slots) source indices; `count` means none

    @classmethod
    def build(cls, source: AngleGrid, target: AngleGrid) -> ConservativePlan:
        centre = _source_offsets(source, target.angles())
        half = 0.5 * abs(target.angle_increment / source.angle_increment)
        # Source reading i covers [i - 0.5, i + 0.5] in index units; overlap is strict.
        first = np.floor(centre - half - 0.5).astype(np.intp) + 1
        last = np.ceil(centre + half + 0.5).astype(np.intp) - 1
        first = np.maximum(first, 0)
        last = np.minimum(last, source.count - 1)
        span = np.maximum(last - first + 1, 0)
        width = max(int(span.max()), 1)
        offsets = np.arange(width, dtype=np.intp)[:, np.newaxis]
        gather = np.where(offsets < span, first + offsets, source.count)
        return cls(gather)

    def apply(self, ranges: FloatArray) -> FloatArray:
        # Index `count` is the appended NaN, which fmin ignores.
        padded = np.append(ranges, np.float32(np.nan))
        nearest: FloatArray = np.fmin.reduce(padded[self.gather], axis=0)
        return nearest


Plan = LinearPlan | ConservativePlan


def build_plan(kind: Resampler, source: AngleGrid, target: AngleGrid) -> Plan:
    if kind is Resampler.LINEAR:
        return LinearPlan.build(source, target)
    return ConservativePlan.build(source, target)


def apply_plan(plan: Plan, scan: Scan, target: Scan | AngleGrid) -> Scan:
    """Algorithm 3's header rule: the depth scan's header, times and limits, the target's angles."""
    grid = target.grid if isinstance(target, Scan) else target
    return Scan(
        angle_min=grid.angle_min,
        angle_max=grid.angle_max,
        angle_increment=grid.angle_increment,
        range_min=scan.range_min,
        range_max=scan.range_max,
        ranges=plan.apply(scan.ranges),
        time_increment=scan.time_increment,
        scan_time=scan.scan_time,
        frame_id=scan.frame_id,
        stamp_ns=scan.stamp_ns,
    )


def resample(kind: Resampler, scan: Scan, target: Scan | AngleGrid) -> Scan:
    grid = target.grid if isinstance(target, Scan) else target
    return apply_plan(build_plan(kind, scan.grid, grid), scan, grid)


def resample_linear(scan: Scan, target: Scan | AngleGrid) -> Scan:
    """Algorithm 3 (resample): linear interpolation onto `target`'s angles, NaN outside view."""
    return resample(Resampler.LINEAR, scan, target)


def resample_conservative(scan: Scan, target: Scan | AngleGrid) -> Scan:
    """Minimum of the source readings inside each target slot; NaN outside the source's view."""
    return resample(Resampler.CONSERVATIVE, scan, target)
