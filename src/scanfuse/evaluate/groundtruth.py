"""Per-slot ground truth of a simulated scan: slab truth, LiDAR-plane truth, kind, camera view.

Built from the world's true obstacle geometry with the simulator's exact
`TruthScanner`, one per obstacle, so that each slot also knows which obstacle
(and so which kind) is nearest in it. A drop-off (`worlds.Drop`) is one more
obstacle, of its own kind (ledge, stairs, hole), at floor level and below the
LiDAR's plane: the plane never sees it.

On terrain (ramps, platforms: `worlds.Ground`) the slab's heights are above the ground each
obstacle stands on (`Obstacle.ground`): the ramp itself is floor, never an obstacle, and a box
on it is one. Which obstacles the LiDAR's plane crosses is decided per scan at the LiDAR's
true height (`LidarFrame.origin`): on a platform its plane lies higher.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.evaluate.mapping import GridSpec, rasterize_footprints
from scanfuse.evaluate.metrics import SlotTruth, near_footprint_slots
from scanfuse.memory import slab_points
from scanfuse.sim.truth import TruthScanner

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import AngleGrid
    from scanfuse.sim.simulation import LidarFrame
    from scanfuse.sim.worlds import Drop, Obstacle
    from scanfuse.transforms import Extrinsics, Transform

# Recall counts low obstacles the camera sees within this distance (the 3 m).
VIEW_RANGE = 3.0
# `SeenSurfaces`: cells this size; a pixel shows an obstacle when it falls in a cell its
# footprint touches or one beside it (within one cell: inside the 5 cm tolerance).
SEEN_CELL = 0.025
# A drop's edge is shown by floor pixels this near the floor plane, metres.
FLOOR_BAND = 0.03


class SeenSurfaces:
    """Which places of a world's slab obstacles (and drop-offs) the depth camera has shown.

    Each depth image, placed at the camera's true pose, marks the cells of its slab pixels
    that lie on an obstacle's footprint (within a cell), and of its floor pixels that lie
    on a drop's edge; a place counts as shown when its cell or one beside it is marked
    (`shown`). Noise-free placement (the simulator's true pose): it says what the camera
    showed, whatever the robot's odometry believed.
    """

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        bounds: tuple[float, float, float, float],
        *,
        slab: tuple[float, float],
        range_min: float,
        range_max: float,
        drops: tuple[Drop, ...] = (),
    ) -> None:
        self.spec = GridSpec.covering(bounds, SEEN_CELL, margin=0.3)
        self.slab = slab
        self.range_min = range_min
        self.range_max = range_max
        polygons = [o.footprint for o in obstacles if o.overlaps_slab(*slab)]
        self._on_obstacle = _grow(rasterize_footprints(self.spec, polygons))
        rectangles = [
            np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
            for x0, x1, y0, y1 in (drop.rectangle for drop in drops)
        ]
        self._on_drop = _grow(rasterize_footprints(self.spec, rectangles)) if drops else None
        self.marked = np.zeros((self.spec.height, self.spec.width), dtype=bool)

    def add(self, depth: npt.NDArray[np.generic], camera: CameraModel, pose: Transform) -> None:
        """One depth image; `pose` is its optical frame in the world (z = 0 the floor)."""
        for slab, surface in (
            (self.slab, self._on_obstacle),
            ((-FLOOR_BAND, FLOOR_BAND), self._on_drop),
        ):
            if surface is not None:
                points = slab_points(
                    depth, camera, pose, slab=slab, range_min=self.range_min,
                    range_max=self.range_max,
                )  # fmt: skip
                self._mark(points, surface)

    def _mark(
        self,
        points: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
        surface: npt.NDArray[np.bool_],
    ) -> None:
        column, row, inside = self.spec.cell_of(*points)
        column, row = column[inside], row[inside]
        on = surface[row, column]
        self.marked[row[on], column[on]] = True

    def shown(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.bool_]:
        """Whether each place (world frame) lies in a marked cell or one beside it."""
        column, row, inside = self.spec.cell_of(x, y)
        near = _grow(self.marked)
        found: npt.NDArray[np.bool_] = np.zeros(x.shape, dtype=bool)
        found[inside] = near[row[inside], column[inside]]
        return found


def _grow(mask: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """`mask` and every cell beside a set cell (the eight neighbours)."""
    padded = np.pad(mask, 1)
    grown = np.zeros_like(mask)
    height, width = mask.shape
    for dy in range(3):
        for dx in range(3):
            grown |= padded[dy : dy + height, dx : dx + width]
    return grown


class SlotTruthBuilder:
    """Builds `SlotTruth` for LiDAR frames of one world and robot."""

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        grid: AngleGrid,
        *,
        min_obstacle_height: float,
        max_obstacle_height: float,
        range_max: float,
        camera: CameraModel,
        extrinsics: Extrinsics,
        view_range: float = VIEW_RANGE,
        drops: tuple[Drop, ...] = (),
        footprint_radius: float | None = None,
        more_cameras: Sequence[tuple[CameraModel, Extrinsics]] = (),
        seen: SeenSurfaces | None = None,
    ) -> None:
        """`more_cameras`: other cameras (each with the same LiDAR in its extrinsics) whose
        view counts as in view too (a robot with a rear camera)."""
        self.grid = grid
        self.seen = seen
        in_slab = [
            o for o in obstacles if o.overlaps_slab(min_obstacle_height, max_obstacle_height)
        ]
        self._kinds = np.array(
            [o.kind for o in in_slab] + [d.kind for d in drops] + [''], dtype=np.str_
        )
        # A drop's edge is at floor level: the camera must see the floor there. Tops in the
        # world's z: the slab's top is above the ground the obstacle stands on.
        self._tops = np.array(
            [min(o.z_max, o.ground + max_obstacle_height) for o in in_slab]
            + [0.0] * len(drops)
            + [0.0],
            dtype=np.float64,
        )
        # Height spans (world z) of what the LiDAR's plane may cross; drops never.
        self._spans = np.array(
            [(o.z_min, o.z_max) for o in in_slab] + [(np.inf, -np.inf)] * len(drops),
            dtype=np.float64,
        ).reshape(-1, 2)
        self._scanners = [
            TruthScanner(
                (obstacle,),
                grid,
                min_obstacle_height=min_obstacle_height,
                max_obstacle_height=max_obstacle_height,
                range_max=range_max,
            )
            for obstacle in in_slab
        ]
        self._scanners += [
            TruthScanner(
                (),
                grid,
                min_obstacle_height=min_obstacle_height,
                max_obstacle_height=max_obstacle_height,
                range_max=range_max,
                drops=(drop,),
            )
            for drop in drops
        ]
        self.camera = camera
        self.view_range = view_range
        # Per camera: laser frame -> optical frame, to project truth points into the image,
        # and the camera's origin in the laser frame.
        self._views = [
            (
                model,
                view.laser_to_camera_optical.inverse(),
                np.asarray(view.laser_to_camera_optical.translation),
            )
            for model, view in ((camera, extrinsics), *more_cameras)
        ]
        self._lidar_yaw = extrinsics.base_to_laser.rpy()[2]
        # The round footprint about the base's origin, in the LiDAR's frame (all-around recall).
        self.footprint_radius = footprint_radius
        base_in_laser = extrinsics.base_to_laser.inverse().translation
        self._base_in_laser = (float(base_in_laser[0]), float(base_in_laser[1]))

    def per_obstacle(self, x: float, y: float, yaw: float) -> npt.NDArray[np.float32]:
        """(obstacles, slots) truth ranges of each obstacle on its own."""
        if not self._scanners:
            return np.full((0, self.grid.count), np.inf, dtype=np.float32)
        return np.stack([scanner.scan(x, y, yaw) for scanner in self._scanners])

    def build(self, frame: LidarFrame) -> SlotTruth:
        origin = frame.origin
        heading = frame.pose.yaw + self._lidar_yaw
        ranges = self.per_obstacle(origin[0], origin[1], heading)
        count = self.grid.count
        if ranges.shape[0] == 0:
            empty = np.full(count, np.inf, dtype=np.float32)
            return SlotTruth(empty, empty, np.full(count, '', dtype=np.str_), np.zeros(count, bool))
        nearest = np.argmin(ranges, axis=0)
        truth = ranges[nearest, np.arange(count)]
        found = np.isfinite(truth)
        index = np.where(found, nearest, len(self._scanners))
        height = origin[2]  # the LiDAR's plane, in the world's z
        crosses = (self._spans[:, 0] <= height) & (height <= self._spans[:, 1])
        plane = ranges[crosses].min(axis=0) if crosses.any() else np.full(count, np.inf, np.float32)
        in_view = found & self._visible(truth, self._tops[index], height)
        truth = truth.astype(np.float32)
        near = (
            None
            if self.footprint_radius is None
            else near_footprint_slots(
                truth, self.grid.angles(), self._base_in_laser, self.footprint_radius
            )
        )
        shown = None
        if self.seen is not None:
            along = np.where(found, truth, 0.0).astype(np.float64)
            bearing = heading + self.grid.angles()
            places = (origin[0] + along * np.cos(bearing), origin[1] + along * np.sin(bearing))
            shown = found & self.seen.shown(*places)
        return SlotTruth(truth, plane, self._kinds[index], in_view, near, shown)

    def _visible(
        self, ranges: npt.NDArray[np.float32], tops: npt.NDArray[np.float64], height: float
    ) -> npt.NDArray[np.bool_]:
        """Slots whose obstacle top (at the truth range) projects into an image within range;
        `height` the LiDAR's in the world (the robot level on its ground)."""
        angles = self.grid.angles()
        finite = np.where(np.isfinite(ranges), ranges, 0.0).astype(np.float64)
        points = np.column_stack([finite * np.cos(angles), finite * np.sin(angles), tops - height])
        visible: npt.NDArray[np.bool_] = np.zeros(len(points), dtype=bool)
        for camera, laser_to_optical, camera_in_laser in self._views:
            optical = laser_to_optical.apply(points)
            z = optical[:, 2]
            with np.errstate(divide='ignore', invalid='ignore'):
                u = camera.fx * optical[:, 0] / z + camera.cx
                v = camera.fy * optical[:, 1] / z + camera.cy
            horizontal = np.hypot(
                points[:, 0] - camera_in_laser[0], points[:, 1] - camera_in_laser[1]
            )
            visible |= (
                (z > 0.0)
                & (u >= -0.5)
                & (u <= camera.width - 0.5)
                & (v >= -0.5)
                & (v <= camera.height - 0.5)
                & (horizontal <= self.view_range)
            )
        return visible
