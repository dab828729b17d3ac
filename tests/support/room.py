"""The room the benchmarks time and the ground tests look at: a RealSense D435-like camera
(87 deg horizontal field of view at every size, square pixels) 0.45 m above the floor,
pitched 20 deg down, 0.1 m ahead of a LiDAR 0.3 m up; walls 2.8 m ahead, 1.6 m to the left
and 2.0 m to the right (boxes: x, y, z ranges in the base frame, metres)."""

from __future__ import annotations

import math

from scanfuse.camera import CameraModel
from scanfuse.transforms import Extrinsics

MOUNTING = Extrinsics.from_mounting(
    camera_x=0.1, camera_height=0.45, camera_pitch=math.radians(20.0), lidar_height=0.3
)
WALLS = (
    (2.8, 3.0, -4.0, 4.0, 0.0, 2.5),  # front wall
    (-1.0, 3.0, 1.6, 1.8, 0.0, 2.5),  # left wall
    (-1.0, 3.0, -2.2, -2.0, 0.0, 2.5),  # right wall
)


def d435(width: int, height: int) -> CameraModel:
    """The D435's 87 deg horizontal field of view at this size, square pixels."""
    focal = (width / 2.0) / math.tan(math.radians(87.0) / 2.0)
    return CameraModel.from_intrinsics(
        width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0
    )
