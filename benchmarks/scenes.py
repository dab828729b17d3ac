"""Realistic depth frames for the obstacle benchmarks: a room seen by a robot's depth camera.

A RealSense D435-like camera (87 deg horizontal field of view at every size) 0.45 m above
the floor, pitched 20 deg down, 0.1 m ahead of an RPLIDAR-like LiDAR (0.3 m up, 1080
readings over the full turn). The room: floor, a wall 2.8 m ahead, side walls 1.6 m to
the left and 2.0 m to the right, a 12 cm and a 30 cm box, a chair (four 2.5 cm legs and a
seat at 0.45 m, inside the slab) and a table top at 0.72 m (above it). Depth along the
optical axis gets active-stereo noise, Gaussian with sigma = 0.01 Z^2 (as the simulator's
D435 model), then 3 % of the pixels, uniformly at random, read 0 (no measurement).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from tests.support.render import box_depth, slope_depth
from tests.support.room import MOUNTING, WALLS, d435

from scanfuse.config import FusionConfig
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Transform

if TYPE_CHECKING:
    from scanfuse.camera import CameraModel

SIZES = ((640, 480), (848, 480), (1280, 720), (1920, 1080))
CADENCE_SIZE = (1280, 720)  # the size timed at a camera's 30 Hz cadence
EXTRINSICS = MOUNTING
GRID = AngleGrid(-math.pi, 2.0 * math.pi / 1080, 1080)
NOISE = 0.01  # sigma = NOISE * Z^2, metres
INVALID = 0.03
_DEFAULTS = FusionConfig()
# The slab, range limits and per-slot statistic the pipeline runs by default.
SETTINGS = {
    'min_obstacle_height': _DEFAULTS.min_obstacle_height,
    'max_obstacle_height': _DEFAULTS.max_obstacle_height,
    'range_min': _DEFAULTS.range_min,
    'range_max': _DEFAULTS.range_max,
    'min_points': _DEFAULTS.obstacle_min_points,
    'cluster_spread': _DEFAULTS.obstacle_cluster_spread,
}

_LEG = 0.025
_CHAIR = (1.1, 0.35)  # front-right leg, base frame
BOXES = (
    *WALLS,
    (1.2, 1.5, -0.6, -0.2, 0.0, 0.12),  # low box
    (2.0, 2.4, -1.4, -0.9, 0.0, 0.3),  # box
    *(
        (x, x + _LEG, y, y + _LEG, 0.0, 0.45)
        for x in (_CHAIR[0], _CHAIR[0] + 0.42)
        for y in (_CHAIR[1], _CHAIR[1] + 0.42)
    ),  # chair legs
    (_CHAIR[0], _CHAIR[0] + 0.45, _CHAIR[1], _CHAIR[1] + 0.45, 0.45, 0.48),  # chair seat
    (1.9, 2.7, 0.2, 1.2, 0.70, 0.72),  # table top
)


camera_for = d435  # the D435's 87 deg horizontal field of view at any size


def true_depth(camera: CameraModel, *, body_pitch: float = 0.0, ramp: float = 0.0) -> np.ndarray:
    """Noise-free depth along the optical axis of the nearest surface, metres (inf: none);
    seen from a body pitched `body_pitch` radians (nose down) about the base's origin, and
    with the floor rising `ramp` metres per metre from 1.2 m ahead (a ramp) when not 0."""
    pose = Transform.from_rpy(0.0, body_pitch, 0.0) @ EXTRINSICS.base_to_camera_optical
    if ramp:
        return slope_depth(camera, pose, start=1.2, rise=ramp, boxes=BOXES)
    return box_depth(camera, pose, BOXES)


def frame(
    camera: CameraModel, seed: int = 0, *, body_pitch: float = 0.0, ramp: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """One noisy frame of the room: (uint16 millimetres, 0 invalid; float32 metres, NaN)."""
    rng = np.random.default_rng(seed)
    depth = true_depth(camera, body_pitch=body_pitch, ramp=ramp)
    with np.errstate(invalid='ignore'):
        depth = depth + NOISE * depth**2 * rng.standard_normal(depth.shape)
        invalid = ~np.isfinite(depth) | (depth <= 0.0) | (rng.random(depth.shape) < INVALID)
    metres = np.where(invalid, np.nan, depth).astype(np.float32)
    millimetres = np.where(invalid | (depth > 65.0), 0, np.round(depth * 1000.0))
    return millimetres.astype(np.uint16), metres
