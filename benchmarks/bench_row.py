"""Row method (Algorithm 1): scanfuse's vectorised default mode, the depthimage_to_laserscan
compatible mode, and the per-pixel Python loop of Algorithm 1 as baseline.

Images are synthetic 16UC1 frames of a plausible indoor scene: a camera 0.4 m above
the floor pitched 15 deg down, a wall 4 m ahead, a box 1.5 m ahead, 1 % sensor noise
and 5 % missing pixels (code 0).
"""

from __future__ import annotations

import math

import numpy as np
from tests.support.reference import row_scan_loop

from benchmarks.common import Row, median_seconds
from scanfuse.camera import CameraModel
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.row import row_scan

SECTION = 'row'
SIZES = ((640, 480), (848, 480), (1280, 720), (1920, 1080))
HEIGHT, PITCH = 0.4, math.radians(15.0)
LIMITS = {'range_min': 0.2, 'range_max': 10.0}


def camera_for(width: int, height: int) -> CameraModel:
    # About 87 deg horizontal field of view, as a RealSense D435 depth stream.
    focal = 0.95 * width / 2.0
    return CameraModel.from_intrinsics(width, height, focal, focal, width / 2.0, height / 2.0)


def scene(camera: CameraModel, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x_n, y_n = camera.normalized_coordinates
    descent = y_n * math.cos(PITCH) + math.sin(PITCH)
    with np.errstate(divide='ignore'):
        floor = np.where(descent > 0.0, HEIGHT / descent, np.inf)
    depth = np.minimum(floor, 4.0)
    box = (np.abs(x_n) < 0.15) & (y_n > -0.05)
    depth = np.where(box, np.minimum(depth, 1.5), depth)
    depth = depth * (1.0 + 0.01 * rng.standard_normal(depth.shape))
    codes = np.clip(np.rint(depth * 1000.0), 0, 65535).astype(np.uint16)
    codes[rng.random(codes.shape) < 0.05] = 0
    return codes


def run() -> list[Row]:
    rows: list[Row] = []
    guard = FloorGuard(camera_height=HEIGHT, camera_pitch=PITCH)
    for width, height in SIZES:
        camera = camera_for(width, height)
        depth = scene(camera)
        size = f'{width}x{height}'
        targets = {
            ('scan_height 1', 640): 'target < 100 us',
            ('full height', 1280): 'target < 5 ms',
        }
        cases = (
            ('scan_height 1', depth, {'scan_height': 1}),
            ('full height', depth, {'scan_height': height}),
            ('full height + floor guard', depth, {'scan_height': height, 'floor_guard': guard}),
            ('d2l_compat full height', depth, {'scan_height': height - 2, 'd2l_compat': True}),
        )
        if width == 1280:
            metres = depth.astype(np.float32) * np.float32(0.001)
            metres[depth == 0] = np.nan
            cases += (('full height 32FC1', metres, {'scan_height': height}),)
        for name, image, kwargs in cases:
            seconds = median_seconds(
                lambda image=image, camera=camera, kwargs=kwargs: row_scan(
                    image, camera, **LIMITS, **kwargs
                ),
                repeat=15,
            )
            note = targets.get((name, width), '')
            rows.append(Row(SECTION, f'{name} {size}', seconds, note))

    camera = camera_for(640, 480)
    depth = scene(camera)
    fast = next(row.median_s for row in rows if row.name == 'scan_height 1 640x480')
    loop = median_seconds(lambda: row_scan_loop(depth, camera, **LIMITS), repeat=5, min_time=0.05)
    rows.append(
        Row(
            SECTION,
            'per-pixel Python loop, scan_height 1 640x480',
            loop,
            f'vectorised is {loop / fast:.0f}x faster',
        )
    )
    return rows
