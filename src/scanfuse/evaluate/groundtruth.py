"""Per-slot ground truth of a simulated scan: slab truth, LiDAR-plane truth, kind, camera view.

Built from the world's true obstacle geometry with the simulator's exact
`TruthScanner`, one per obstacle, so that each slot also knows which obstacle
(and so which kind) is nearest in it. A drop-off (`worlds.Drop`) is one more
obstacle, of its own kind (ledge, stairs, hole), at floor level and below the
LiDAR's plane: the plane never sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.evaluate.metrics import SlotTruth, near_footprint_slots
from scanfuse.sim.truth import TruthScanner

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import AngleGrid
    from scanfuse.sim.simulation import LidarFrame
    from scanfuse.sim.worlds import Drop, Obstacle
    from scanfuse.transforms import Extrinsics

# Recall counts low obstacles the camera sees within this distance (the 3 m).
VIEW_RANGE = 3.0


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
    ) -> None:
        """`more_cameras`: other cameras (each with the same LiDAR in its extrinsics) whose
        view counts as in view too (a robot with a rear camera)."""
        self.grid = grid
        lidar_height = extrinsics.base_to_laser.translation[2]
        in_slab = [
            o for o in obstacles if o.overlaps_slab(min_obstacle_height, max_obstacle_height)
        ]
        self._kinds = np.array(
            [o.kind for o in in_slab] + [d.kind for d in drops] + [''], dtype=np.str_
        )
        # A drop's edge is at floor level: the camera must see the floor there.
        self._tops = np.array(
            [min(o.z_max, max_obstacle_height) for o in in_slab] + [0.0] * len(drops) + [0.0],
            dtype=np.float64,
        )
        self._crosses_plane = np.array(
            [o.z_min <= lidar_height <= o.z_max for o in in_slab] + [False] * len(drops),
            dtype=bool,
        )
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
        self._lidar_height = lidar_height
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
        plane = (
            ranges[self._crosses_plane].min(axis=0)
            if self._crosses_plane.any()
            else np.full(count, np.inf, dtype=np.float32)
        )
        in_view = found & self._visible(truth, self._tops[index])
        truth = truth.astype(np.float32)
        near = (
            None
            if self.footprint_radius is None
            else near_footprint_slots(
                truth, self.grid.angles(), self._base_in_laser, self.footprint_radius
            )
        )
        return SlotTruth(truth, plane, self._kinds[index], in_view, near)

    def _visible(
        self, ranges: npt.NDArray[np.float32], tops: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.bool_]:
        """Slots whose obstacle top (at the truth range) projects into an image within range."""
        angles = self.grid.angles()
        finite = np.where(np.isfinite(ranges), ranges, 0.0).astype(np.float64)
        points = np.column_stack(
            [finite * np.cos(angles), finite * np.sin(angles), tops - self._lidar_height]
        )
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
