"""Algorithm 1 (row method), default mode: geometry, REP-117 values, errors, and the loop oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse.camera import CameraModel
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.row import row_scan
from scanfuse.errors import ConfigError, InputError, ScanfuseError
from tests.support.reference import row_scan_loop

CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5, frame_id='cam_optical')
LIMITS = {'range_min': 0.2, 'range_max': 10.0}


def _column_angles(camera: CameraModel) -> np.ndarray:
    """theta of each pixel column, worked out from the intrinsics: -atan((u - cx) / fx).

    The camera keeps its ray table in float32, so x_n is rounded the same way here.
    """
    x_n = ((np.arange(camera.width) - camera.cx) / camera.fx).astype(np.float32)
    return -np.arctan(x_n.astype(np.float64))


def _wall(camera: CameraModel, metres: float, dtype: type) -> np.ndarray:
    if dtype is np.uint16:
        return np.full((camera.height, camera.width), round(metres * 1000), dtype=np.uint16)
    return np.full((camera.height, camera.width), metres, dtype=np.float32)


@pytest.mark.parametrize('dtype', [np.uint16, np.float32])
def test_wall_at_two_metres_gives_two_over_cos_theta(dtype: type) -> None:
    scan = row_scan(_wall(CAMERA, 2.0, dtype), CAMERA, **LIMITS)
    centres = scan.angles()
    columns = _column_angles(CAMERA)
    half = 0.5 * scan.angle_increment
    for centre, value in zip(centres, scan.ranges, strict=True):
        # The slot holds the columns within half an increment of its centre; on a
        # fronto-parallel wall each sees r = Z / cos(theta), the nearest wins.
        inside = columns[(columns >= centre - half - 1e-12) & (columns < centre + half + 1e-12)]
        assert inside.size >= 1
        expected = (2.0 / np.cos(inside)).min()
        assert value == pytest.approx(expected, rel=1e-6)
        assert value == pytest.approx(2.0 / math.cos(centre), abs=2.0 * half * math.tan(0.6) + 1e-6)


def test_grid_spans_the_outermost_columns_with_the_widest_column_spacing() -> None:
    scan = row_scan(_wall(CAMERA, 2.0, np.uint16), CAMERA, **LIMITS)
    columns = _column_angles(CAMERA)
    assert scan.angle_min == pytest.approx(columns[-1], abs=1e-9)
    assert scan.angle_max == pytest.approx(columns[0], abs=1e-9)
    # Widest spacing: the two columns around cx = 319.5, at +-0.5 px.
    widest = 2.0 * math.atan(0.5 / CAMERA.fx)
    assert scan.angle_increment >= widest
    assert len(scan) == math.floor((columns[0] - columns[-1]) / widest) + 1
    assert scan.frame_id == 'cam_optical'


@pytest.mark.parametrize('scan_row', [0, 100, 239, 240, 400, 479])
def test_every_slot_is_finite_for_every_row_on_a_wall(scan_row: int) -> None:
    scan = row_scan(_wall(CAMERA, 2.0, np.float32), CAMERA, scan_row=scan_row, **LIMITS)
    assert np.isfinite(scan.ranges).all()


def test_every_slot_is_finite_for_every_row_and_odd_camera() -> None:
    camera = CameraModel.from_intrinsics(848, 480, 421.3, 421.9, 427.9, 236.1)
    wall = _wall(camera, 2.0, np.uint16)
    for scan_row in range(camera.height):
        assert np.isfinite(row_scan(wall, camera, scan_row=scan_row, **LIMITS).ranges).all()


def test_rep117_values_beyond_close_and_missing() -> None:
    depth = np.zeros((CAMERA.height, CAMERA.width), dtype=np.uint16)
    row = 240
    depth[row, :200] = 15000  # 15 m, beyond range_max
    depth[row, 200:400] = 100  # 0.1 m, closer than range_min
    # columns 400.. stay 0: no measurement
    scan = row_scan(depth, CAMERA, scan_row=row, **LIMITS)
    # Angles grow to the left of the image: the first slot is column 639, the last column 0.
    assert np.isnan(scan.ranges[0])
    assert scan.ranges[-1] == np.inf
    straight_ahead = round(-scan.angle_min / scan.angle_increment)  # columns 319-320
    assert scan.ranges[straight_ahead] == -np.inf
    assert set(np.unique(scan.ranges[np.isfinite(scan.ranges) | np.isinf(scan.ranges)])) == {
        -np.inf,
        np.inf,
    }


def test_reduction_prefers_value_then_too_close_then_beyond_then_nothing() -> None:
    # One slot fed by a band of rows: the preferred outcome must not depend on row order.
    camera = CameraModel.from_intrinsics(2, 4, 100.0, 100.0, 0.5, 1.5)
    orders = [[0.1, np.inf, np.nan, 3.0], [3.0, np.nan, np.inf, 0.1], [np.nan, 3.0, 0.1, np.inf]]
    for column in orders:
        depth = np.tile(np.asarray(column, dtype=np.float32)[:, None], (1, 2))
        ranges = row_scan(depth, camera, scan_height=4, **LIMITS).ranges
        # x_n = +-0.005: r = 3 sqrt(1 + 0.005^2)
        assert ranges == pytest.approx([3.0 * math.sqrt(1.000025)] * 2, rel=1e-6)
    for column, expected in (
        ([0.1, np.inf, np.nan, np.nan], -np.inf),
        ([np.inf, np.nan, 12.0, np.nan], np.inf),
        ([np.nan, np.nan, 0.0, np.nan], np.nan),
        ([-np.inf, np.nan, np.inf, np.nan], -np.inf),
    ):
        depth = np.tile(np.asarray(column, dtype=np.float32)[:, None], (1, 2))
        ranges = row_scan(depth, camera, scan_height=4, **LIMITS).ranges
        np.testing.assert_array_equal(ranges, [expected, expected])


def test_band_takes_the_nearest_row_per_column() -> None:
    depth = np.full((CAMERA.height, CAMERA.width), 3000, dtype=np.uint16)
    depth[238, 320] = 1000  # inside a band of 5 around row 240
    depth[230, 100] = 500  # outside it
    ranges = row_scan(depth, CAMERA, scan_row=240, scan_height=5, **LIMITS).ranges
    assert ranges.min() == pytest.approx(1.0 * math.sqrt(1 + (0.5 / 525) ** 2), rel=1e-6)
    assert np.sort(ranges)[1] > 2.9


def test_uint16_and_float_input_agree() -> None:
    rng = np.random.default_rng(5)
    codes = rng.integers(0, 12000, size=(CAMERA.height, CAMERA.width)).astype(np.uint16)
    metres = codes.astype(np.float32) * np.float32(0.001)
    metres[codes == 0] = np.nan
    guard = FloorGuard(camera_height=0.4, camera_pitch=0.3)
    for height in (1, 7, 480):
        a = row_scan(codes, CAMERA, scan_height=height, floor_guard=guard, **LIMITS)
        b = row_scan(metres, CAMERA, scan_height=height, floor_guard=guard, **LIMITS)
        np.testing.assert_array_equal(a.ranges, b.ranges)


def test_float64_depth_is_accepted_as_metres() -> None:
    scan = row_scan(_wall(CAMERA, 2.0, np.float32).astype(np.float64), CAMERA, **LIMITS)
    assert scan.ranges.min() == pytest.approx(2.0, rel=1e-6)


def test_distorted_camera_rows_match_the_loop() -> None:
    camera = CameraModel.from_camera_info(
        160,
        120,
        [120.0, 0, 80.0, 0, 120.0, 60.0, 0, 0, 1],
        D=[-0.2, 0.05, 0.0, 0.0, 0.0],
        distortion_model='plumb_bob',
    )
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.5, 6.0, size=(120, 160)).astype(np.float32)
    for height in (1, 31):
        fast = row_scan(depth, camera, scan_row=40, scan_height=height, **LIMITS)
        slow = row_scan_loop(depth, camera, scan_row=40, scan_height=height, **LIMITS)
        np.testing.assert_allclose(fast.ranges, slow.ranges, rtol=1e-6)


# --- errors -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('depth', 'kwargs', 'error', 'match'),
    [
        (np.zeros((480, 640), np.int32), {}, InputError, 'dtype int32 is not supported'),
        (np.zeros((480, 640), np.uint8), {}, InputError, 'dtype uint8 is not supported'),
        (np.zeros((240, 320), np.uint16), {}, InputError, 'depth image is 320x240 but the camera'),
        (np.zeros((480, 640, 3), np.uint16), {}, InputError, 'must be two-dimensional'),
        (np.zeros((0, 0), np.uint16), {}, InputError, 'depth image is empty'),
        (np.zeros((480, 0), np.float32), {}, InputError, 'depth image is empty'),
        (np.zeros((480, 640), np.uint16), {'scan_height': 481}, ConfigError, 'scan_height 481'),
        (np.zeros((480, 640), np.uint16), {'scan_height': 0}, ConfigError, 'scan_height 0'),
        (
            np.zeros((480, 640), np.uint16),
            {'scan_row': 480},
            ConfigError,
            'scan_row 480 is outside',
        ),
        (np.zeros((480, 640), np.uint16), {'scan_row': -1}, ConfigError, 'scan_row -1 is outside'),
        (
            np.zeros((480, 640), np.uint16),
            {'range_min': 5.0, 'range_max': 5.0},
            ConfigError,
            r'range_min \(5.0\) must be smaller than range_max \(5.0\)',
        ),
        (
            np.zeros((480, 640), np.uint16),
            {'range_min': 0.2, 'range_max': math.inf},
            ConfigError,
            'must be finite metres',
        ),
        (
            np.zeros((480, 640), np.uint16),
            {'range_min': -1.0},
            ConfigError,
            r'range limits must lie in \[0',
        ),
        (
            np.zeros((480, 640), np.uint16),
            {'floor_guard': FloorGuard(camera_height=-0.1, camera_pitch=0.2)},
            ConfigError,
            'camera_height must be a positive number',
        ),
        (
            np.zeros((480, 640), np.uint16),
            {'floor_guard': FloorGuard(camera_height=0.4, camera_pitch=2.0)},
            ConfigError,
            'camera_pitch must be finite and within',
        ),
        (
            np.zeros((480, 640), np.uint16),
            {'floor_guard': FloorGuard(camera_height=0.4, camera_pitch=0.2, margin=-1.0)},
            ConfigError,
            'margin must be a non-negative',
        ),
    ],
)
def test_bad_input_raises(depth: np.ndarray, kwargs: dict, error: type, match: str) -> None:
    arguments = {**LIMITS, **kwargs}
    with pytest.raises(error, match=match):
        row_scan(depth, CAMERA, **arguments)
    assert issubclass(error, ScanfuseError)


def test_non_array_depth_raises() -> None:
    with pytest.raises(InputError, match='must be a numpy array, got list'):
        row_scan([[1, 2]], CAMERA, **LIMITS)  # type: ignore[arg-type]


# --- the loop oracle ----------------------------------------------------------------------

PIXEL_METRES = st.one_of(
    st.floats(min_value=0.015625, max_value=20.0, width=32),
    st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -1.0]),
)
PIXEL_CODES = st.one_of(st.integers(0, 20000), st.just(0), st.integers(65000, 65535))


@st.composite
def small_cases(draw: st.DrawFn) -> dict:
    width = draw(st.integers(2, 24))
    height = draw(st.integers(1, 12))
    camera = CameraModel.from_intrinsics(
        width,
        height,
        draw(st.floats(4.0, 60.0)),
        draw(st.floats(4.0, 60.0)),
        draw(st.floats(-2.0, width + 1.0)),
        draw(st.floats(0.0, height - 1.0)),
    )
    if draw(st.booleans()):
        depth = draw(hnp.arrays(np.uint16, (height, width), elements=PIXEL_CODES))
    else:
        depth = draw(hnp.arrays(np.float32, (height, width), elements=PIXEL_METRES))
    range_min = draw(st.floats(0.0, 2.0))
    range_max = range_min + draw(st.floats(0.5, 15.0))
    guard = None
    if draw(st.booleans()):
        guard = FloorGuard(
            camera_height=draw(st.floats(0.05, 1.5)),
            camera_pitch=draw(st.floats(-0.5, 1.2)),
            margin=draw(st.floats(0.0, 0.3)),
        )
    return {
        'depth': depth,
        'camera': camera,
        'scan_row': draw(st.integers(0, height - 1)),
        'scan_height': draw(st.integers(1, height)),
        'range_min': range_min,
        'range_max': range_max,
        'floor_guard': guard,
    }


def _near_a_limit(case: dict) -> bool:
    """Whether a pixel's range sits within float rounding of a limit (its class is then
    decided by float32 vs float64 arithmetic, not by the method)."""
    camera, depth, guard = case['camera'], case['depth'], case['floor_guard']
    x_n, y_n = camera.normalized_coordinates
    z = depth.astype(np.float64) * (0.001 if depth.dtype == np.uint16 else 1.0)
    with np.errstate(invalid='ignore', over='ignore', divide='ignore'):
        r = z * np.sqrt(1.0 + x_n.astype(np.float64) ** 2)
        limits = [np.full_like(r, case['range_min']), np.full_like(r, case['range_max'])]
        if guard is not None:
            descent = y_n * math.cos(guard.camera_pitch) + math.sin(guard.camera_pitch)
            floor = guard.camera_height / descent * np.sqrt(1.0 + x_n.astype(np.float64) ** 2)
            limits.append(np.where(descent > 0, floor - guard.margin, np.inf))
        finite = np.isfinite(r)
        return any(
            bool(np.any(finite & (np.abs(r - limit) <= 1e-5 * np.maximum(1.0, np.abs(limit)))))
            for limit in limits
        )


@settings(max_examples=300, deadline=None)
@given(small_cases())
def test_default_mode_equals_the_per_pixel_loop(case: dict) -> None:
    assume(not _near_a_limit(case))
    depth, camera = case.pop('depth'), case.pop('camera')
    fast = row_scan(depth, camera, **case)
    slow = row_scan_loop(depth, camera, **case)
    assert len(fast) == len(slow)
    assert fast.angle_min == pytest.approx(slow.angle_min, abs=1e-12)
    assert fast.angle_increment == pytest.approx(slow.angle_increment, abs=1e-12)
    np.testing.assert_allclose(fast.ranges, slow.ranges, rtol=2e-6)
    # REP-117: no finite value outside the limits, ever.
    finite = fast.ranges[np.isfinite(fast.ranges)]
    assert np.all(
        (finite >= np.float32(case['range_min'])) & (finite <= np.float32(case['range_max']))
    )
