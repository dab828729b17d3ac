"""Ground-truth obstacle scan, computed analytically from the obstacles' true geometry.

Per LiDAR slot, the range from the LiDAR origin to the nearest surface whose
height lies inside the collision slab [min_obstacle_height, max_obstacle_height],
anywhere in the slot's angular interval (angle +- half an increment).

Every obstacle is a vertical prism over its footprint polygon, so a surface inside
the slab exists above a footprint point exactly when the obstacle's height span
overlaps the slab, and the nearest such surface in an angular interval is the
nearest point of the footprint boundary there. On one edge the distance, as a
function of the angle, falls to the foot of the perpendicular and rises again,
so its minimum over an interval lies at one of three places, all computed
exactly: where the interval's bounding rays cross the edge, at an edge end
(a polygon vertex) inside the interval, or at the perpendicular's foot inside
the interval. No sub-sampling of the angle is involved. Circles are polygons
inscribed to within 0.2 mm (`worlds.MAX_SAGITTA`).

Heights are above the ground each obstacle stands on (`Obstacle.ground`: 0 on the floor, a
ramp's or a platform's surface under a box on it; `Obstacle.overlaps_slab`). Ramps, platforms
and sills (`worlds.Ground`) are floor and never enter the truth: a ramp's surface is never an
obstacle, a box standing on it is one when its top is inside the slab above the ramp.

A drop-off (`worlds.Drop`, floor missing over a rectangle) is an obstacle whatever the
slab: its footprint joins the obstacles', so each slot's range to the drop's nearest
edge is the range the robot must stop short of.

Ranges beyond the LiDAR's range_max are +Inf; nearer ones, even below range_min,
are reported as they are (the truth does not share the sensor's blind zone).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.scan import AngleGrid
    from scanfuse.sim.worlds import Drop, Obstacle

    Matrix = npt.NDArray[np.float64]

_PARALLEL = 1e-12


class TruthScanner:
    """Ground-truth obstacle scans of a fixed set of obstacles on a fixed angular grid."""

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        grid: AngleGrid,
        *,
        min_obstacle_height: float,
        max_obstacle_height: float,
        range_max: float,
        drops: tuple[Drop, ...] = (),
    ) -> None:
        inside = [
            obstacle.footprint
            for obstacle in obstacles
            if obstacle.overlaps_slab(min_obstacle_height, max_obstacle_height)
        ]
        inside += [drop.footprint for drop in drops]
        starts = inside
        ends = [np.roll(footprint, -1, axis=0) for footprint in inside]
        self.starts = np.concatenate(starts) if starts else np.zeros((0, 2))
        self.ends = np.concatenate(ends) if ends else np.zeros((0, 2))
        self.grid = grid
        self.range_max = range_max
        # Bounding angles of every slot: slot i spans boundaries i and i + 1.
        bounds = grid.angle_min + grid.angle_increment * (np.arange(grid.count + 1) - 0.5)
        self._bound_directions = np.column_stack([np.cos(bounds), np.sin(bounds)])

    def scan(self, x: float, y: float, yaw: float) -> npt.NDArray[np.float32]:
        """Truth ranges for a LiDAR at (x, y) in the world heading `yaw` (radians)."""
        count = self.grid.count
        best = np.full(count, np.inf)
        if self.starts.shape[0] == 0:
            return best.astype(np.float32)
        c, s = math.cos(yaw), math.sin(yaw)
        to_laser = np.array([[c, -s], [s, c]])  # row vectors times this = rotate by -yaw
        a = (self.starts - (x, y)) @ to_laser
        b = (self.ends - (x, y)) @ to_laser
        edge = b - a
        # Seen from outside, the nearest boundary point in any direction lies on an edge
        # that faces the LiDAR (footprints are counter-clockwise: outward normal (dy, -dx)).
        facing = edge[:, 1] * a[:, 0] - edge[:, 0] * a[:, 1] <= 0.0
        a, edge = a[facing], edge[facing]
        b = b[facing]
        if a.shape[0] == 0:  # inside a drop's footprint (the robot fell in): nothing faces it
            return best.astype(np.float32)
        self._bounding_rays(a, edge, best)
        self._points(np.concatenate([a, b]), best)
        self._perpendicular_feet(a, edge, best)
        best[best > self.range_max] = np.inf
        return best.astype(np.float32)

    def _bounding_rays(self, a: Matrix, edge: Matrix, best: npt.NDArray[np.float64]) -> None:
        u = self._bound_directions
        # Ray t*u meets a + s*edge at t = cross(a, edge) / cross(u, edge),
        # s = cross(a, u) / cross(u, edge).
        denom = u[:, 0:1] * edge[None, :, 1] - u[:, 1:2] * edge[None, :, 0]
        cross_a_edge = a[:, 0] * edge[:, 1] - a[:, 1] * edge[:, 0]
        cross_a_u = a[None, :, 0] * u[:, 1:2] - a[None, :, 1] * u[:, 0:1]
        with np.errstate(divide='ignore', invalid='ignore'):
            t = cross_a_edge[None, :] / denom
            along = cross_a_u / denom
        hit = (np.abs(denom) > _PARALLEL) & (t > 0.0) & (along >= 0.0) & (along <= 1.0)
        nearest = np.where(hit, t, np.inf).min(axis=1)
        # Boundary i closes slot i - 1 and opens slot i.
        np.minimum(best, nearest[:-1], out=best)
        np.minimum(best, nearest[1:], out=best)

    def _points(self, points: Matrix, best: npt.NDArray[np.float64]) -> None:
        angles = np.arctan2(points[:, 1], points[:, 0])
        slots = self.grid.slot_of(angles)
        keep = slots >= 0
        np.minimum.at(best, slots[keep], np.hypot(points[keep, 0], points[keep, 1]))

    def _perpendicular_feet(self, a: Matrix, edge: Matrix, best: npt.NDArray[np.float64]) -> None:
        length2 = np.einsum('ij,ij->i', edge, edge)
        with np.errstate(divide='ignore', invalid='ignore'):
            along = -np.einsum('ij,ij->i', a, edge) / length2
        inside = (length2 > 0.0) & (along > 0.0) & (along < 1.0)
        self._points(a[inside] + along[inside, None] * edge[inside], best)
