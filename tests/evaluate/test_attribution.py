"""Where each reading of a fused scan came from: the LiDAR, a camera or the memory."""

from __future__ import annotations

import math

import numpy as np

from scanfuse.evaluate.attribution import CAMERA, LIDAR, MEMORY, count_sources, slot_sources
from scanfuse.fuse.merge import merge_scans
from scanfuse.scan import Scan

NAN, INF = math.nan, math.inf


def _scan(ranges: list[float]) -> Scan:
    return Scan(
        ranges=np.array(ranges, dtype=np.float32),
        angle_min=-0.1,
        angle_max=0.1,
        angle_increment=0.05,
        range_min=0.1,
        range_max=10.0,
        stamp_ns=1,
        frame_id='laser',
    )


def test_each_reading_is_the_source_that_made_it_the_memory_merged_last():
    lidar = _scan([2.0, 2.0, 2.0, 2.0, NAN])
    camera = _scan([INF, 1.0, 3.0, NAN, 1.5])
    memory = _scan([NAN, 1.5, NAN, 0.5, NAN])
    instant = merge_scans(lidar, camera)  # the nearer of the two, slot by slot
    fused = merge_scans(instant, memory)
    sources = slot_sources(fused, camera, instant)
    # 2 m LiDAR; the camera's 1 m (the memory's 1.5 m behind it); the LiDAR's 2 m before the
    # camera's 3 m; the memory's 0.5 m; the camera's 1.5 m where the LiDAR had nothing.
    assert sources.tolist() == [LIDAR, CAMERA, LIDAR, MEMORY, CAMERA]
    # Without memory or camera every reading is the LiDAR's, or the camera's.
    assert slot_sources(lidar, None, None).tolist() == [LIDAR] * 5
    assert slot_sources(instant, camera, None).tolist() == [LIDAR, CAMERA, LIDAR, LIDAR, CAMERA]
    false = np.array([True, True, False, True, True])
    assert count_sources(sources, false) == [1, 2, 1]
