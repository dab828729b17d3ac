"""`FusionPipeline`: the one way from a LiDAR scan and a depth image to a fused scan.

convert (row | obstacle) -> resample (row method only) -> merge. The bag
processor, the live node, the simulator's evaluation and the benchmarks all
call `FusionPipeline.fuse`; there is no second implementation of the fusion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from scanfuse.config import FusionConfig, Method
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.ground import GroundPlane, GroundProfile
from scanfuse.convert.obstacle import DropLimits, ObstacleProjector
from scanfuse.convert.row import row_scan
from scanfuse.errors import InputError
from scanfuse.fuse.merge import merge_scans
from scanfuse.fuse.resample import Plan, apply_plan, build_plan
from scanfuse.motion import IDENTITY_MOTION, PlanarMotion
from scanfuse.sources import MAX_MOUNTING_OFFSET
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import AngleGrid, Scan


# A robot has one camera and one LiDAR; a few entries cover a change of either (a new
# CameraInfo, TF after parameters) without keeping every one ever seen (a projector is ~9 MB).
PROJECTOR_CACHE_SIZE = 4
PLAN_CACHE_SIZE = 8
# Two LiDAR grids of one count are one grid when no reading's angle differs by more than this
# share of a slot. Some drivers jitter angle_min by microradians from scan to scan
# (rplidar_ros); 1 % of a slot (87 microradians at 720 readings per turn) moves the edge
# where a depth point is binned far less than any LiDAR's beam is wide.
GRID_TOLERANCE = 0.01

# cos^2 + sin^2 of a motion's rotation may differ from 1 by float rounding, not by more.
MOTION_TOLERANCE = 1e-6

Key = TypeVar('Key')
Value = TypeVar('Value')


def grids_match(first: AngleGrid, second: AngleGrid) -> bool:
    """Whether every reading of the two grids points within `GRID_TOLERANCE` slots alike."""
    if first.count != second.count:
        return False
    # Reading i differs by d_min + i * d_increment: the largest is at one end.
    d_min = second.angle_min - first.angle_min
    d_increment = second.angle_increment - first.angle_increment
    worst = max(abs(d_min), abs(d_min + (first.count - 1) * d_increment))
    return worst <= GRID_TOLERANCE * abs(first.angle_increment)


class GridCache(Generic[Key, Value]):
    """The `size` most recently used values, keyed exactly and by grids within tolerance."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._entries: list[tuple[Key, tuple[AngleGrid, ...], Value]] = []

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key: Key, grids: tuple[AngleGrid, ...]) -> Value | None:
        for index, (entry_key, entry_grids, value) in enumerate(self._entries):
            if entry_key == key and all(map(grids_match, entry_grids, grids)):
                self._entries.append(self._entries.pop(index))  # now the most recent
                return value
        return None

    def put(self, key: Key, grids: tuple[AngleGrid, ...], value: Value) -> None:
        self._entries.append((key, grids, value))
        del self._entries[: -self.size]


def check_motion(motion: PlanarMotion) -> None:
    """InputError unless `motion` is a finite rotation and a plausible translation.

    The obstacle kernel bins every moved point by its angle: a NaN or float32-overflowing
    motion would give every point a meaningless slot. Between a depth frame and a scan
    (at most max_time_offset, 10 s, apart) no robot moves 100 m.
    """
    values = (motion.cos, motion.sin, motion.tx, motion.ty)
    if not all(math.isfinite(value) for value in values):
        msg = f'motion {motion} must be finite; check the odometry it was found from'
        raise InputError(msg)
    if abs(motion.cos**2 + motion.sin**2 - 1.0) > MOTION_TOLERANCE:
        msg = f'motion {motion} is not a rotation (cos^2 + sin^2 must be 1)'
        raise InputError(msg)
    if max(abs(motion.tx), abs(motion.ty)) > MAX_MOUNTING_OFFSET:
        msg = (
            f'motion {motion} moves the LiDAR more than {MAX_MOUNTING_OFFSET:g} m between '
            'the depth frame and the scan; check the odometry and the stamps'
        )
        raise InputError(msg)


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
    """The fused scan, the depth scan on the LiDAR's grid, and how long each stage took.
    `slab_slots`: the depth scan's slots whose reading is the collision slab's, not a
    drop-off's edge (None: the row method, which tells no slab from floor)."""

    fused: Scan
    depth_scan: Scan
    timings: StageTimings
    slab_slots: npt.NDArray[np.bool_] | None = None


class FusionPipeline:
    """Fuses LiDAR scans with depth images as `config` says.

    Work that depends only on the camera, the extrinsics and the LiDAR's grid
    (ray tables, resampling index plans) is done on first use and kept, so the
    per-frame cost is only the per-pixel arithmetic. Only the few most recently used
    are kept, and LiDAR grids that differ by less than `GRID_TOLERANCE` of a slot share
    them: memory stays bounded whatever the inputs.
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
        self._drops = (
            DropLimits(
                min_depth=self.config.drop_min_depth,
                min_width=self.config.drop_min_width,
                noise=self.config.depth_noise,
            )
            if self.config.detect_drops
            else None
        )
        self._plans: GridCache[None, Plan] = GridCache(PLAN_CACHE_SIZE)
        self._projectors: GridCache[tuple[CameraModel, Extrinsics], ObstacleProjector] = GridCache(
            PROJECTOR_CACHE_SIZE
        )

    @property
    def cached(self) -> tuple[int, int]:
        """How many obstacle projectors and resampling plans are kept now."""
        return len(self._projectors), len(self._plans)

    def fuse(
        self,
        lidar: Scan,
        depth: npt.NDArray[np.generic],
        camera: CameraModel,
        extrinsics: Extrinsics | None = None,
        motion: PlanarMotion = IDENTITY_MOTION,
        ground: GroundPlane | None = None,
        profile: GroundProfile | None = None,
    ) -> FusedResult:
        """Fuse one LiDAR scan with one depth image (uint16 mm or float32 m).

        `ground` is the floor the obstacle method measures heights from (`FusionStream`
        estimates it per frame); None: the mounting's plane. `profile`: its ramps.

        `motion` takes points from the LiDAR frame at the image's stamp to the LiDAR frame at
        the scan's stamp (`FusionStream` finds it from odometry). The obstacle method moves
        every point; the row method's scan, whose points are only bearings and ranges from the
        camera, is turned by the motion's angle.
        """
        extrinsics = extrinsics or self._default_extrinsics
        if not motion.is_identity:
            check_motion(motion)
        start = time.perf_counter()
        if self.config.method is Method.OBSTACLE:
            projector = self._projector(camera, extrinsics, lidar.grid)
            depth_scan = projector.scan(
                depth,
                motion,
                ground or GroundPlane.of_mounting(extrinsics.base_to_camera_optical),
                profile,
            )
            converted = time.perf_counter()
            # The projector may be one of a grid within tolerance: label with the LiDAR's own.
            on_lidar_grid = depth_scan.with_ranges(
                depth_scan.ranges,
                angle_min=lidar.angle_min,
                angle_max=lidar.angle_max,
                angle_increment=lidar.angle_increment,
                frame_id=lidar.frame_id,
                stamp_ns=lidar.stamp_ns,
            )
            slab_slots = np.isfinite(depth_scan.ranges) & ~projector.drop_slots
            resampled = time.perf_counter()
        else:
            slab_slots = None
            depth_scan = self.row_depth_scan(depth, camera)
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
            slab_slots=slab_slots,
        )

    def row_depth_scan(self, depth: npt.NDArray[np.generic], camera: CameraModel) -> Scan:
        """Algorithm 1 (the row method) on its own grid: one reading per image column, as
        depthimage_to_laserscan publishes it (bit for bit with `d2l_compat`)."""
        return row_scan(
            depth,
            camera,
            scan_row=self.config.scan_row,
            scan_height=self.config.scan_height,
            range_min=self.config.range_min,
            range_max=self.config.range_max,
            d2l_compat=self.config.d2l_compat,
            floor_guard=self._floor_guard,
        )

    def prepare(self, camera: CameraModel, extrinsics: Extrinsics, grid: AngleGrid) -> None:
        """Build the obstacle method's tables for this camera, mounting and LiDAR grid now
        (the node calls it when CameraInfo arrives), not on the first fused scan."""
        if self.config.method is Method.OBSTACLE:
            self._projector(camera, extrinsics, grid)

    def _plan(self, source: AngleGrid, target: AngleGrid) -> Plan:
        plan = self._plans.get(None, (source, target))
        if plan is None:
            plan = build_plan(self.config.resample, source, target)
            self._plans.put(None, (source, target), plan)
        return plan

    def _projector(
        self, camera: CameraModel, extrinsics: Extrinsics, grid: AngleGrid
    ) -> ObstacleProjector:
        projector = self._projectors.get((camera, extrinsics), (grid,))
        if projector is None:
            projector = ObstacleProjector(
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
                drops=self._drops,
                bottom_noise=self.config.slab_noise_sigmas * self.config.depth_noise,
            )
            self._projectors.put((camera, extrinsics), (grid,), projector)
        return projector
