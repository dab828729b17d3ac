"""Resample + merge onto a 1080-reading LiDAR, and the whole pipeline per frame."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.common import Row, median_seconds
from scanfuse import CameraModel, FusionConfig, FusionPipeline, Method, Resampler, Scan
from scanfuse.fuse.merge import merge_scans
from scanfuse.fuse.resample import Plan, apply_plan, build_plan

SIZES = ((640, 480), (848, 480), (1280, 720), (1920, 1080))


def lidar_scan(count: int = 1080) -> Scan:
    rng = np.random.default_rng(0)
    increment = 2 * math.pi / count
    ranges = rng.uniform(0.5, 8.0, count).astype(np.float32)
    return Scan(-math.pi, math.pi - increment, increment, 0.15, 12.0, ranges, frame_id='laser')


def camera_scan(count: int = 640) -> Scan:
    rng = np.random.default_rng(1)
    half = math.radians(43.5)
    increment = 2 * half / (count - 1)
    ranges = rng.uniform(0.3, 6.0, count).astype(np.float32)
    ranges[::17] = np.nan
    return Scan(-half, half, increment, 0.2, 10.0, ranges, frame_id='camera')


def scene(width: int, height: int) -> tuple[np.ndarray, CameraModel]:
    """A D435-like view of a floor with a box and a wall: plausible depth, some holes."""
    fx = width / (2 * math.tan(math.radians(43.5)))
    camera = CameraModel.from_intrinsics(width, height, fx, fx, width / 2 - 0.5, height / 2 - 0.5)
    x_n, y_n = camera.normalized_coordinates
    pitch = math.radians(20)
    down = y_n * math.cos(pitch) + math.sin(pitch)
    with np.errstate(divide='ignore'):
        floor = np.where(down > 0, 0.45 / down, np.inf)
    wall = 4.0 / (math.cos(pitch) - y_n * math.sin(pitch))
    depth = np.minimum(floor, wall)
    depth[(np.abs(x_n) < 0.1) & (y_n > 0.1)] *= 0.8  # a box in front
    rng = np.random.default_rng(2)
    depth_mm = np.clip(depth * 1000, 0, 65535).astype(np.uint16)
    depth_mm[rng.random(depth.shape) < 0.02] = 0
    return depth_mm, camera


def run() -> list[Row]:
    rows = []
    lidar = lidar_scan()
    source = camera_scan()
    for kind in Resampler:
        plan = build_plan(kind, source.grid, lidar.grid)

        def step(plan: Plan = plan) -> Scan:
            return merge_scans(lidar, apply_plan(plan, source, lidar.grid))

        rows.append(
            Row(
                'fuse',
                f'resample {kind.value} + merge, 1080 readings',
                median_seconds(step),
                'target < 100 us',
            )
        )
    rows.append(
        Row('fuse', 'merge alone, 1080 readings', median_seconds(lambda: merge_scans(lidar, lidar)))
    )
    for width, height in SIZES:
        depth, camera = scene(width, height)
        for method in Method:
            pipeline = FusionPipeline(FusionConfig(method=method))
            pipeline.fuse(lidar, depth, camera)  # builds the per-camera tables once
            t = pipeline.fuse(lidar, depth, camera).timings
            total = median_seconds(lambda p=pipeline, d=depth, c=camera: p.fuse(lidar, d, c))
            rows.append(
                Row(
                    'pipeline',
                    f'{method.value} {width}x{height} fuse()',
                    total,
                    f'a warm call: convert {t.convert * 1e3:.2f} ms, resample '
                    f'{t.resample * 1e6:.0f} us, merge {t.merge * 1e6:.0f} us',
                )
            )
    return rows
