"""Drop-offs on real sensor noise: every depth frame in ../shared/data/real (issue 15 item 4).

The frames (README there) are Kinect v1 / Xtion class, with flat floors and no drop-off.
Their camera poses are not recorded above a floor, so, as the other real-data tests do,
each frame's floor comes from `fit_floor`: the floor is the lowest large plane the camera
looks down on (a table top or a seat lies higher, a wall is steep), found by fitting
planes in turn, each time without the previous plane's points. The pcl_grabber MCAP bag
holds the same depth as its TIFF (test_bag_real), so the TIFF stands for both.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
import tifffile
from PIL import Image

from scanfuse import FusionConfig
from scanfuse.camera import CameraModel, depth_in_metres
from scanfuse.convert.floor_fit import FloorFit, fit_floor
from scanfuse.convert.obstacle import DropLimits, ObstacleProjector
from scanfuse.errors import InputError
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    from pathlib import Path

pytestmark = pytest.mark.real_data

GRID = AngleGrid(-math.pi, 2.0 * math.pi / 1080, 1080)
DEFAULTS = FusionConfig()
DROPS = DropLimits(DEFAULTS.drop_min_depth, DEFAULTS.drop_min_width, DEFAULTS.depth_noise)


def _pgm(path: Path, byte_order: str) -> np.ndarray:
    """Binary 16-bit PGM: header `P5 width height maxval`, then width x height samples."""
    data = path.read_bytes()
    magic, width, height = data.split(maxsplit=3)[:3]
    assert magic == b'P5'
    count = int(width) * int(height)
    samples = np.frombuffer(data[-2 * count :], dtype=f'{byte_order}u2')
    return samples.reshape(int(height), int(width))


def _png16(path: Path) -> np.ndarray:
    with Image.open(path) as image:
        return np.array(image).astype(np.uint16)


def _slambook_ch5(n: int):
    def load(root: Path) -> np.ndarray:
        return _pgm(root / f'slambook2/ch5_rgbd/depth/{n}.pgm', '>').astype(np.uint16)

    return load


def _tum(relative: str):
    def load(root: Path) -> np.ndarray:
        return (_png16(root / relative).astype(np.float64) / 5000.0).astype(np.float32)

    return load


def _sun(root: Path) -> np.ndarray:
    raw = _png16(root / 'open3d_rgbd/SUN_depth.png').astype(np.uint32)
    return (((raw >> 3) | (raw << 13)) & 0xFFFF).astype(np.uint16)


def _nyu(root: Path) -> np.ndarray:
    raw = _pgm(root / 'open3d_rgbd/NYU_depth.pgm', '<').astype(np.float64)
    with np.errstate(divide='ignore'):
        metres = np.where(raw >= 2047, np.nan, 351.3 / (1092.5 - raw))
    return metres.astype(np.float32)


def _pcl(root: Path) -> np.ndarray:
    return tifffile.imread(root / 'pcl_grabber/frame_20121214T142255.814212_depth.tiff')


# name: (loader, fx, fy, cx, cy) as the README gives them
FRAMES = {
    'pcl_grabber': (_pcl, 525.0, 525.0, 320.0, 240.0),
    'slambook2 ch5 1': (_slambook_ch5(1), 518.0, 519.0, 325.5, 253.5),
    'slambook2 ch5 2': (_slambook_ch5(2), 518.0, 519.0, 325.5, 253.5),
    'slambook2 ch5 3': (_slambook_ch5(3), 518.0, 519.0, 325.5, 253.5),
    'slambook2 ch7': (_tum('slambook2/ch7/1_depth.png'), 520.9, 521.0, 325.1, 249.7),
    'open3d TUM': (_tum('open3d_rgbd/TUM_depth.png'), 525.0, 525.0, 319.5, 239.5),
    'open3d SUN': (_sun, 570.3, 570.3, 320.0, 240.0),
    'open3d NYU': (_nyu, 582.624, 582.691, 313.045, 238.444),
}


def floor_of(depth: np.ndarray, camera: CameraModel) -> FloorFit:
    """The lowest floor-like plane among the four largest (pitch 0-75 deg, |roll| < 30 deg)."""
    work = depth.copy()
    x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
    z = depth_in_metres(depth).astype(np.float64)
    candidates = []
    for _ in range(4):
        try:
            fit = fit_floor(work, camera, min_inlier_share=0.05)
        except InputError:
            break
        if 0.0 < fit.camera_pitch < math.radians(75.0) and abs(fit.camera_roll) < math.radians(30):
            candidates.append(fit)
        normal = fit.normal
        distance = (normal[0] * x_n + normal[1] * y_n + normal[2]) * z + fit.camera_height
        with np.errstate(invalid='ignore'):
            work[np.abs(distance) < 0.05] = 0 if work.dtype == np.uint16 else np.nan
    assert candidates, 'no floor-like plane'
    return max(candidates, key=lambda fit: fit.camera_height)


@pytest.fixture(scope='module')
def frames(real_data: Path) -> dict[str, tuple[np.ndarray, CameraModel, FloorFit]]:
    loaded = {}
    for name, (load, fx, fy, cx, cy) in FRAMES.items():
        depth = load(real_data)
        camera = CameraModel.from_intrinsics(depth.shape[1], depth.shape[0], fx, fy, cx, cy)
        loaded[name] = (depth, camera, floor_of(depth, camera))
    return loaded


@pytest.mark.parametrize('range_max', [DEFAULTS.range_max, 5.0])
@pytest.mark.parametrize('min_points', [DEFAULTS.obstacle_min_points, 1])
def test_no_drop_slot_on_any_real_frame(frames, range_max, min_points):
    drop_slots = {}
    behind_floor = {}
    for name, (depth, camera, floor) in frames.items():
        extrinsics = Extrinsics.from_mounting(
            camera_height=floor.camera_height,
            camera_pitch=floor.camera_pitch,
            camera_roll=floor.camera_roll,
            lidar_height=0.2,
        )
        scanner = ObstacleProjector(
            camera,
            extrinsics,
            GRID,
            min_obstacle_height=DEFAULTS.min_obstacle_height,
            max_obstacle_height=DEFAULTS.max_obstacle_height,
            range_min=DEFAULTS.range_min,
            range_max=range_max,
            min_points=min_points,
            cluster_spread=DEFAULTS.obstacle_cluster_spread,
            drops=DropLimits(
                DEFAULTS.drop_min_depth, DEFAULTS.drop_min_width, DEFAULTS.depth_noise
            ),
        )
        scanner.scan(depth)
        drop_slots[name] = int(scanner.drop_slots.sum())
        # Readings behind the fitted floor (noise, the carpet's pile) where the floor is in
        # range: Z > Z0 = -h / (n . ray), n the floor's upward normal in the optical frame.
        x_n, y_n = (c.astype(np.float64) for c in camera.normalized_coordinates)
        rate = floor.normal[0] * x_n + floor.normal[1] * y_n + floor.normal[2]
        with np.errstate(divide='ignore', invalid='ignore'):
            at_floor = np.where(rate < 0.0, -floor.camera_height / rate, np.nan)
            z = depth_in_metres(depth)
            in_range = (at_floor >= DEFAULTS.range_min) & (at_floor <= range_max)
            behind_floor[name] = int((in_range & (z > at_floor)).sum())
    assert drop_slots == dict.fromkeys(FRAMES, 0)
    # Not vacuous: every frame has thousands of readings behind its floor plane.
    assert min(behind_floor.values()) > 5000, behind_floor
