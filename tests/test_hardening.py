"""Regression tests of issue 11 (core items): bad input ends in a clear ScanfuseError.

1. mountings and transforms are validated at every entry (config, Transform,
   Extrinsics, TF messages);
2. the pipeline's caches are bounded, grids within tolerance share an entry, NaN grids
   and NaN distortion are malformed messages;
3. obstacle_min_points is bounded;
10. the row method handles rays lost to distortion and refuses degenerate cameras.
(Item 4, the merge, is in test_merge.py and test_merge_real.py.)
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from scanfuse import FusionConfig, FusionPipeline, Method, Scan
from scanfuse import pipeline as fusion
from scanfuse.camera import CameraModel
from scanfuse.convert.row import row_scan
from scanfuse.distortion import undistort_normalized
from scanfuse.errors import ConfigError, InputError, MessageError, TransformError
from scanfuse.ros import messages
from scanfuse.ros.messages import StampedTransform
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics, Transform
from tests.support import REPOSITORY
from tests.support.reference import row_scan_loop
from tests.support.synthetic import Scene

REPO = REPOSITORY

SCENE = Scene(width=160, height=120, focal=100.0, readings=360)


def lidar_scan(angle_min: float = SCENE.angle_min, increment: float = SCENE.angle_increment):
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (SCENE.readings - 1),
        angle_increment=increment,
        range_min=0.15,
        range_max=SCENE.lidar_range_max,
        ranges=SCENE.lidar_ranges(),
        frame_id='laser',
    )


def scene_config(**changes: object) -> FusionConfig:
    return FusionConfig(
        camera_x=SCENE.camera_x,
        camera_height=SCENE.camera_height,
        camera_pitch=SCENE.camera_pitch,
        lidar_height=SCENE.lidar_height,
        **changes,
    )


def run_isolated(code: str) -> str:
    """Run `code` in a fresh interpreter (a segfault fails the test, not pytest); its stdout."""
    done = subprocess.run(
        [sys.executable, '-c', textwrap.dedent(code)],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, f'exit {done.returncode}\n{done.stdout}\n{done.stderr}'
    return done.stdout


# --- 1. mountings and transforms ------------------------------------------------------------


@pytest.mark.parametrize(
    ('name', 'value', 'match'),
    [
        ('camera_x', 1e39, 'camera_x: Input should be less than or equal to 100'),
        ('camera_y', -150.0, 'camera_y: Input should be greater than or equal to -100'),
        ('camera_height', math.nan, 'camera_height: Input should be a finite number'),
        ('lidar_x', math.inf, 'lidar_x: Input should be a finite number'),
        ('lidar_height', 1e39, 'lidar_height: Input should be less than or equal to 100'),
        ('camera_pitch', math.inf, 'camera_pitch: Input should be a finite number'),
        ('camera_roll', 7.0, 'camera_roll: Input should be less than or equal to 6.28'),
        ('camera_yaw', -1e300, 'camera_yaw: Input should be greater than or equal to -6.28'),
        ('lidar_yaw', math.nan, 'lidar_yaw: Input should be a finite number'),
        ('max_time_offset', math.inf, 'max_time_offset: Input should be a finite number'),
        ('max_time_offset', 1e300, 'max_time_offset: Input should be less than or equal to 10'),
        ('camera_timeout', math.inf, 'camera_timeout: Input should be a finite number'),
        ('range_max', math.inf, 'range_max: Input should be a finite number'),
        ('floor_margin', math.inf, 'floor_margin: Input should be a finite number'),
        ('max_obstacle_height', 1e39, 'max_obstacle_height: Input should be less than or equal'),
    ],
)
def test_absurd_mountings_and_times_are_config_errors(name, value, match):
    with pytest.raises(ConfigError, match=match):
        FusionConfig.from_dict({name: value})


def test_a_parameter_file_with_inf_offset_is_one_clear_error(tmp_path):
    path = tmp_path / 'params.yaml'
    path.write_text('scanfuse:\n  ros__parameters:\n    max_time_offset: .inf\n')
    with pytest.raises(ConfigError, match='max_time_offset: Input should be a finite number'):
        FusionConfig.from_ros_params(path)


def test_the_bounds_themselves_are_accepted():
    config = FusionConfig.from_dict(
        {'camera_x': 100.0, 'lidar_y': -100.0, 'camera_yaw': 2 * math.pi, 'max_time_offset': 10.0}
    )
    assert (config.camera_x, config.lidar_y, config.max_time_offset) == (100.0, -100.0, 10.0)


def test_transform_beyond_any_tf_tree_is_refused():
    with pytest.raises(TransformError, match=r'more than 1e\+09 m from its parent frame'):
        Transform(translation=(1e39, 0.0, 0.0))
    # A UTM northing (below 1e7 m) is a legitimate map frame.
    assert Transform(translation=(0.0, 9.9e6, 0.0)).translation[1] == 9.9e6


def test_a_quaternion_whose_squares_overflow_is_still_normalised():
    # (1, 0, 0, 1) scaled by 1e300: 90 degrees about x. Before, its norm overflowed to Inf
    # and the rotation became (0, 0, 0, 0), a zero-length quaternion deep in the pipeline.
    half = math.sqrt(0.5)
    rotation = Transform((1e300, 0.0, 0.0, 1e300)).rotation
    assert rotation == pytest.approx((half, 0.0, 0.0, half), abs=1e-15)
    with pytest.raises(TransformError, match='has zero length'):
        Transform((1e-170, 0.0, 0.0, 1e-170))


@pytest.mark.parametrize('laser', [True, False])
def test_extrinsics_more_than_100_m_from_the_base_are_refused(laser):
    far = Transform(translation=(0.0, 0.0, 150.0))
    sensor, kwargs = ('LiDAR', {'base_to_laser': far}) if laser else ('depth camera', {})
    if not laser:
        kwargs = {'base_to_camera_optical': far}
    with pytest.raises(TransformError, match=rf'the {sensor} is mounted at .* more than 100 m'):
        Extrinsics(**kwargs)


@pytest.mark.parametrize('value', [1e39, math.nan, -math.inf])
def test_tf_message_with_a_corrupt_translation_is_malformed(value):
    raw = messages.tf_message_to_cdr(
        [StampedTransform('base_link', 'camera_link', (value, 0.0, 0.5), (0.0, 0.0, 0.0, 1.0))]
    )
    with pytest.raises(MessageError, match="'base_link' -> 'camera_link' has the translation"):
        messages.transforms_from_cdr(raw)


def test_fusing_with_a_float32_overflowing_mounting_is_an_error_not_a_crash():
    # Before: the configured mounting was accepted and fused (silently wrong or worse);
    # explicit extrinsics reached the kernel as Inf.
    out = run_isolated(
        """
        from scanfuse import FusionConfig, FusionPipeline, ScanfuseError
        from scanfuse.transforms import Extrinsics, Transform
        from tests.test_hardening import SCENE, lidar_scan
        for name in ('camera_x', 'camera_height', 'lidar_y', 'lidar_height'):
            try:
                config = FusionConfig.from_dict({name: 1e39})
                FusionPipeline(config).fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera)
                print(name, 'fused')
            except ScanfuseError as err:
                print(name, type(err).__name__)
        try:
            far = Extrinsics(base_to_camera_optical=Transform(translation=(1e39, 0, 0.45)))
            FusionPipeline().fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera, far)
            print('extrinsics fused')
        except ScanfuseError as err:
            print('extrinsics', type(err).__name__)
        """
    )
    assert out.split('\n')[:5] == [
        'camera_x ConfigError',
        'camera_height ConfigError',
        'lidar_y ConfigError',
        'lidar_height ConfigError',
        'extrinsics TransformError',
    ]


def test_a_corrupt_motion_is_refused_before_the_kernel_bins_its_points():
    # Found by the fuzz test: PlanarMotion(ty=nan) sent every moved point to a NaN slot
    # and the kernel read out of bounds (a segfault, 1 run in 3 of that seed).
    out = run_isolated(
        """
        import math
        from scanfuse import FusionPipeline, ScanfuseError
        from scanfuse.motion import PlanarMotion
        from tests.test_hardening import SCENE, lidar_scan, scene_config
        for motion in (
            PlanarMotion(ty=math.nan),
            PlanarMotion(tx=1e39),
            PlanarMotion(cos=math.inf),
            PlanarMotion(cos=0.0, sin=0.0),
            PlanarMotion(tx=150.0),
        ):
            try:
                FusionPipeline(scene_config()).fuse(
                    lidar_scan(), SCENE.depth_mm(), SCENE.camera, None, motion
                )
                print('fused')
            except ScanfuseError as err:
                print(type(err).__name__, err)
        """
    )
    lines = out.splitlines()
    expected = ['must be finite', 'more than 100 m', 'must be finite', 'is not a rotation', '100 m']
    assert len(lines) == len(expected)
    for line, phrase in zip(lines, expected, strict=True):
        assert line.startswith('InputError motion PlanarMotion(')
        assert phrase in line


# --- 2. bounded caches, tolerant grids, malformed grids and distortion ------------------------


def test_grids_within_a_hundredth_of_a_slot_match():
    grid = AngleGrid(-math.pi, 2 * math.pi / 720, 720)
    slot = grid.angle_increment
    assert fusion.grids_match(grid, AngleGrid(grid.angle_min + 0.005 * slot, slot, 720))
    assert not fusion.grids_match(grid, AngleGrid(grid.angle_min + 0.02 * slot, slot, 720))
    # An increment off by 2e-5 slot moves the last of 720 readings by 0.0144 slot.
    assert not fusion.grids_match(grid, AngleGrid(grid.angle_min, slot * (1 + 2e-5), 720))
    assert fusion.grids_match(grid, AngleGrid(grid.angle_min, slot * (1 + 1e-5), 720))
    assert not fusion.grids_match(grid, AngleGrid(grid.angle_min, slot, 719))
    assert fusion.GRID_TOLERANCE == 0.01


def test_grid_cache_keeps_the_most_recently_used():
    cache: fusion.GridCache[str, int] = fusion.GridCache(2)
    grids = [(AngleGrid(float(i), 0.01, 10),) for i in range(3)]
    cache.put('a', grids[0], 0)
    cache.put('a', grids[1], 1)
    assert cache.get('a', grids[0]) == 0  # 0 is now the most recent: 1 goes next
    cache.put('a', grids[2], 2)
    assert (cache.get('a', grids[1]), cache.get('a', grids[0]), cache.get('a', grids[2])) == (
        None,
        0,
        2,
    )
    assert cache.get('b', grids[0]) is None
    assert len(cache) == 2


def test_a_jittering_lidar_grid_shares_one_projector():
    # angle_min drifting 1 microradian per scan (rplidar_ros): before, a new ~9 MB
    # projector per scan. 50 microradians is 0.6 % of this LiDAR's 8.7 mrad slot.
    pipeline = FusionPipeline(scene_config(method=Method.OBSTACLE))
    reference = pipeline.fuse(lidar_scan(), SCENE.depth_mm(), SCENE.camera).depth_scan
    for step in range(1, 51):
        lidar = lidar_scan(SCENE.angle_min + 1e-6 * step)
        result = pipeline.fuse(lidar, SCENE.depth_mm(), SCENE.camera)
        np.testing.assert_array_equal(result.depth_scan.ranges, reference.ranges)
        # Published on the LiDAR's own grid, not the cached one.
        assert result.fused.angle_min == result.depth_scan.angle_min == lidar.angle_min
    assert pipeline.cached == (1, 0)


@pytest.mark.parametrize('method', [Method.OBSTACLE, Method.ROW])
def test_distinct_grids_never_keep_more_than_a_few_entries(method):
    pipeline = FusionPipeline(scene_config(method=method))
    for step in range(12):
        pipeline.fuse(lidar_scan(SCENE.angle_min + 0.05 * step), SCENE.depth_mm(), SCENE.camera)
    if method is Method.OBSTACLE:
        expected = (fusion.PROJECTOR_CACHE_SIZE, 0)
    else:
        expected = (0, fusion.PLAN_CACHE_SIZE)
    assert pipeline.cached == expected


@pytest.mark.parametrize(
    ('field', 'value'), [('angle_min', math.nan), ('angle_max', math.inf), ('range_min', math.nan)]
)
def test_nan_grids_and_limits_are_malformed_scans(field, value):
    scan = lidar_scan()
    with pytest.raises(InputError, match='the driver publishes a malformed LaserScan'):
        scan.with_ranges(scan.ranges, **{field: value})
    message = messages.scan_to_msg(scan)
    setattr(message, field, value)
    raw = messages.serialize(message, messages.LASER_SCAN)
    with pytest.raises(MessageError, match="LaserScan in frame 'laser' is unusable"):
        messages.scan_from_cdr(raw)


def test_angle_grid_needs_a_finite_start():
    with pytest.raises(InputError, match='angle_min must be finite, got nan'):
        AngleGrid(math.nan, 0.01, 10)


def test_nan_distortion_is_a_malformed_camera_info():
    with pytest.raises(InputError, match=r'distortion coefficients \(nan, 0.0'):
        CameraModel(640, 480, 525.0, 525.0, 319.5, 239.5, 'plumb_bob', (math.nan, 0.0, 0, 0, 0))
    camera = CameraModel(640, 480, 525.0, 525.0, 319.5, 239.5, 'plumb_bob', (0.1, 0, 0, 0, 0))
    message = messages.camera_to_msg(camera, stamp_ns=0)
    message.d[1] = math.nan
    raw = messages.serialize(message, messages.CAMERA_INFO)
    with pytest.raises(MessageError, match=r'CameraInfo .* is unusable: .* must be finite'):
        messages.camera_from_cdr(raw)
    with pytest.raises(InputError, match='plumb_bob distortion coefficients must be finite'):
        undistort_normalized([0.1], [0.1], 'plumb_bob', (0.1, math.inf, 0, 0, 0))


@pytest.mark.parametrize(('fx', 'cx'), [(1e-300, 319.5), (525.0, 1e30), (0.01, 319.5)])
def test_intrinsics_beyond_any_pinhole_camera_are_refused(fx, cx):
    with pytest.raises(InputError, match='degrees off the optical axis, beyond any pinhole'):
        CameraModel(640, 480, fx, 525.0, cx, 239.5)


# --- 3. obstacle_min_points ------------------------------------------------------------------


@pytest.mark.parametrize(
    ('value', 'match'),
    [(5000, 'less than or equal to 64'), (100_000, 'less than or equal to 64'), (0, 'greater')],
)
def test_obstacle_min_points_is_bounded(value, match):
    with pytest.raises(ConfigError, match=f'obstacle_min_points: Input should be {match}'):
        FusionConfig.from_dict({'obstacle_min_points': value})
    assert FusionConfig(obstacle_min_points=64).obstacle_min_points == 64


# --- 10. row method edge cases ---------------------------------------------------------------

# A plausible wide-angle lens whose model is not invertible in the image's top corners.
WIDE = CameraModel(640, 480, 450.0, 450.0, 319.5, 239.5, 'plumb_bob', (0.3, 0.0, 0.0, 0.0, -0.5))
LIMITS = {'range_min': 0.2, 'range_max': 10.0}


def test_rays_lost_to_distortion_take_no_part_in_the_row():
    x_table, _ = WIDE.normalized_coordinates
    lost = np.isnan(x_table[0])
    assert 0 < lost.sum() < WIDE.width  # the premise: some, not all, of row 0 has no ray
    rng = np.random.default_rng(11)
    depth = rng.uniform(0.5, 6.0, size=(WIDE.height, WIDE.width)).astype(np.float32)
    for height in (1, 5):
        fast = row_scan(depth, WIDE, scan_row=0, scan_height=height, **LIMITS)
        slow = row_scan_loop(depth, WIDE, scan_row=0, scan_height=height, **LIMITS)
        assert fast.angle_min == pytest.approx(slow.angle_min, abs=1e-12)
        np.testing.assert_allclose(fast.ranges, slow.ranges, rtol=1e-6)
    # The grid spans the columns that have a ray, and every slot holds one.
    angles = -np.arctan(x_table[0][~lost].astype(np.float64))
    assert fast.angle_min == pytest.approx(angles.min(), abs=1e-9)
    assert fast.angle_max == pytest.approx(angles.max(), abs=1e-9)
    assert np.isfinite(row_scan(depth.astype(np.float32), WIDE, scan_row=0, **LIMITS).ranges).all()
    mm = (depth * 1000).astype(np.uint16)
    assert np.isfinite(row_scan(mm, WIDE, scan_row=0, **LIMITS).ranges).all()


def test_a_row_without_any_ray_is_a_clear_error():
    camera = CameraModel(640, 480, 250.0, 250.0, 319.5, 239.5, 'plumb_bob', (0.3, 0, 0, 0, -0.5))
    depth = np.full((480, 640), 1000, np.uint16)
    with pytest.raises(InputError, match='no pixel of the scan row has a ray'):
        row_scan(depth, camera, scan_row=0, **LIMITS)


def test_d2l_compat_refuses_a_one_pixel_wide_camera():
    camera = CameraModel(1, 480, 525.0, 525.0, 0.0, 239.5)
    with pytest.raises(InputError, match='d2l_compat needs an image at least 2 pixels wide'):
        row_scan(np.full((480, 1), 1000, np.uint16), camera, d2l_compat=True, **LIMITS)
    # The default mode makes one slot of it.
    assert len(row_scan(np.full((480, 1), 1000, np.uint16), camera, **LIMITS)) == 1


def test_d2l_compat_refuses_a_field_of_view_float32_cannot_resolve():
    camera = CameraModel(640, 480, 1e30, 1e30, 319.5, 239.5)
    with pytest.raises(InputError, match='too little for float32 angles to tell its columns'):
        row_scan(np.full((480, 640), 1000, np.uint16), camera, d2l_compat=True, **LIMITS)


def test_columns_of_one_bearing_are_a_clear_error():
    camera = CameraModel(640, 480, 1e300, 1e300, 319.5, 239.5)  # x_n underflows to 0
    with pytest.raises(InputError, match='the columns of the scan row all have the bearing'):
        row_scan(np.full((480, 640), 1000, np.uint16), camera, **LIMITS)


@pytest.mark.parametrize(
    ('camera', 'changes', 'match'),
    [
        (WIDE, {'scan_row': 0}, None),
        (CameraModel(1, 480, 525.0, 525.0, 0.0, 239.5), {'d2l_compat': True}, '2 pixels wide'),
        (CameraModel(640, 480, 1e30, 1e30, 319.5, 239.5), {'d2l_compat': True}, 'float32'),
    ],
)
def test_row_method_in_the_pipeline_gives_a_result_or_a_scanfuse_error(camera, changes, match):
    pipeline = FusionPipeline(scene_config(method=Method.ROW, **changes))
    depth = np.full((camera.height, camera.width), 1500, np.uint16)
    if match is None:
        assert len(pipeline.fuse(lidar_scan(), depth, camera).fused) == SCENE.readings
    else:
        with pytest.raises(InputError, match=match):
            pipeline.fuse(lidar_scan(), depth, camera)
