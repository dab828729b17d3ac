"""Merge invariants (Algorithm 2 with REP-117) when the depth side is an obstacle scan."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse.camera import CameraModel
from scanfuse.convert.obstacle import ObstacleProjector
from scanfuse.fuse.merge import merge_scans
from scanfuse.scan import AngleGrid, Scan
from scanfuse.transforms import Extrinsics

CAMERA = CameraModel.from_intrinsics(80, 60, 65.0, 65.0, 40.0, 30.0)
GRIDS = [
    AngleGrid(-math.pi, math.radians(1.0), 360),
    AngleGrid(0.0, math.radians(0.5), 720),
    AngleGrid(2.0, -0.01, 400),
]
LIDAR_LIMITS = (0.1, 6.0)
PROJECTORS = [
    ObstacleProjector(
        CAMERA,
        Extrinsics.from_mounting(
            camera_x=0.1, camera_y=0.03, camera_height=0.3, camera_pitch=0.4, lidar_height=0.2
        ),
        grid,
        min_obstacle_height=0.02,
        max_obstacle_height=0.5,
        range_min=0.2,
        range_max=4.0,
    )
    for grid in GRIDS
]
SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])

lidar_values = st.one_of(
    st.floats(0.0, 8.0, width=32),
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0]),
)
depth_values = st.sampled_from([0, 150, 300, 500, 800, 1200, 2500, 3900, 6000])


@st.composite
def cases(draw):
    projector = draw(st.sampled_from(PROJECTORS))
    ranges = draw(hnp.arrays(np.float32, projector.grid.count, elements=lidar_values))
    grid = projector.grid
    lidar = Scan(
        angle_min=grid.angle_min,
        angle_max=grid.angle_max,
        angle_increment=grid.angle_increment,
        range_min=LIDAR_LIMITS[0],
        range_max=LIDAR_LIMITS[1],
        ranges=ranges,
        frame_id='laser',
        stamp_ns=42,
    )
    depth = draw(hnp.arrays(np.uint16, (CAMERA.height, CAMERA.width), elements=depth_values))
    return projector, lidar, depth


def in_limits(values, low, high):
    with np.errstate(invalid='ignore'):
        return np.isfinite(values) & (values >= low) & (values <= high)


@SETTINGS
@given(cases())
def test_merge_invariants_with_obstacle_scan(case):
    projector, lidar, depth = case
    depth_scan = projector.scan(depth)
    fused = merge_scans(lidar, depth_scan)
    lidar_ranges, depth_ranges, merged = lidar.ranges, depth_scan.ranges, fused.ranges
    # the LiDAR's layout, count and header
    assert len(fused) == len(lidar)
    assert (fused.angle_min, fused.angle_increment, fused.angle_max) == (
        lidar.angle_min,
        lidar.angle_increment,
        lidar.angle_max,
    )
    np.testing.assert_array_equal(fused.angles(), lidar.angles())
    assert (fused.frame_id, fused.stamp_ns) == ('laser', 42)
    # never farther than a finite in-range LiDAR reading
    lidar_valid = in_limits(lidar_ranges, *LIDAR_LIMITS)
    assert np.all(merged[lidar_valid] <= lidar_ranges[lidar_valid])
    # NaN never hides a finite reading of either side
    depth_valid = in_limits(depth_ranges, depth_scan.range_min, depth_scan.range_max)
    assert not np.isnan(merged[lidar_valid | depth_valid]).any()
    only_depth = depth_valid & np.isnan(lidar_ranges)
    np.testing.assert_array_equal(merged[only_depth], depth_ranges[only_depth])
    # -Inf (too close) wins over everything
    too_close = (lidar_ranges == -np.inf) | (depth_ranges == -np.inf)
    assert np.all(merged[too_close] == -np.inf)
    # a depth reading never makes a finite LiDAR reading farther; nearer obstacles win
    nearer = depth_valid & lidar_valid & (depth_ranges < lidar_ranges)
    np.testing.assert_array_equal(merged[nearer], depth_ranges[nearer])


@SETTINGS
@given(cases())
def test_all_nan_depth_returns_the_lidar_s_real_readings(case):
    projector, lidar, _ = case
    nothing = np.full((CAMERA.height, CAMERA.width), np.nan, np.float32)
    depth_scan = projector.scan(nothing)
    assert np.isnan(depth_scan.ranges).all()
    # Real readings (positive, inside the LiDAR's own limits) and +-Inf unchanged; a
    # driver's error values are no information (NaN).
    r = lidar.ranges
    with np.errstate(invalid='ignore'):
        kept = ((r > 0) & (r >= lidar.range_min) & (r <= lidar.range_max)) | np.isinf(r)
    expected = np.where(kept, r, np.float32(np.nan))
    fused = merge_scans(lidar, depth_scan)
    np.testing.assert_array_equal(fused.ranges, expected)
    zeros = projector.scan(np.zeros((CAMERA.height, CAMERA.width), np.uint16))
    np.testing.assert_array_equal(merge_scans(lidar, zeros).ranges, expected)
