"""Obstacle method (height-filtered full frame): compiled kernel, numpy reference, and the
ratio to the row method over the full image height (the same pixels, no 3D placement).

Images are synthetic 16UC1 frames ray-cast from a camera 0.45 m above the floor pitched
20 deg down, 0.1 m ahead of the LiDAR: floor, a wall 4 m ahead, a 25 cm box 1.5 m ahead,
a table top at 0.7 m; 1 % noise and 5 % missing pixels (code 0). The LiDAR grid is
720 slots over the full turn.
"""

from __future__ import annotations

import math

import numpy as np

from common import Row, median_seconds
from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.convert.obstacle import ObstacleProjector
from scanfuse.convert.row import row_scan
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics

SECTION = 'obstacle'
SIZES = ((640, 480), (848, 480), (1280, 720), (1920, 1080))
EXTRINSICS = Extrinsics.from_mounting(
    camera_x=0.1, camera_height=0.45, camera_pitch=math.radians(20.0), lidar_height=0.3
)
GRID = AngleGrid(-math.pi, 2.0 * math.pi / 720, 720)
LIMITS = {'range_min': 0.2, 'range_max': 10.0}
SLAB = {'min_obstacle_height': 0.03, 'max_obstacle_height': 0.5}
# The default per-slot statistic (k nearest within a window), as the pipeline runs it.
STATISTIC = {
    'min_points': FusionConfig().obstacle_min_points,
    'cluster_spread': FusionConfig().obstacle_cluster_spread,
}
BOXES = (
    (4.0, 4.2, -10.0, 10.0, 0.0, 3.0),  # wall
    (1.5, 1.8, -0.3, 0.2, 0.0, 0.25),  # box
    (2.2, 3.0, 0.4, 1.4, 0.68, 0.7),  # table top
)


def camera_for(width: int, height: int) -> CameraModel:
    # About 87 deg horizontal field of view, as a RealSense D435 depth stream.
    focal = 0.95 * width / 2.0
    return CameraModel.from_intrinsics(width, height, focal, focal, width / 2.0, height / 2.0)


def scene(camera: CameraModel, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    optical = EXTRINSICS.base_to_camera_optical
    origin = np.asarray(optical.translation)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1) @ optical.rotation_matrix.T
    with np.errstate(divide='ignore', invalid='ignore'):
        at_floor = -origin[2] / rays[..., 2]
        depth = np.where(at_floor > 0.0, at_floor, np.inf)
        for box in BOXES:
            low, high = np.array(box[0::2]), np.array(box[1::2])
            t_low, t_high = (low - origin) / rays, (high - origin) / rays
            enter = np.nanmax(np.minimum(t_low, t_high), axis=-1)
            leave = np.nanmin(np.maximum(t_low, t_high), axis=-1)
            depth = np.where((enter <= leave) & (enter > 0.0) & (enter < depth), enter, depth)
    depth = depth * (1.0 + 0.01 * rng.standard_normal(depth.shape))
    depth[rng.random(depth.shape) < 0.05] = 0.0
    return np.where(np.isfinite(depth) & (depth < 60.0), np.round(depth * 1000), 0).astype(
        np.uint16
    )


def run() -> list[Row]:
    rows = []
    for width, height in SIZES:
        camera = camera_for(width, height)
        depth = scene(camera)
        projector = ObstacleProjector(camera, EXTRINSICS, GRID, **SLAB, **LIMITS, **STATISTIC)
        implementation = 'numba' if projector.uses_kernel else 'numpy (numba missing)'
        obstacle = median_seconds(lambda p=projector, d=depth: p.scan(d))
        rows.append(Row(SECTION, f'obstacle {width}x{height}', obstacle, implementation))
        flat = depth.ravel()
        reference = median_seconds(
            lambda p=projector, d=flat: p.nearest_squared(d, reference=True), repeat=7
        )
        rows.append(Row(SECTION, f'numpy reference {width}x{height}', reference, 'reduction only'))
        try:
            row = median_seconds(
                lambda d=depth, c=camera: row_scan(d, c, scan_height=c.height, **LIMITS), repeat=11
            )
        except NotImplementedError:
            rows.append(Row(SECTION, f'row full height {width}x{height}', math.nan, 'row.py stub'))
            continue
        rows.append(
            Row(
                SECTION,
                f'row full height {width}x{height}',
                row,
                f'obstacle / row = {obstacle / row:.2f}',
            )
        )
    return rows
