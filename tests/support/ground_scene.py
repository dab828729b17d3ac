"""Issue 25's analytic scene (tests of the ground estimate, the IMU and the mount check):
an 848x480 D435-like camera 0.40 m up pitched 20 deg, a LiDAR 0.30 m up at the base's
origin, a 6 cm box whose front face is 1.5 m ahead (0.6 m wide), TF absent (the parameters
say where the sensors are). Expected values are the scene's geometry: the box's slots read
1.5 / cos(angle) within the tolerance (0.05 m + 2 %), every other slot in view has no
obstacle within range (+Inf).
"""

from __future__ import annotations

import math

import numpy as np

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.scan import Scan
from scanfuse.transforms import BODY_TO_OPTICAL, Transform

NS = 1_000_000_000
CAMERA = CameraModel.from_intrinsics(848, 480, 424.0, 424.0, 423.5, 239.5, frame_id='optical')
HEIGHT, PITCH = 0.40, math.radians(20.0)
READINGS = 1440
BOX_FRONT, BOX_HALF_WIDTH, BOX_HEIGHT = 1.5, 0.3, 0.06
BOX = (BOX_FRONT, BOX_FRONT + 0.3, -BOX_HALF_WIDTH, BOX_HALF_WIDTH, 0.0, BOX_HEIGHT)


def config(**changes: object) -> FusionConfig:
    values: dict[str, object] = {
        'use_tf': False,
        'camera_height': HEIGHT,
        'camera_pitch': PITCH,
        'lidar_height': 0.30,
        'memory': False,
        **changes,
    }
    return FusionConfig(**values)  # type: ignore[arg-type]


def lidar_scan(stamp_ns: int) -> Scan:
    increment = 2.0 * math.pi / READINGS
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - increment,
        angle_increment=increment,
        range_min=0.05,
        range_max=10.0,
        ranges=np.full(READINGS, np.inf, dtype=np.float32),
        frame_id='laser',
        stamp_ns=stamp_ns,
    )


def optical_pose(
    *, body_pitch: float = 0.0, body_roll: float = 0.0, height: float = HEIGHT, pitch: float = PITCH
) -> Transform:
    """Where the camera's optical frame really is: its mounting on a body tilted about the
    base's origin (pitch positive nose-down, REP-103)."""
    body = Transform.from_rpy(math.radians(body_roll), math.radians(body_pitch), 0.0)
    mounting = Transform.from_rpy(0.0, pitch, 0.0, (0.0, 0.0, height))
    return body @ mounting @ BODY_TO_OPTICAL


def box_truth(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """Slots wholly on the box's front face, and slots wholly off it (beside it)."""
    angles = scan.angle_min + np.arange(scan.ranges.size) * scan.angle_increment
    half = 0.5 * scan.angle_increment
    near_edge = np.abs(np.tan(angles) * BOX_FRONT)
    on_face = (np.cos(angles) > 0) & (np.abs(np.tan(np.abs(angles) + half)) * BOX_FRONT <= 0.3)
    off_face = ~((np.cos(angles) > 0) & (near_edge <= BOX_HALF_WIDTH + 0.05))
    return on_face, off_face


def score(scan: Scan) -> tuple[float, float]:
    """(share of the in-view slots off the box with an obstacle reading, share of the box's
    slots within tolerance of 1.5 / cos(angle))."""
    ranges = scan.ranges.astype(np.float64)
    angles = scan.angle_min + np.arange(ranges.size) * scan.angle_increment
    on_face, off_face = box_truth(scan)
    in_view = ~np.isnan(ranges)
    false = in_view & off_face & (ranges < scan.range_max)  # finite or -Inf: an obstacle
    truth = BOX_FRONT / np.cos(angles)
    right = on_face & (np.abs(ranges - truth) <= 0.05 + 0.02 * truth)
    return float(false.sum() / in_view.sum()), float(right.sum() / on_face.sum())
