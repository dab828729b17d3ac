"""Several sources into one output scan: the budget is 4 ms per scan on one core.

A 1080-reading LiDAR (the output), a second 1080-reading LiDAR at the back, an 848x480
depth camera seeing the benchmark room (scenes.py) and a 30 000-point cloud: the room's
depth pixels back-projected, as a 3D camera publishing PointCloud2 would send them. Also
the cloud path alone per point (PointCloud2 decode + binning), on those 30 000 points (in
random order) and on the whole 848x480 frame as one organized cloud (NaN where the depth
is invalid), beside the depth path per pixel on the same scene.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from benchmarks.common import Row, median_seconds
from benchmarks.scenes import EXTRINSICS, camera_for, frame
from scanfuse.config import FusionConfig
from scanfuse.convert.cloud import points_scan
from scanfuse.motion import IDENTITY_MOTION
from scanfuse.pipeline import FusionPipeline
from scanfuse.ros.messages import cloud_from_cdr, cloud_to_cdr
from scanfuse.scan import Scan
from scanfuse.stream import FusionStream

if TYPE_CHECKING:
    from collections.abc import Callable

    from scanfuse.camera import CameraModel

SECTION = 'sources'
NS = 1_000_000_000


def lidar(frame_id: str) -> Scan:
    count = 1080
    increment = 2 * math.pi / count
    ranges = np.random.default_rng(2).uniform(0.5, 6.0, count).astype(np.float32)
    return Scan(
        -math.pi, math.pi - increment, increment, 0.15, 12.0, ranges, frame_id=frame_id, stamp_ns=NS
    )


def organized_cloud(camera: CameraModel, metres: np.ndarray) -> np.ndarray:
    """Every pixel back-projected (height x width x 3, optical frame; NaN: no depth)."""
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    z = metres.astype(np.float64)
    return np.stack([x_n * z, y_n * z, z], axis=-1)


def cloud_points(count: int = 30_000) -> np.ndarray:
    camera = camera_for(848, 480)
    _, metres = frame(camera, seed=3)
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    keep = np.isfinite(metres)
    z = metres[keep].astype(np.float64)
    points = np.stack([x_n[keep] * z, y_n[keep] * z, z], axis=1)
    chosen = np.random.default_rng(4).choice(len(points), count, replace=False)
    return points[chosen]


def run() -> list[Row]:
    camera = camera_for(848, 480)
    depth, metres = frame(camera)
    optical = EXTRINSICS.base_to_camera_optical
    roll, pitch, yaw = optical.rpy()
    config = FusionConfig.from_dict(
        {
            'use_tf': False,
            'memory': False,
            'camera_x': 0.1,
            'camera_height': 0.45,
            'camera_pitch': math.radians(20.0),
            'lidars': ['front', 'rear'],
            'front': {'topic': '/front', 'z': 0.3},
            'rear': {'topic': '/rear', 'x': -0.4, 'z': 0.3, 'yaw': math.pi},
            'clouds': ['points'],
            'points': {
                'topic': '/points',
                'x': optical.translation[0],
                'z': optical.translation[2],
                'roll': roll,
                'pitch': pitch,
                'yaw': yaw,
            },
        }
    )
    stream: FusionStream[int] = FusionStream(config)
    points = cloud_points()
    stream.add_camera_info(camera)
    stream.add_depth(NS, depth, NS)
    stream.add_scan(lidar('rear'), 0, NS, source='rear')
    stream.add_cloud(NS, points, NS, 'points', 'points')
    front = lidar('front')

    def one_scan() -> None:
        (out,) = stream.add_scan(front, 1, NS)
        assert out.passed is None  # fused with the camera

    one_scan()
    assert stream.sources.counts.used == {'rear': 1, 'points': 1}, stream.sources.counts

    pipeline = FusionPipeline(config)

    def cloud_path(raw: bytes) -> Callable[[], None]:
        def decode_and_bin() -> None:
            cloud = cloud_from_cdr(raw)
            points_scan(
                cloud.points,
                optical,
                EXTRINSICS.base_to_laser,
                front.grid,
                motion=IDENTITY_MOTION,
                min_height=0.03,
                max_height=0.5,
                range_min=0.2,
                range_max=3.0,
                min_points=16,
                cluster_spread=0.02,
            )

        return decode_and_bin

    def depth_path() -> None:
        pipeline.fuse(front, depth, camera, EXTRINSICS)

    organized = organized_cloud(camera, metres)
    per_scan = median_seconds(one_scan)
    cloud = median_seconds(cloud_path(cloud_to_cdr(points, frame_id='points', stamp_ns=NS)))
    frame_cloud = median_seconds(
        cloud_path(cloud_to_cdr(organized, frame_id='points', stamp_ns=NS))
    )
    empty = median_seconds(cloud_path(cloud_to_cdr(points[:0], frame_id='points', stamp_ns=NS)))
    depth_time = median_seconds(depth_path)
    pixels = camera.width * camera.height
    return [
        Row(
            SECTION,
            '2 LiDARs x 1080 + 848x480 depth + 30 000-point cloud, per output scan',
            per_scan,
            'target < 4 ms',
        ),
        Row(
            SECTION,
            'PointCloud2 decode + binning, 30 000 points (random order)',
            cloud,
            f'{cloud / len(points) * 1e9:.2f} ns per point',
        ),
        Row(
            SECTION,
            'PointCloud2 decode + binning, 848x480 organized (NaN: no depth)',
            frame_cloud,
            f'{frame_cloud / pixels * 1e9:.2f} ns per point',
        ),
        Row(
            SECTION,
            'PointCloud2 decode + binning, empty cloud (the fixed cost of a call)',
            empty,
        ),
        Row(
            SECTION,
            'depth path (obstacle method + merge), 848x480',
            depth_time,
            f'{depth_time / pixels * 1e9:.2f} ns per pixel',
        ),
    ]
