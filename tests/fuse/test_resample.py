"""Algorithm 3 (linear resample) and the conservative resampler."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse import AngleGrid, Scan
from scanfuse.fuse.resample import resample_conservative, resample_linear
from tests.strategies import RANGE_VALUES

NAN, INF = np.nan, np.inf


def depth_scan(ranges, angle_min=-0.5, increment=0.25):
    ranges = np.asarray(ranges, np.float32)
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (ranges.size - 1),
        angle_increment=increment,
        range_min=0.2,
        range_max=10.0,
        ranges=ranges,
        time_increment=1e-5,
        scan_time=1 / 30,
        frame_id='camera_depth_optical_frame',
        stamp_ns=42,
    )


def test_linear_interpolates_between_neighbours_and_is_nan_outside_view():
    source = depth_scan([1, 2, 3, 4, 5])  # at -0.5, -0.25, 0, 0.25, 0.5
    target = AngleGrid(-1.0, 0.125, 17)
    out = resample_linear(source, target).ranges
    expected = [NAN] * 4 + [1, 1.5, 2, 2.5, 3, 3.5, 4, 4.5, 5] + [NAN] * 4
    np.testing.assert_allclose(out, expected, rtol=1e-6)


def test_linear_takes_the_nearer_reading_next_to_a_non_finite_one():
    source = depth_scan([1, INF, 3, NAN, 5])
    target = AngleGrid(-0.45, 0.25, 4)  # 0.2 of the way past each source reading
    np.testing.assert_array_equal(resample_linear(source, target).ranges, [1, INF, 3, NAN])


def test_result_keeps_depth_header_and_lidar_angles():
    source = depth_scan([1, 2, 3, 4, 5])
    lidar = Scan(-math.pi, math.pi - 0.01, 0.01, 0.15, 12.0, np.ones(629), frame_id='laser')
    for resample in (resample_linear, resample_conservative):
        out = resample(source, lidar)
        assert (out.angle_min, out.angle_increment, len(out)) == (-math.pi, 0.01, 629)
        assert (out.frame_id, out.stamp_ns, out.scan_time, out.time_increment) == (
            'camera_depth_optical_frame',
            42,
            source.scan_time,
            source.time_increment,
        )
        assert (out.range_min, out.range_max) == (0.2, 10.0)


def test_lidar_grid_from_zero_to_two_pi_wraps_negative_angles():
    source = depth_scan([1, 2, 3, 4, 5])
    increment = 2 * math.pi / 16
    target = AngleGrid(0.0, increment, 16)  # 0, pi/8, ..., 15 pi/8
    out = resample_linear(source, target).ranges
    # Slot 15 is at -pi/8 = -0.3927: a fraction 0.429 of the way from -0.5 to -0.25.
    assert out[15] == np.float32(1 + (0.5 - math.pi / 8) / 0.25)
    assert out[0] == 3.0
    assert np.isnan(out[2:14]).all()


def test_negative_increments_on_either_side_give_the_same_ranges():
    forward = depth_scan([1, 2, 3, 4, 5])
    backward = depth_scan([5, 4, 3, 2, 1], angle_min=0.5, increment=-0.25)
    target = AngleGrid(0.5, -0.1, 11)
    for resample in (resample_linear, resample_conservative):
        np.testing.assert_allclose(
            resample(forward, target).ranges, resample(backward, target).ranges, rtol=1e-6
        )


def test_conservative_takes_the_near_side_of_a_depth_edge():
    # A table leg at 1 m in front of a wall at 5 m, sampled finely by the camera.
    source = depth_scan([5] * 10 + [1] * 10, angle_min=-0.095, increment=0.01)
    target = AngleGrid(-0.1, 0.025, 9)  # slots of 2.5 readings
    conservative = resample_conservative(source, target).ranges
    linear = resample_linear(source, target).ranges
    # The slot centred on 0.0 spans the edge: conservative says 1 m, never in between.
    assert conservative[4] == 1.0
    assert set(np.unique(conservative).tolist()) <= {1.0, 5.0}
    # Linear invents a range in the free space between leg and wall: the phantom point.
    assert 1.0 < linear[4] < 5.0


def test_conservative_coarse_source_fills_every_target_slot_it_covers():
    source = depth_scan([1, 2, 3, 4, 5])  # readings cover [-0.625, 0.625]
    target = AngleGrid(-0.6, 0.1, 13)  # -0.6 ... 0.6
    out = resample_conservative(source, target).ranges
    assert np.isfinite(out).all()
    # -0.6 lies only in reading 0's interval; -0.4 overlaps readings 0 and 1 (edge at -0.375).
    assert out[0] == 1.0
    assert out[2] == 1.0
    assert out[12] == 5.0


def brute_force_conservative(source: Scan, target: AngleGrid) -> np.ndarray:
    """Per target slot, fmin over source readings whose angular intervals overlap it."""
    out = np.full(target.count, np.nan, np.float32)
    s_half = abs(source.angle_increment) / 2
    t_half = abs(target.angle_increment) / 2
    for j, t in enumerate(target.angles()):
        for i, a in enumerate(source.angles()):
            gap = abs((t - a + math.pi) % (2 * math.pi) - math.pi)
            if gap < s_half + t_half - 1e-9:
                out[j] = np.fmin(out[j], source.ranges[i])
    return out


@given(
    ranges=hnp.arrays(np.float32, st.integers(1, 40), elements=RANGE_VALUES),
    source_increment=st.sampled_from([0.0024, 0.01, -0.01, 0.03]),
    source_min=st.floats(-1.0, 1.0),
    target_min=st.sampled_from([-math.pi, 0.0]),
    target_count=st.sampled_from([360, 1080]),
)
def test_conservative_equals_brute_force_overlap_minimum(
    ranges, source_increment, source_min, target_min, target_count
):
    source = depth_scan(ranges, angle_min=source_min, increment=source_increment)
    target = AngleGrid(target_min, 2 * math.pi / target_count, target_count)
    expected = brute_force_conservative(source, target)
    got = resample_conservative(source, target).ranges
    # Slots whose intervals only touch a source interval's edge may go either way.
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    both = ~np.isnan(got)
    np.testing.assert_array_equal(got[both], expected[both])
