"""`row_scan(d2l_compat=True)` against depthimage_to_laserscan (ros2 branch).

The first group ports test/DepthImageToLaserScanTest.cpp test by test with its
assertions; the rest pins the behaviour its source (DepthImageToLaserScan.cpp,
depth_traits.hpp) defines: float precision, index truncation, use_point's order
dependence, and the scan_height exception. `reference.d2l_scan_loop` is a
line-by-line transliteration of that source.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse.camera import CameraModel
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.row import row_scan
from scanfuse.errors import ConfigError, InputError
from tests.support.reference import d2l_scan_loop

# The upstream fixture: 640x480, CameraInfo K as below, no distortion.
G_RANGE_MIN = 0.45
G_RANGE_MAX = 10.0
G_SCAN_HEIGHT = 1
G_OUTPUT_FRAME = 'camera_depth_frame'
CAMERA = CameraModel.from_intrinsics(
    640, 480, 570.3422241210938, 570.3422241210938, 314.5, 235.5, frame_id=G_OUTPUT_FRAME
)


def _convert(depth: np.ndarray, scan_height: int = G_SCAN_HEIGHT) -> np.ndarray:
    return row_scan(
        depth,
        CAMERA,
        scan_height=scan_height,
        range_min=G_RANGE_MIN,
        range_max=G_RANGE_MAX,
        d2l_compat=True,
    ).ranges


@pytest.fixture
def depth_msg() -> np.ndarray:
    # data.assign(height * step, 0x0F): every byte 0x0F, so every 16UC1 pixel is
    # 0x0F0F = 3855 mm ("Sets all values to 3.855m").
    return np.full((480, 640), 0x0F0F, dtype=np.uint16)


def _float_msg(value: float) -> np.ndarray:
    return np.full((480, 640), value, dtype=np.float32)


def test_setup_library(depth_msg: np.ndarray) -> None:
    scan = row_scan(
        depth_msg,
        CAMERA,
        scan_height=G_SCAN_HEIGHT,
        range_min=G_RANGE_MIN,
        range_max=G_RANGE_MAX,
        d2l_compat=True,
    )
    # EXPECT_EQ on the float fields of the message (scan_time is set by scanfuse's
    # message layer, not by the conversion, so it has no counterpart here).
    assert np.float32(scan.range_min) == np.float32(G_RANGE_MIN)
    assert np.float32(scan.range_max) == np.float32(G_RANGE_MAX)
    assert scan.frame_id == G_OUTPUT_FRAME
    assert len(scan.ranges) == depth_msg.shape[1]


def test_exceptions(depth_msg: np.ndarray) -> None:
    # RGB8 throws: an 8-bit three-channel image is no depth image.
    rgb8 = np.zeros((480, 640, 3), dtype=np.uint8)
    with pytest.raises(InputError, match='must be two-dimensional'):
        _convert(rgb8)
    with pytest.raises(InputError, match='dtype uint8 is not supported'):
        _convert(np.zeros((480, 640), dtype=np.uint8))
    # The same bytes as 32FC1 and as 16UC1 do not throw.
    as_float = np.full((480, 640), 0x0F0F0F0F, dtype=np.uint32).view(np.float32)
    assert _convert(as_float).shape == (640,)
    assert _convert(depth_msg).shape == (640,)


def test_scan_height(depth_msg: np.ndarray) -> None:
    # Make sure the minimum is output for each pixel column for various scan heights.
    data = depth_msg  # written in place from one scan height to the next, as upstream
    low_value, high_value = 500, 3000
    for scan_height in range(1, 101):
        offset = int(235.5 - scan_height / 2.0)
        for v in range(scan_height):
            u = np.arange(640)
            data[offset + v] = np.where(v % scan_height == u % scan_height, low_value, high_value)
        ranges = _convert(data, scan_height)
        # 0.9 represents 10 percent margin on range
        high_float_thresh = np.float32(high_value) * np.float32(1.0) / np.float32(1000.0)
        high_float_thresh *= np.float32(0.9)
        valid = (np.float32(G_RANGE_MIN) <= ranges) & (ranges <= np.float32(G_RANGE_MAX))
        assert np.all(ranges[valid] < high_float_thresh), scan_height
        assert valid.any()


def test_random(depth_msg: np.ndarray) -> None:
    # Distances between 0 and 0.5 m; finite values must respect the limits.
    rng = np.random.default_rng(8675309)
    depth_msg[:] = rng.integers(0, 500, size=depth_msg.shape, endpoint=True)
    ranges = _convert(depth_msg)
    finite = ranges[np.isfinite(ranges)]
    assert np.all(finite >= np.float32(G_RANGE_MIN))
    assert np.all(finite <= np.float32(G_RANGE_MAX))
    assert finite.size > 0


def test_nan() -> None:
    ranges = _convert(_float_msg(np.nan))
    assert not np.isfinite(ranges).any(), 'Non-NaN value produced from NaN test.'


def test_positive_inf() -> None:
    ranges = _convert(_float_msg(np.inf))
    assert not np.isfinite(ranges).any(), 'Non-finite value produced from positive infinity test.'
    assert not np.any(ranges < 0), 'Negative value produced from positive infinity test.'
    nan_count = int(np.isnan(ranges).sum())
    assert nan_count <= ranges.size * 0.80


def test_negative_inf() -> None:
    ranges = _convert(_float_msg(-np.inf))
    assert not np.isfinite(ranges).any(), 'Non-finite value produced from negative infinity test.'
    assert not np.any(ranges > 0), 'Positive value produced from negative infinity test.'
    nan_count = int(np.isnan(ranges).sum())
    assert nan_count <= ranges.size * 0.80


# --- behaviour the upstream source defines -----------------------------------------------


def test_angle_fields_are_upstreams(depth_msg: np.ndarray) -> None:
    scan = row_scan(
        depth_msg, CAMERA, range_min=G_RANGE_MIN, range_max=G_RANGE_MAX, d2l_compat=True
    )
    # angle_between_rays of (0, cy) and (width-1, cy) with the optical centre, stored float.
    angle_max = np.float32(math.atan(314.5 / 570.3422241210938))
    angle_min = np.float32(-math.atan((639 - 314.5) / 570.3422241210938))
    assert scan.angle_max == pytest.approx(float(angle_max), abs=1e-7)
    assert scan.angle_min == pytest.approx(float(angle_min), abs=1e-7)
    assert scan.angle_increment == pytest.approx(float((angle_max - angle_min) / 639), rel=1e-6)


def test_upstream_leaves_empty_slots_that_default_mode_fills(depth_msg: np.ndarray) -> None:
    # Evenly spaced angles against pixel columns evenly spaced in tangent: near the
    # centre two columns are more than an increment apart, so upstream skips slots.
    compat = _convert(depth_msg)
    assert np.isnan(compat).any()
    default = row_scan(depth_msg, CAMERA, range_min=G_RANGE_MIN, range_max=G_RANGE_MAX)
    assert np.isfinite(default.ranges).all()


def test_last_infinity_wins_as_in_use_point() -> None:
    # Two rows, every column: +Inf above -Inf. use_point lets a later +-Inf replace an
    # earlier one, so the lower row (visited last) wins; swapping the rows swaps the result.
    depth = np.full((480, 640), np.nan, dtype=np.float32)
    offset = int(235.5 - 2 / 2.0)  # 234
    depth[offset] = np.inf
    depth[offset + 1] = -np.inf
    ranges = _convert(depth, scan_height=2)
    filled = ranges[~np.isnan(ranges)]
    assert filled.size > 0
    assert np.all(filled == -np.inf)
    depth[offset], depth[offset + 1] = -np.inf, np.inf
    filled = _convert(depth, scan_height=2)
    assert np.all(filled[~np.isnan(filled)] == np.inf)
    # The default mode is order independent: -Inf (too close) either way.
    default = row_scan(
        depth, CAMERA, scan_row=235, scan_height=2, range_min=G_RANGE_MIN, range_max=G_RANGE_MAX
    )  # rows 234 and 235, the same band
    assert np.all(default.ranges == -np.inf)


def test_finite_value_beats_infinity_and_out_of_limits_values_never_enter() -> None:
    depth = np.full((480, 640), np.inf, dtype=np.float32)
    depth[235, 320] = 2.0  # in limits, in the band of height 1 (offset int(235.5 - 0.5))
    depth[235, 100] = 20.0  # beyond range_max: never used, the slot stays what it was
    ranges = _convert(depth)
    assert np.sum(np.isfinite(ranges)) == 1
    x = (np.float32(320) - np.float32(314.5)) * np.float32(2.0) / np.float32(570.3422241210938)
    assert ranges[np.isfinite(ranges)][0] == pytest.approx(math.hypot(float(x), 2.0), rel=1e-6)


def test_invalid_16uc1_pixel_is_range_zero_and_wins_when_range_min_is_zero() -> None:
    # DepthTraits<uint16_t>::valid(0) is false, so r keeps the raw depth 0 (a finite
    # number): rejected by range_min > 0, but the nearest value when range_min = 0.
    depth = np.full((480, 640), 2000, dtype=np.uint16)
    depth[235, 400] = 0
    zero_min = row_scan(depth, CAMERA, range_min=0.0, range_max=10.0, d2l_compat=True)
    assert np.any(zero_min.ranges == 0.0)
    assert not np.any(_convert(depth) == 0.0)


def test_scan_height_too_large_raises_like_upstream() -> None:
    depth = np.zeros((480, 640), dtype=np.uint16)
    # scan_height / 2 (integer) > cy = 235.5 first happens at 472.
    assert _convert(depth, scan_height=471).shape == (640,)
    with pytest.raises(ConfigError, match=r'scan_height \( 472 pixels\) is too large'):
        _convert(depth, scan_height=472)


def test_band_reaching_outside_the_image_raises() -> None:
    # cy = 240 in a 480-row image: upstream's check lets 481 through, then reads row 480.
    camera = CameraModel.from_intrinsics(64, 480, 60.0, 60.0, 31.5, 240.0)
    depth = np.zeros((480, 64), dtype=np.uint16)
    with pytest.raises(ConfigError, match='scan_height 481 must be between 1'):
        row_scan(depth, camera, scan_height=481, range_min=0.4, range_max=5.0, d2l_compat=True)


def test_compat_refuses_what_upstream_does_not_have() -> None:
    depth = np.zeros((480, 640), dtype=np.uint16)
    with pytest.raises(ConfigError, match='band is always centred on cy'):
        row_scan(depth, CAMERA, scan_row=100, range_min=0.4, range_max=5.0, d2l_compat=True)
    with pytest.raises(ConfigError, match='which has no floor guard'):
        row_scan(
            depth,
            CAMERA,
            range_min=0.4,
            range_max=5.0,
            d2l_compat=True,
            floor_guard=FloorGuard(0.4, 0.3),
        )


# --- bit-exact against the transliterated loop --------------------------------------------


def test_fixture_scans_equal_the_transliteration(depth_msg: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    images = [
        depth_msg,
        rng.integers(0, 12000, size=(480, 640)).astype(np.uint16),
        np.where(rng.random((480, 640)) < 0.2, np.nan, rng.uniform(0.1, 12.0, (480, 640))).astype(
            np.float32
        ),
    ]
    for image in images:
        for scan_height in (1, 4):
            scan = row_scan(
                image,
                CAMERA,
                scan_height=scan_height,
                range_min=G_RANGE_MIN,
                range_max=G_RANGE_MAX,
                d2l_compat=True,
            )
            angle_min, angle_max, increment, ranges = d2l_scan_loop(
                image,
                CAMERA.fx,
                CAMERA.cx,
                CAMERA.cy,
                scan_height=scan_height,
                range_min=G_RANGE_MIN,
                range_max=G_RANGE_MAX,
            )
            assert (scan.angle_min, scan.angle_max, scan.angle_increment) == (
                angle_min,
                angle_max,
                increment,
            )
            np.testing.assert_array_equal(scan.ranges, ranges)


PIXELS_FLOAT = st.one_of(
    st.floats(min_value=0.0, max_value=15.0, width=32),
    st.sampled_from([np.nan, np.inf, -np.inf, -1.0]),
)


@st.composite
def compat_cases(draw: st.DrawFn) -> tuple[np.ndarray, CameraModel, int, float, float]:
    width = draw(st.integers(2, 20))
    height = draw(st.integers(1, 10))
    camera = CameraModel.from_intrinsics(
        width,
        height,
        draw(st.floats(5.0, 80.0)),
        draw(st.floats(5.0, 80.0)),
        draw(st.sampled_from([(width - 1) / 2, width / 2, width / 3])),
        draw(st.floats(0.0, height - 0.01)),
    )
    if draw(st.booleans()):
        depth = draw(hnp.arrays(np.uint16, (height, width), elements=st.integers(0, 16000)))
    else:
        depth = draw(hnp.arrays(np.float32, (height, width), elements=PIXELS_FLOAT))
    range_min = draw(st.floats(0.0, 2.0))
    range_max = range_min + draw(st.floats(0.1, 12.0))
    return depth, camera, draw(st.integers(1, height)), range_min, range_max


@settings(max_examples=300, deadline=None)
@given(compat_cases())
def test_compat_equals_the_transliteration_bit_for_bit(
    case: tuple[np.ndarray, CameraModel, int, float, float],
) -> None:
    depth, camera, scan_height, range_min, range_max = case
    try:
        expected = d2l_scan_loop(
            depth,
            camera.fx,
            camera.cx,
            camera.cy,
            scan_height=scan_height,
            range_min=range_min,
            range_max=range_max,
        )
    except (RuntimeError, IndexError):
        # Upstream throws (or reads outside the image): scanfuse refuses too.
        with pytest.raises(ConfigError):
            row_scan(
                depth,
                camera,
                scan_height=scan_height,
                range_min=range_min,
                range_max=range_max,
                d2l_compat=True,
            )
        return
    scan = row_scan(
        depth,
        camera,
        scan_height=scan_height,
        range_min=range_min,
        range_max=range_max,
        d2l_compat=True,
    )
    assert (scan.angle_min, scan.angle_max, scan.angle_increment) == expected[:3]
    np.testing.assert_array_equal(scan.ranges, expected[3])
