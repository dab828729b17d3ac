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
def test_merging_with_all_nan_returns_the_lidar_unchanged(pair):
    lidar, _ = pair
    nothing = lidar.with_ranges(np.full(len(lidar), np.nan, np.float32))
    fused = merge_scans(lidar, nothing)
    np.testing.assert_array_equal(fused.ranges, lidar.ranges)


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
