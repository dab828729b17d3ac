"""Floor fit: a synthetic floor seen from a known pose, and the real pcl_grabber frame."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.convert.floor_fit import FloorFit, check_extrinsics, fit_floor
from scanfuse.errors import InputError
from scanfuse.transforms import Extrinsics

CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)


def floor_depth(height, pitch, roll, *, millimetres=False):
    """Depth of the plane z = 0 seen by a camera at `height` with `pitch` (down) and `roll`.

    The optical-frame ray (x_n, y_n, 1) meets the floor at Z = height / -(up . ray), where
    up, the floor normal in the optical frame, is (-cos p sin r, -cos p cos r, -sin p)
    (worked out from R = Ry(p) Rx(r) and the body-to-optical axes).
    """
    x_n, y_n = (c.astype(np.float64) for c in CAMERA.normalized_coordinates)
    up = (-math.cos(pitch) * math.sin(roll), -math.cos(pitch) * math.cos(roll), -math.sin(pitch))
    down_rate = -(up[0] * x_n + up[1] * y_n + up[2])
    with np.errstate(divide='ignore'):
        depth = np.where(down_rate > 1e-6, height / down_rate, np.nan)
    depth[depth > 8.0] = np.nan
    if millimetres:
        return np.where(np.isnan(depth), 0, np.round(depth * 1000)).astype(np.uint16)
    return depth.astype(np.float32)


@pytest.mark.parametrize(
    ('height', 'pitch_deg', 'roll_deg'),
    [(0.4, 20.0, 0.0), (0.7, 45.0, -6.0), (0.25, 10.0, 3.0), (1.0, 70.0, 0.0)],
)
def test_recovers_known_pose(height, pitch_deg, roll_deg):
    depth = floor_depth(height, math.radians(pitch_deg), math.radians(roll_deg))
    fit = fit_floor(depth, CAMERA)
    assert fit.camera_height == pytest.approx(height, abs=0.005)
    assert math.degrees(fit.camera_pitch) == pytest.approx(pitch_deg, abs=0.2)
    assert math.degrees(fit.camera_roll) == pytest.approx(roll_deg, abs=0.2)
    assert fit.inlier_share > 0.99
    assert check_extrinsics(fit, height, math.radians(pitch_deg), math.radians(roll_deg)) == []


def test_floor_depth_agrees_with_extrinsics():
    # cross-check of the test's own formula against the transforms: floor points have z = 0
    pitch, roll = math.radians(30.0), math.radians(4.0)
    depth = floor_depth(0.5, pitch, roll).astype(np.float64)
    x_n, y_n = CAMERA.normalized_coordinates
    points = np.stack([x_n * depth, y_n * depth, depth], axis=-1).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    extrinsics = Extrinsics.from_mounting(camera_height=0.5, camera_pitch=pitch, camera_roll=roll)
    heights = extrinsics.base_to_camera_optical.apply(points)[:, 2]
    assert np.abs(heights).max() < 1e-5


def test_millimetre_depth_with_a_box_on_the_floor():
    depth = floor_depth(0.45, math.radians(25.0), 0.0, millimetres=True)
    depth[200:300, 250:400] = 900  # a fronto-parallel box face: not the floor
    fit = fit_floor(depth, CAMERA, seed=3)
    assert fit.camera_height == pytest.approx(0.45, abs=0.005)
    assert math.degrees(fit.camera_pitch) == pytest.approx(25.0, abs=0.3)
    assert 0.8 < fit.inlier_share < 0.97


def test_same_seed_same_fit():
    depth = floor_depth(0.45, math.radians(25.0), 0.0, millimetres=True)
    assert fit_floor(depth, CAMERA, seed=7) == fit_floor(depth, CAMERA, seed=7)


def test_warnings_name_each_disagreement():
    fit = FloorFit(0.70, math.radians(45.0), math.radians(-1.0), 0.8, (0.0, -0.7, -0.7), 8, 10)
    warnings = check_extrinsics(fit, 0.45, math.radians(20.0), math.radians(-1.0))
    assert len(warnings) == 2
    assert 'camera_height is 0.450 m but the floor is 0.700 m' in warnings[0]
    assert 'camera_pitch is 20.00 deg but the floor says 45.00 deg' in warnings[1]
    tolerant = check_extrinsics(
        fit, 0.69, math.radians(44.5), math.radians(-1.5), height_tolerance=0.02
    )
    assert tolerant == []
    assert len(check_extrinsics(fit, 0.70, math.radians(45.0), math.radians(1.5))) == 1


def test_too_few_points():
    depth = np.zeros((480, 640), np.uint16)
    depth[:10, :10] = 1000
    with pytest.raises(InputError, match='only 100 valid depth pixels'):
        fit_floor(depth, CAMERA)


def test_no_plane():
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.5, 5.0, (480, 640)).astype(np.float32)  # noise, no surface
    with pytest.raises(InputError, match='no floor plane found'):
        fit_floor(depth, CAMERA)


@pytest.mark.real_data
def test_real_frame(real_data):
    tifffile = pytest.importorskip('tifffile')
    depth = tifffile.imread(real_data / 'pcl_grabber' / 'frame_20121214T142255.814212_depth.tiff')
    assert depth.shape == (480, 640)
    fit = fit_floor(depth, CAMERA)
    # README: about 0.7 m above the carpet, pitched about 45 deg; tolerance 0.1 m and 10 deg
    assert 0.6 < fit.camera_height < 0.8
    assert 35.0 < math.degrees(fit.camera_pitch) < 55.0
    assert abs(math.degrees(fit.camera_roll)) < 10.0
    assert fit.inlier_share > 0.5  # the carpet fills most of the image
    warnings = check_extrinsics(fit, 0.45, math.radians(20.0), 0.0)
    assert any('camera_height' in warning for warning in warnings)
