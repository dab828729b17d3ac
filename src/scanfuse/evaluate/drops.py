"""False drop slots: what reporting drop-offs costs on worlds that have none.

Definition (the report states it too): on a world without drop-offs, a slot is a
**false drop slot** when

1. the fused range is shorter than the ground-truth obstacle scan by more than the
   tolerance (a false obstacle, `metrics.false_obstacle_slots`), and
2. the fused point lies on open floor: no footprint of an obstacle inside the
   collision slab (walls included) within `OPEN_FLOOR` (0.3 m) of it, measured in
   the plane at the scan's true pose.

A drop-off is reported where a line of sight into it crosses the floor plane, so a
false one lands on the floor short of the truth; condition 2 leaves out what lands
beside obstacles (mixed pixels at silhouettes, phantom edges), which detect_drops
does not cause. Floor noise that rises into the slab on open floor passes both
conditions too: the count is an upper bound on the slots drops add, and the `lidar`
and `obstacle-no-memory` rows show what the same count is without them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.evaluate.metrics import Tolerance, false_obstacle_slots

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.scan import AngleGrid
    from scanfuse.sim.worlds import Obstacle

OPEN_FLOOR = 0.3  # metres from any obstacle footprint for a point to be on open floor


def distance_to_footprints(
    points: npt.NDArray[np.float64], footprints: list[npt.NDArray[np.float64]]
) -> npt.NDArray[np.float64]:
    """Distance from each (N, 2) point to the nearest footprint (0 inside one), metres."""
    nearest = np.full(points.shape[0], np.inf)
    if points.shape[0] == 0:
        return nearest
    for footprint in footprints:
        start = footprint
        edge = np.roll(footprint, -1, axis=0) - start
        offset = points[:, None, :] - start[None, :, :]
        length2 = np.einsum('ij,ij->i', edge, edge)
        along = np.clip(np.einsum('nij,ij->ni', offset, edge) / np.maximum(length2, 1e-18), 0, 1)
        closest = start[None] + along[..., None] * edge[None]
        distance = np.hypot(*(points[:, None, :] - closest).transpose(2, 0, 1)).min(axis=1)
        # Counter-clockwise footprints: a point left of every edge lies inside.
        cross = edge[None, :, 0] * offset[..., 1] - edge[None, :, 1] * offset[..., 0]
        inside = np.all(cross >= 0.0, axis=1)
        np.minimum(nearest, np.where(inside, 0.0, distance), out=nearest)
    return nearest


@dataclass
class FalseDropCounter:
    """Counts false drop slots of one world's scans (module docstring)."""

    footprints: list[npt.NDArray[np.float64]]
    grid: AngleGrid
    lidar_yaw: float = 0.0
    tolerance: Tolerance = field(default_factory=Tolerance)
    open_floor: float = OPEN_FLOOR

    @classmethod
    def of(
        cls,
        obstacles: tuple[Obstacle, ...],
        grid: AngleGrid,
        slab: tuple[float, float],
        lidar_yaw: float = 0.0,
    ) -> FalseDropCounter:
        footprints = [o.footprint for o in obstacles if o.overlaps_slab(*slab)]
        return cls(footprints, grid, lidar_yaw)

    def mask(
        self,
        fused: npt.NDArray[np.float32],
        truth: npt.NDArray[np.float32],
        origin: tuple[float, float],
        heading: float,
    ) -> npt.NDArray[np.bool_]:
        """False drop slots of one scan taken at `origin` looking along `heading` (world)."""
        short = false_obstacle_slots(fused, truth, self.tolerance) & np.isfinite(fused)
        found = np.zeros(fused.shape, dtype=bool)
        if not short.any():
            return found
        angles = self.grid.angles()[short] + heading + self.lidar_yaw
        ranges = np.maximum(fused[short].astype(np.float64), 0.0)
        points = np.column_stack(
            [origin[0] + ranges * np.cos(angles), origin[1] + ranges * np.sin(angles)]
        )
        found[short] = distance_to_footprints(points, self.footprints) > self.open_floor
        return found


@dataclass
class DropTally:
    """False drop slots and all slots counted, over the scans of worlds without drop-offs."""

    slots: int = 0
    false_drops: int = 0

    def add(self, mask: npt.NDArray[np.bool_]) -> None:
        self.slots += int(mask.size)
        self.false_drops += int(mask.sum())

    @property
    def rate(self) -> float:
        return self.false_drops / self.slots if self.slots else math.nan
