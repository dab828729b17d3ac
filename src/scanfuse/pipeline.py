"""`FusionPipeline`: the one way from a LiDAR scan and a depth image to a fused scan.

convert (row | obstacle) -> resample (row method only) -> merge. The bag
processor, the live node, the simulator's evaluation and the benchmarks all
call `FusionPipeline.fuse`; there is no second implementation of the fusion.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from scanfuse.config import FusionConfig, Method
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.obstacle import ObstacleProjector
from scanfuse.convert.row import row_scan
from scanfuse.fuse.merge import merge_scans
from scanfuse.fuse.resample import Plan, apply_plan, build_plan
from scanfuse.motion import IDENTITY_MOTION, PlanarMotion
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import AngleGrid, Scan


@dataclass(frozen=True)
class StageTimings:
    """Wall time of each stage of one `fuse` call, seconds."""

    convert: float
    resample: float
    merge: float

    @property
    def total(self) -> float:
        return self.convert + self.resample + self.merge


@dataclass(frozen=True)
class FusedResult:
    """The fused scan, the depth scan on the LiDAR's grid, and how long each stage took."""

    fused: Scan
    depth_scan: Scan
    timings: StageTimings


class FusionPipeline:
    """Fuses LiDAR scans with depth images as `config` says.

    Work that depends only on the camera, the extrinsics and the LiDAR's grid
    (ray tables, resampling index plans) is done on first use and kept, so the
    per-frame cost is only the per-pixel arithmetic.
    """

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self._default_extrinsics = Extrinsics.from_config(self.config)
        self._floor_guard = (
            FloorGuard(
                camera_height=self.config.camera_height,
                camera_pitch=self.config.camera_pitch,
                margin=self.config.floor_margin,
            )
            # depthimage_to_laserscan has no floor guard; compat mode reproduces it as is.
            if self.config.floor_guard and not self.config.d2l_compat
            else None
        )
        self._plans: dict[tuple[AngleGrid, AngleGrid], Plan] = {}
        self._projectors: dict[tuple[CameraModel, Extrinsics, AngleGrid], ObstacleProjector] = {}

    def fuse(
        self,
        lidar: Scan,
        depth: npt.NDArray[np.generic],
        camera: CameraModel,
        extrinsics: Extrinsics | None = None,
        motion: PlanarMotion = IDENTITY_MOTION,
    ) -> FusedResult:
        """Fuse one LiDAR scan with one depth image (uint16 mm or float32 m).

        `motion` takes points from the LiDAR frame at the image's stamp to the LiDAR frame at
        the scan's stamp (`FusionStream` finds it from odometry). The obstacle method moves
        every point; the row method's scan, whose points are only bearings and ranges from the
        camera, is turned by the motion's angle.
        """
        extrinsics = extrinsics or self._default_extrinsics
        start = time.perf_counter()
        if self.config.method is Method.OBSTACLE:
            depth_scan = self._projector(camera, extrinsics, lidar.grid).scan(depth, motion)
            converted = time.perf_counter()
            on_lidar_grid = depth_scan.with_ranges(
                depth_scan.ranges, frame_id=lidar.frame_id, stamp_ns=lidar.stamp_ns
            )
            resampled = time.perf_counter()
        else:
            depth_scan = row_scan(
                depth,
                camera,
                scan_row=self.config.scan_row,
                scan_height=self.config.scan_height,
                range_min=self.config.range_min,
                range_max=self.config.range_max,
                d2l_compat=self.config.d2l_compat,
                floor_guard=self._floor_guard,
            )
            if not motion.is_identity:
                depth_scan = depth_scan.with_ranges(
                    depth_scan.ranges,
                    angle_min=depth_scan.angle_min + motion.angle,
                    angle_max=depth_scan.angle_max + motion.angle,
                )
            converted = time.perf_counter()
            plan = self._plan(depth_scan.grid, lidar.grid)
            on_lidar_grid = apply_plan(plan, depth_scan, lidar.grid)
            resampled = time.perf_counter()
        fused = merge_scans(lidar, on_lidar_grid)
        merged = time.perf_counter()
        return FusedResult(
            fused=fused,
            depth_scan=on_lidar_grid,
            timings=StageTimings(converted - start, resampled - converted, merged - resampled),
        )

    def _plan(self, source: AngleGrid, target: AngleGrid) -> Plan:
        key = (source, target)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = build_plan(self.config.resample, source, target)
        return plan

    def _projector(
        self, camera: CameraModel, extrinsics: Extrinsics, grid: AngleGrid
    ) -> ObstacleProjector:
        key = (camera, extrinsics, grid)
        projector = self._projectors.get(key)
        if projector is None:
            projector = self._projectors[key] = ObstacleProjector(
                camera,
                extrinsics,
                grid,
                min_obstacle_height=self.config.min_obstacle_height,
                max_obstacle_height=self.config.max_obstacle_height,
                range_min=self.config.range_min,
                range_max=self.config.range_max,
                min_points=self.config.obstacle_min_points,
                cluster_spread=self.config.obstacle_cluster_spread,
                threads=self.config.obstacle_threads,
            )
        return projector
