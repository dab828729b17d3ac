"""A Nav2-like obstacle layer for the evaluation's navigator: marking and raytrace clearing.

What the closed loop forgets should be what Nav2 forgets, so the grid follows
nav2_costmap_2d's ObstacleLayer with the observation source of
examples/nav2_scanfuse.yaml (`inf_is_valid: true`, obstacle_max_range 2.5 m,
raytrace_max_range 3.0 m):

- a reading is projected like laser_geometry does: +Inf (a free ray, REP-117) becomes
  range_max - 0.1 mm (ObstacleLayer::laserScanValidInfCallback), NaN and -Inf are
  dropped, and so is anything outside [range_min, range_max);
- clearing first (ObstacleLayer::raytraceFreespace): every kept ray frees the cells from
  its origin to its end, the end cell included (Costmap2D::raytraceLine), cut at
  raytrace_max_range;
- then marking: the end of every kept ray nearer than obstacle_max_range is lethal;
- a cell stays lethal until a later ray clears it (no decay), and the robot's own
  footprint is cleared (footprint_clearing_enabled).

So a low obstacle the scan stops showing is erased by the next ray that passes over it.
Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.evaluate.mapping import GridSpec
    from scanfuse.scan import Scan

OBSTACLE_MAX_RANGE = 2.5  # metres, examples/nav2_scanfuse.yaml
RAYTRACE_MAX_RANGE = 3.0
INF_EPSILON = 1e-4  # laserScanValidInfCallback: range_max - epsilon


@dataclass
class Costmap:
    """Lethal cells from the scans it was given; `lethal[row, column]`, row 0 at the lowest y."""

    spec: GridSpec
    obstacle_max_range: float = OBSTACLE_MAX_RANGE
    obstacle_min_range: float = 0.0
    raytrace_max_range: float = RAYTRACE_MAX_RANGE
    raytrace_min_range: float = 0.0
    lethal: npt.NDArray[np.bool_] = field(init=False)

    def __post_init__(self) -> None:
        ranges = (
            self.obstacle_min_range,
            self.obstacle_max_range,
            self.raytrace_min_range,
            self.raytrace_max_range,
        )
        if not all(math.isfinite(r) and r >= 0.0 for r in ranges):
            msg = f'costmap ranges must be finite and not negative, got {ranges}'
            raise InputError(msg)
        self.lethal = np.zeros((self.spec.height, self.spec.width), dtype=np.bool_)

    def update(self, scan: Scan, x: float, y: float, yaw: float) -> None:
        """Clear along and mark at the end of every ray of `scan` taken from (x, y, yaw)."""
        ranges = scan.ranges.astype(np.float64)
        ranges = np.where(np.isposinf(ranges), scan.range_max - INF_EPSILON, ranges)
        with np.errstate(invalid='ignore'):
            kept = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges < scan.range_max)
        angles = scan.angles()[kept] + yaw
        ranges = ranges[kept]
        cos, sin = np.cos(angles), np.sin(angles)
        # Clearing: samples every half cell from the raytrace minimum to the ray's end
        # (cut at the raytrace maximum), the end itself included.
        length = np.minimum(ranges, self.raytrace_max_range)
        step = 0.5 * self.spec.resolution
        count = math.ceil(self.raytrace_max_range / step) + 1
        s = self.raytrace_min_range + step * np.arange(count)
        along = np.minimum(s[None, :], length[:, None])
        reach = length[:, None] >= self.raytrace_min_range
        self._set(x + along * cos[:, None], y + along * sin[:, None], reach, value=False)
        # Marking: the ends nearer than the obstacle maximum.
        marked = (ranges < self.obstacle_max_range) & (ranges >= self.obstacle_min_range)
        self._set(x + ranges * cos, y + ranges * sin, marked, value=True)

    def clear_disk(self, x: float, y: float, radius: float) -> None:
        """Free the cells whose centres lie within `radius` of (x, y) (the footprint)."""
        xs, ys = self.spec.centres()
        inside = (xs - x) ** 2 + (ys - y) ** 2 <= radius * radius
        self.lethal[inside] = False

    def _set(
        self,
        xs: npt.NDArray[np.float64],
        ys: npt.NDArray[np.float64],
        where: npt.NDArray[np.bool_],
        *,
        value: bool,
    ) -> None:
        where = np.broadcast_to(where, xs.shape)
        column, row, inside = self.spec.cell_of(xs[where], ys[where])
        self.lethal[row[inside], column[inside]] = value
