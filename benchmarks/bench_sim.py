"""Simulator speed: per-frame sensor costs and the real-time factor of recording a bag.

The target: recording faster than real time on one core with 640x480 depth at 15 Hz
and the LiDAR at 10 Hz. The renderer rows need OpenGL (MUJOCO_GL=egl is set here
unless the caller chose otherwise); without it they say so and are skipped.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

os.environ.setdefault('MUJOCO_GL', 'egl')

from benchmarks.common import Row, median_seconds
from scanfuse.sim import (
    DepthBackend,
    SimConfig,
    SimError,
    Simulation,
    record,
    scripted_path,
)

SECTION = 'sim'
DURATION = 5.0


def _frame_rows(backend: DepthBackend) -> list[Row]:
    config = SimConfig(world='clutter', resolution=(640, 480), depth_backend=backend)
    simulation = Simulation(config)
    rows = [
        Row(
            SECTION,
            f'depth frame 640x480 ({backend.value})',
            median_seconds(simulation.depth_frame, repeat=7, min_time=0.0),
            'clutter world, noise on, 16UC1',
        )
    ]
    if backend is DepthBackend.MULTIRAY:
        pose = simulation.true_pose()
        rows += [
            Row(
                SECTION,
                'LiDAR frame (1080 rays + truth)',
                median_seconds(simulation.lidar_frame, repeat=15),
                'rplidar-a2, clutter world',
            ),
            Row(
                SECTION,
                'truth scan alone',
                median_seconds(lambda: simulation.truth.scan(pose.x, pose.y, pose.yaw), repeat=15),
                f'{simulation.truth.starts.shape[0]} footprint edges',
            ),
        ]
    simulation.close()
    return rows


def _real_time_row(backend: DepthBackend) -> Row:
    config = SimConfig(
        world='bookshelf', resolution=(640, 480), depth_rate=15.0, depth_backend=backend
    )
    with tempfile.TemporaryDirectory() as folder:
        summary = record(config, scripted_path('straight'), DURATION, Path(folder) / 'run.mcap')
    factor = summary.real_time_factor
    return Row(
        SECTION,
        f'record 640x480@15 Hz + LiDAR 10 Hz ({backend.value})',
        summary.wall_time / summary.sim_time,
        f'wall s per simulated s (one {DURATION:.0f} s run); real-time factor {factor:.2f}',
    )


def run() -> list[Row]:
    rows = [*_frame_rows(DepthBackend.MULTIRAY), _real_time_row(DepthBackend.MULTIRAY)]
    try:
        rows += [*_frame_rows(DepthBackend.RENDERER), _real_time_row(DepthBackend.RENDERER)]
    except SimError as err:
        rows.append(Row(SECTION, 'renderer backend', float('nan'), f'unavailable: {err}'))
    return rows
