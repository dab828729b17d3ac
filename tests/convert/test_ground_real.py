"""The floor found in a real Kinect frame (issue 25): `../shared/data/real/pcl_grabber`, a
camera about 0.7 m over a carpet, pitched about 45 deg, a laptop and a small box on it.

The right mounting is an independent floor fit (`floor_fit.fit_floor`: RANSAC and least
squares on the whole frame). The LiDAR is assumed at the base's origin, 0.3 m up (no LiDAR
saw this scene). Given a mounting 5 cm off in height, the ground estimate gives the right
mounting's scan; 3 deg off in pitch, it puts the floor right (no floor slot), while the
camera's points stay where the given pitch puts them across the floor: the laptop's and
the box's edges move by a few slots.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.convert.floor_fit import FloorFit, fit_floor
from scanfuse.stream import FusionStream
from tests.support.ground_scene import NS, lidar_scan

CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0, frame_id='optical')


@pytest.fixture(scope='module')
def frame(real_data):
    tifffile = pytest.importorskip('tifffile')
    path = real_data / 'pcl_grabber' / 'frame_20121214T142255.814212_depth.tiff'
    return tifffile.imread(path)


@pytest.fixture(scope='module')
def floor(frame) -> FloorFit:
    return fit_floor(frame, CAMERA)


def depth_scan(frame, fit: FloorFit, *, height_error=0.0, pitch_error=0.0, **changes):
    config = FusionConfig(
        use_tf=False,
        camera_height=fit.camera_height + height_error,
        camera_pitch=fit.camera_pitch + math.radians(pitch_error),
        camera_roll=fit.camera_roll,
        lidar_height=0.3,
        memory=False,
        **changes,
    )
    stream: FusionStream[int] = FusionStream(config)
    stream.add_camera_info(CAMERA)
    out = None
    for index in range(1, 4):
        stamp = index * NS // 10
        stream.add_depth(stamp, frame, stamp)
        lidar = lidar_scan(stamp)
        (out,) = stream.add_scan(lidar, index, stamp + 1)
    assert out is not None
    assert out.depth_scan is not None
    return out.depth_scan.ranges, stream


@pytest.mark.real_data
@pytest.mark.parametrize('height_error', [0.05, -0.05])
def test_a_mounting_5_cm_off_gives_the_right_mountings_scan(frame, floor, height_error):
    right, _ = depth_scan(frame, floor, ground_estimate=False)
    found, stream = depth_scan(frame, floor, height_error=height_error)
    np.testing.assert_array_equal(np.isfinite(found), np.isfinite(right))
    finite = np.isfinite(right)
    assert np.abs(found[finite] - right[finite]).max() <= 0.005
    off, _ = depth_scan(frame, floor, height_error=height_error, ground_estimate=False)
    assert np.isfinite(off).sum() > np.isfinite(right).sum() + 100  # the carpet, without it
    assert stream.ground is not None
    estimate = stream.ground.estimate
    assert estimate is not None
    assert estimate.offset == pytest.approx(floor.camera_height, abs=0.01)
    assert math.degrees(estimate.camera_pitch) == pytest.approx(
        math.degrees(floor.camera_pitch), abs=0.3
    )


@pytest.mark.real_data
@pytest.mark.parametrize('pitch_error', [3.0, -3.0])
def test_a_mounting_3_deg_off_finds_the_floor_and_keeps_the_obstacles(frame, floor, pitch_error):
    right, _ = depth_scan(frame, floor, ground_estimate=False)
    found, stream = depth_scan(frame, floor, pitch_error=pitch_error)
    assert stream.ground is not None
    estimate = stream.ground.estimate
    assert estimate is not None
    assert estimate.offset == pytest.approx(floor.camera_height, abs=0.01)
    assert math.degrees(estimate.camera_pitch) == pytest.approx(
        math.degrees(floor.camera_pitch), abs=0.3
    )
    both = np.isfinite(found) & np.isfinite(right)
    within = np.abs(found[both] - right[both]) <= 0.05 + 0.02 * right[both]
    assert within.mean() >= 0.95
    # Slots one scan has and the other not: the obstacles' edges, a few of 1440.
    assert (np.isfinite(found) != np.isfinite(right)).sum() <= 30
