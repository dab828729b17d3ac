"""Algorithm 2 (merge) with REP-117 semantics: the invariants of the core issue."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given

from scanfuse import InputError, Scan
from scanfuse.fuse.merge import merge_scans
from tests.strategies import scan_pairs


def in_range(scan: Scan) -> np.ndarray:
    r = scan.ranges
    with np.errstate(invalid='ignore'):
        return np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)


@given(scan_pairs())
def test_result_has_the_lidar_length_angles_and_header(pair):
    lidar, depth = pair
    fused = merge_scans(lidar, depth)
    assert len(fused) == len(lidar)
    np.testing.assert_array_equal(fused.angles(), lidar.angles())
    assert (fused.frame_id, fused.stamp_ns, fused.angle_increment) == (
        lidar.frame_id,
        lidar.stamp_ns,
        lidar.angle_increment,
    )
    assert fused.range_min == min(lidar.range_min, depth.range_min)
    assert fused.range_max == max(lidar.range_max, depth.range_max)


@given(scan_pairs())
def test_never_farther_than_a_finite_in_range_lidar_reading(pair):
    lidar, depth = pair
    fused = merge_scans(lidar, depth)
    valid = in_range(lidar)
    assert np.all(fused.ranges[valid] <= lidar.ranges[valid])


@given(scan_pairs())
def test_nan_never_hides_a_finite_reading_whatever_the_order(pair):
    lidar, depth = pair
    for first, second in ((lidar, depth), (depth, lidar)):
        fused = merge_scans(first, second)
        hidden = np.isnan(fused.ranges) & (in_range(first) | in_range(second))
        assert not hidden.any()


@given(scan_pairs())
def test_too_close_wins_over_everything(pair):
    lidar, depth = pair
    fused = merge_scans(lidar, depth)
    too_close = (lidar.ranges == -np.inf) | (depth.ranges == -np.inf)
    assert np.all(fused.ranges[too_close] == -np.inf)


@given(scan_pairs())
def test_merging_with_all_nan_returns_the_lidar_s_real_readings(pair):
    lidar, _ = pair
    nothing = lidar.with_ranges(np.full(len(lidar), np.nan, np.float32))
    fused = merge_scans(lidar, nothing)
    real = in_range(lidar) & (lidar.ranges > 0.0)
    np.testing.assert_array_equal(fused.ranges[real], lidar.ranges[real])
    infinite = np.isinf(lidar.ranges)
    np.testing.assert_array_equal(fused.ranges[infinite], lidar.ranges[infinite])
    # Everything else (NaN, a driver's 0, values past its own limits) is no information.
    assert np.isnan(fused.ranges[~real & ~infinite]).all()


@given(scan_pairs())
def test_every_published_finite_value_is_a_real_reading_inside_the_published_limits(pair):
    lidar, depth = pair
    for first, second in ((lidar, depth), (depth, lidar)):
        fused = merge_scans(first, second)
        finite = np.isfinite(fused.ranges)
        values = fused.ranges[finite]
        assert np.all((values >= fused.range_min) & (values <= fused.range_max) & (values > 0))
        # ... and it is one of the two sensors' readings inside that sensor's own limits.
        own = ((values == first.ranges[finite]) & in_range(first)[finite]) | (
            (values == second.ranges[finite]) & in_range(second)[finite]
        )
        assert own.all()


def test_a_zero_under_a_published_range_min_of_zero_is_no_reading():
    # A Hokuyo writes 0 for no return; with range_min 0 it used to pass as a 0 m obstacle.
    lidar = Scan(0.0, 0.2, 0.1, 0.0, 5.6, np.array([0.0, 1.0, 0.0], np.float32))
    depth = lidar.with_ranges(np.array([np.nan, np.nan, 2.5], np.float32), range_min=0.2)
    fused = merge_scans(lidar, depth)
    np.testing.assert_array_equal(fused.ranges, np.float32([np.nan, 1.0, 2.5]))
    assert (fused.range_min, fused.range_max) == (0.0, 5.6)


def test_values_below_range_min_become_nan_not_too_close():
    # REP-117's -Inf is for a driver that says "too close"; 0.01 under range_min 0.02 is
    # a Hokuyo error code, not a measurement, and must not put an obstacle on the robot.
    lidar = Scan(0.0, 0.2, 0.1, 0.02, 5.6, np.array([0.01, -np.inf, 7.0], np.float32))
    nothing = lidar.with_ranges(np.full(3, np.nan, np.float32))
    fused = merge_scans(lidar, nothing)
    assert np.isnan(fused.ranges[0])
    assert fused.ranges[1] == -np.inf
    assert np.isnan(fused.ranges[2])


@given(scan_pairs())
def test_a_valid_depth_reading_nearer_than_the_lidar_is_taken(pair):
    lidar, depth = pair
    fused = merge_scans(lidar, depth)
    lidar_nearest = in_range(lidar) | (lidar.ranges == -np.inf)
    lidar_r = np.where(lidar_nearest, lidar.ranges, np.inf)
    nearer = in_range(depth) & (depth.ranges < lidar_r)
    np.testing.assert_array_equal(fused.ranges[nearer], depth.ranges[nearer])


def test_hand_worked_slots():
    nan, inf = np.nan, np.inf
    lidar = Scan(-0.3, 0.3, 0.1, 0.15, 12.0, np.array([2.0, 2.0, nan, inf, 0.0, 2.0, 2.0]))
    depth = lidar.with_ranges(
        np.array([1.0, nan, 1.5, 3.0, 1.2, -inf, 11.0]), range_min=0.2, range_max=10.0
    )
    fused = merge_scans(lidar, depth)
    # nearer depth; NaN depth; NaN lidar; free lidar vs depth obstacle;
    # lidar error value 0 vs depth; too close; depth beyond its own range_max.
    np.testing.assert_array_equal(fused.ranges, np.float32([1.0, 2.0, 1.5, 3.0, 1.2, -inf, 2.0]))


def test_intensities_are_zero_where_depth_wins():
    lidar = Scan(0.0, 0.1, 0.1, 0.1, 10.0, np.array([2.0, 2.0]), intensities=np.array([7.0, 9.0]))
    depth = lidar.with_ranges(np.array([1.0, np.nan], np.float32), intensities=None)
    fused = merge_scans(lidar, depth)
    np.testing.assert_array_equal(fused.intensities, [0.0, 9.0])


def test_length_mismatch_is_rejected():
    lidar = Scan(0.0, 0.1, 0.1, 0.1, 10.0, np.array([2.0, 2.0]))
    depth = Scan(0.0, 0.2, 0.1, 0.1, 10.0, np.array([2.0, 2.0, 2.0]))
    with pytest.raises(InputError, match='resample it onto the LiDAR grid first'):
        merge_scans(lidar, depth)
