"""FusionPipeline end to end on a scene whose geometry is worked out by hand.

Scene (tests.support.synthetic.Scene defaults): LiDAR 0.30 m above the floor at the
base origin sees only a wall at x = 2 m; a 0.2 m tall box (front face x = 1.2 m,
|y| <= 0.15 m) lies below its plane; the camera is 0.10 m ahead, 0.45 m high,
pitched 20 deg down.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse import FusionConfig, FusionPipeline, Method, Resampler, Scan
from scanfuse.transforms import Extrinsics
from tests.support.synthetic import Scene

SCENE = Scene(width=320, height=240, focal=200.0, readings=720)


def lidar_scan() -> Scan:
    return Scan(
        angle_min=SCENE.angle_min,
        angle_max=SCENE.angle_min + SCENE.angle_increment * (SCENE.readings - 1),
        angle_increment=SCENE.angle_increment,
        range_min=0.15,
        range_max=SCENE.lidar_range_max,
        ranges=SCENE.lidar_ranges(),
        frame_id='laser',
        stamp_ns=123,
    )


def scene_config(**changes: object) -> FusionConfig:
    return FusionConfig(
        camera_x=SCENE.camera_x,
        camera_height=SCENE.camera_height,
        camera_pitch=SCENE.camera_pitch,
        lidar_height=SCENE.lidar_height,
        **changes,
    )


def fuse(config: FusionConfig):
    return FusionPipeline(config).fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera)


def test_obstacle_method_reports_the_box_from_the_lidar_origin():
    result = fuse(scene_config(method=Method.OBSTACLE))
    angles = result.fused.angles()
    # Rays from the LiDAR origin meet the box's front face where |1.2 tan(a)| <= 0.15.
    on_box = np.abs(1.2 * np.tan(angles)) <= 0.15 - 0.01
    expected = 1.2 / np.cos(angles[on_box])
    np.testing.assert_allclose(result.fused.ranges[on_box], expected, atol=0.01 + 0.01)
    # Beside the box the camera sees the wall's foot inside the slab: its nearest point
    # in each slot is at the slot's edge nearer to the x axis, 2 / cos(|a| - inc / 2),
    # a few millimetres short of the LiDAR's 2 / cos(a) at the slot centre.
    beside = (np.abs(angles) > 0.2) & (np.abs(angles) < 0.5)
    slot_edge = np.abs(angles[beside]) - SCENE.angle_increment / 2
    np.testing.assert_allclose(result.fused.ranges[beside], 2.0 / np.cos(slot_edge), atol=0.002)


def test_row_centre_reports_the_box_at_its_slant_range_from_the_camera():
    # The paper's centre row: the optical axis leaves the camera 20 deg below horizontal
    # and meets the box face 1.1 m ahead of the camera at 1.1 / cos(20 deg) = 1.1706 m.
    # The row method assumes camera and LiDAR share an origin, so that is what it reports.
    for resampler in Resampler:
        result = fuse(scene_config(method=Method.ROW, resample=resampler))
        centre = int(np.argmin(np.abs(result.fused.angles())))
        assert result.fused.ranges[centre] == pytest.approx(
            1.1 / math.cos(SCENE.camera_pitch), abs=0.005
        )


def test_fused_scan_keeps_the_lidar_grid_and_header_for_every_method():
    lidar = lidar_scan()
    configs = [
        scene_config(method=Method.OBSTACLE),
        scene_config(method=Method.ROW, resample=Resampler.LINEAR),
        scene_config(method=Method.ROW, scan_height=SCENE.height),
        scene_config(method=Method.ROW, d2l_compat=True, scan_height=10),
    ]
    for config in configs:
        result = fuse(config)
        assert len(result.fused) == len(result.depth_scan) == len(lidar)
        np.testing.assert_array_equal(result.fused.angles(), lidar.angles())
        assert (result.fused.frame_id, result.fused.stamp_ns) == ('laser', 123)
        valid = np.isfinite(lidar.ranges)
        assert np.all(result.fused.ranges[valid] <= lidar.ranges[valid])
        t = result.timings
        assert min(t.convert, t.resample, t.merge) >= 0.0
        assert t.total == pytest.approx(t.convert + t.resample + t.merge)


def test_explicit_extrinsics_override_the_configured_mounting():
    # Configured as if the camera were at the LiDAR's x; the real mounting is 0.1 m ahead.
    config = FusionConfig(camera_height=SCENE.camera_height, camera_pitch=SCENE.camera_pitch)
    true_mounting = Extrinsics.from_config(scene_config())
    pipeline = FusionPipeline(config)
    wrong = pipeline.fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera)
    right = pipeline.fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera, true_mounting)
    centre = int(np.argmin(np.abs(lidar_scan().angles())))
    assert right.fused.ranges[centre] == pytest.approx(1.2, abs=0.02)
    assert wrong.fused.ranges[centre] == pytest.approx(1.1, abs=0.02)


def test_camera_failure_leaves_the_lidar_scan_unchanged():
    nothing = np.zeros((SCENE.height, SCENE.width), np.uint16)  # 16UC1: 0 = no measurement
    for method in Method:
        result = FusionPipeline(scene_config(method=method)).fuse(
            lidar_scan(), nothing, SCENE.camera
        )
        np.testing.assert_array_equal(result.fused.ranges, lidar_scan().ranges)
