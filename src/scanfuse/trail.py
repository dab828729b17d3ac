"""The ground the robot drove over: a LiDAR reading that lies on it is the floor.

A 2D LiDAR's plane is parallel to the base. When the body pitches (over a ramp's foot or
crest, braking on a sprung chassis), or stands on ground that is not level with the ground
around it (half-way up a ramp the floor behind it lies lower), the plane meets the floor
a metre or two away, and the LiDAR reports the floor as a wall: behind and beside the
robot, where no camera looks.

With an IMU (the base's pitch and roll) and odometry the stream keeps the ground under the
path the robot drove, in the odometry frame: the base's height is summed along the path
(each step climbs its length along the base's tilted axes, `GroundTrail.advance`), and
every cell within `half_width` of the base takes the height of the plane the wheels stand
on there (the nearest pass's: the ground beside the path is taken to go on as under it,
as a corridor's or a ramp's does). A LiDAR reading whose point, tilted the same way (by
the tilt when its beam was measured, where the stream knows it: a sprung body rocks
degrees within one sweep), lies within `tolerance` of a known cell's ground is the floor
(`on_ground`): the stream drops it (NaN, no reading), and what a camera or the memory sees
there stands.

Where the trail begins (the node's start, an odometry reset), the plane the wheels stand on
is taken out to `start_radius`, not just `half_width`: the robot was parked on that floor,
and up a 1:8 ramp a LiDAR 0.3 m up meets the level floor 2.4 m back, behind where it set off.

The base's height is summed with the body's pitch, which on a sprung body is not only the
ground's: up a 1:8 ramp it sags 2 degrees more on its suspension, and the sum runs 6-7 cm
ahead of the ramp in 1.5 m. A pitched plane meets the floor along a line, so a scan holds
tens of readings of known ground, all that drift above it: their common height above their
cells (`_drift`, at most `max_drift`) is taken as the drift, and a reading within
`tolerance` of it is the floor too.

A reading is dropped only where the robot has been (or around where it began): an obstacle
there stands above the ground by more than `tolerance` (and, with a drift, than the drift's
window) wherever the LiDAR's plane meets it (the plane is `lidar_height` above the base),
except near its foot. A low obstacle that only a pitched plane reaches, and a level one
passes over, may be dropped: the camera and the memory keep what stands in the slab.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.motion import PlanarPose

    F64 = npt.NDArray[np.float64]

# A step longer than this between two scans is odometry jumping, not driving: start anew.
MAX_STEP = 0.5  # metres
_NO_CELL = np.iinfo(np.int64).min


@dataclass(frozen=True)
class TrailSettings:
    """`half_width`: metres either side of the base's origin whose ground the trail keeps;
    `cell`: the grid's cell, metres; `length`: metres of path after which a cell is
    forgotten (the height summed along the path drifts); `tolerance`: metres above or
    below a cell's ground a reading may lie and still be the floor; `start_radius`: metres
    around where the trail begins whose ground it takes (at most `length` + `half_width`);
    `max_drift`: metres the summed height may have drifted, as `drift_readings` readings
    of one scan on known ground show it (`GroundTrail._drift`)."""

    half_width: float = 1.0
    cell: float = 0.1
    length: float = 8.0
    tolerance: float = 0.05
    start_radius: float = 4.0
    max_drift: float = 0.12
    drift_readings: int = 20

    @property
    def side(self) -> int:
        """Cells along each side of the rolling grid: every cell the kept path can reach."""
        return math.ceil(2.0 * (self.length + self.half_width) / self.cell) + 1


class GroundTrail:
    """The ground under the path driven, on a rolling grid in the odometry frame."""

    def __init__(self, settings: TrailSettings | None = None) -> None:
        self.settings = settings or TrailSettings()
        side = self.settings.side
        self._keys = np.full((side, side, 2), _NO_CELL, dtype=np.int64)
        self._ground = np.zeros((side, side))
        self._reach = np.zeros((side, side))  # the writer's distance from the cell
        self._written = np.zeros((side, side))  # the path length when it was written
        self._pose: PlanarPose | None = None
        self._segment: int | None = None
        self._height = 0.0  # the base's height above where the trail began
        self._travelled = 0.0
        self._last_write: float | None = None  # the path length at the last write
        self._lowest, self._highest = math.inf, -math.inf  # the ground heights written
        self._start_radius = min(
            max(self.settings.start_radius, self.settings.half_width),
            self.settings.length + self.settings.half_width,
        )
        self._offsets = _disc(self.settings.half_width, self.settings.cell)
        self._start_offsets = _disc(self._start_radius, self.settings.cell)

    def clear(self) -> None:
        self._keys[...] = _NO_CELL
        self._pose = None
        self._segment = None
        self._height = 0.0
        self._travelled = 0.0
        self._last_write = None
        self._lowest, self._highest = math.inf, -math.inf

    def advance(self, pose: PlanarPose, tilt: F64, segment: int) -> None:
        """The base at `pose` (odometry), tilted by `tilt` (3x3, base to a level frame of
        the same heading: the IMU's), in odometry segment `segment` (a new one: odometry
        was reset, the trail starts anew); its ground is written around it."""
        last = self._pose
        if last is not None and segment == self._segment:
            step = math.hypot(pose.x - last.x, pose.y - last.y)
            if step > MAX_STEP:
                self.clear()
            else:
                self._height += self._climb(pose, tilt, last)
                self._travelled += step
        else:
            self.clear()
        self._pose, self._segment = pose, segment
        # Half a cell of travel changes no cell's height by much: write no more often.
        if self._last_write is None:
            self._write(pose, tilt, self._start_radius, self._start_offsets)
            self._last_write = self._travelled
        elif self._travelled - self._last_write >= 0.5 * self.settings.cell:
            self._write(pose, tilt, self.settings.half_width, self._offsets)
            self._last_write = self._travelled

    def on_ground(
        self, points: F64, pose: PlanarPose, tilt: F64, beams: F64 | None = None
    ) -> npt.NDArray[np.bool_]:
        """Which of `points` (N x 3, base frame, of the base at `pose` tilted by `tilt`)
        lie within `tolerance` of the ground of a cell the trail knows. `beams` (N x 3 x 3),
        when given, is the base's tilt when each point was measured (`ImuHistory.tilts_over`:
        a LiDAR's sweep takes a tenth of a second, in which a sprung body rocks degrees)."""
        settings = self.settings
        if self._pose is None or not points.size:
            return np.zeros(len(points), dtype=np.bool_)
        found = np.zeros(len(points), dtype=np.bool_)
        level = points @ tilt.T if beams is None else np.einsum('nij,nj->ni', beams, points)
        # Only points at a height some cell's ground has can lie on it (a LiDAR's points
        # stand its height above the base: on a level floor, none).
        z = self._height + self._climb(pose, tilt, self._pose) + level[:, 2]
        reach = settings.tolerance + settings.max_drift
        near = np.flatnonzero((z >= self._lowest - reach) & (z <= self._highest + reach))
        if not near.size:
            return found
        level = level[near]
        z = z[near]
        cosine, sine = math.cos(pose.yaw), math.sin(pose.yaw)
        x = pose.x + cosine * level[:, 0] - sine * level[:, 1]
        y = pose.y + sine * level[:, 0] + cosine * level[:, 1]
        ix = np.floor(x / settings.cell).astype(np.int64)
        iy = np.floor(y / settings.cell).astype(np.int64)
        side = settings.side
        row, column = ix % side, iy % side
        known = (self._keys[row, column, 0] == ix) & (self._keys[row, column, 1] == iy)
        known &= self._written[row, column] >= self._travelled - settings.length
        above = z - self._ground[row, column]
        on = known & (np.abs(above) <= settings.tolerance)
        drift = self._drift(above[known])
        if drift:
            on |= known & (np.abs(above - drift) <= settings.tolerance)
        found[near] = on
        return found

    def _drift(self, above: F64) -> float:
        """How far the heights summed since the trail's cells were written have drifted,
        as this scan's readings on them show (0: they do not show it), from `above`: the
        readings' heights above the ground of their (known) cells.

        The base's height is summed with the body's pitch, and a sprung body pitches on its
        suspension, not only with the ground (2 degrees more up a 1:8 ramp: 7 cm in 1.5 m).
        Readings of the floor (a pitched plane meets it along a line, tens of them) then stand
        at one height above their cells, and outnumber those of any low obstacle's face the
        plane cuts near the ground. The median of the readings within `max_drift` (and
        `tolerance`) of their cells is the drift when `drift_readings` of them lie within
        `tolerance` of it."""
        settings = self.settings
        candidates = above[np.abs(above) <= settings.max_drift + settings.tolerance]
        if candidates.size < settings.drift_readings:
            return 0.0
        drift = float(np.median(candidates))
        agree = int(np.count_nonzero(np.abs(candidates - drift) <= settings.tolerance))
        if agree < settings.drift_readings or abs(drift) > settings.max_drift:
            return 0.0
        return drift

    @staticmethod
    def _climb(pose: PlanarPose, tilt: F64, last: PlanarPose) -> float:
        """The height gained from `last` to `pose`: the step along the base's axes, each
        rising as `tilt` says."""
        dx, dy = pose.x - last.x, pose.y - last.y
        cosine, sine = math.cos(pose.yaw), math.sin(pose.yaw)
        forward, sideways = cosine * dx + sine * dy, -sine * dx + cosine * dy
        return float(forward * tilt[2, 0] + sideways * tilt[2, 1])

    def _write(
        self, pose: PlanarPose, tilt: F64, radius: float, offsets: npt.NDArray[np.int64]
    ) -> None:
        """Every cell within `radius` of the base (`offsets`: `_disc(radius)`): the height
        of the plane the base stands on there, unless a pass nearer to the cell wrote it."""
        settings = self.settings
        cell = settings.cell
        ix = np.floor(pose.x / cell).astype(np.int64) + offsets[:, 0]
        iy = np.floor(pose.y / cell).astype(np.int64) + offsets[:, 1]
        dx, dy = (ix + 0.5) * cell - pose.x, (iy + 0.5) * cell - pose.y
        reach = np.hypot(dx, dy)
        near = reach <= radius
        ix, iy, dx, dy, reach = ix[near], iy[near], dx[near], dy[near], reach[near]
        # The base's plane: its normal (the base's up axis) in the level frame.
        normal = tilt[:, 2]
        cosine, sine = math.cos(pose.yaw), math.sin(pose.yaw)
        forward, sideways = cosine * dx + sine * dy, -sine * dx + cosine * dy
        ground = self._height - (normal[0] * forward + normal[1] * sideways) / normal[2]
        side = settings.side
        row, column = ix % side, iy % side
        same = (self._keys[row, column, 0] == ix) & (self._keys[row, column, 1] == iy)
        fresh = self._written[row, column] >= self._travelled - settings.length
        nearer = reach <= self._reach[row, column] + 0.5 * cell
        take = ~(same & fresh) | nearer
        row, column = row[take], column[take]
        if row.size:
            self._lowest = min(self._lowest, float(ground[take].min()))
            self._highest = max(self._highest, float(ground[take].max()))
        self._keys[row, column, 0] = ix[take]
        self._keys[row, column, 1] = iy[take]
        self._ground[row, column] = ground[take]
        self._reach[row, column] = reach[take]
        self._written[row, column] = self._travelled


def _disc(radius: float, cell: float) -> npt.NDArray[np.int64]:
    """The cell offsets (N x 2) of a square holding a disc of `radius` metres."""
    reach = math.ceil(radius / cell)
    offsets = np.arange(-reach, reach + 1)
    return np.stack(np.meshgrid(offsets, offsets, indexing='ij'), -1).reshape(-1, 2)
