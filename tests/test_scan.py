"""Scan, AngleGrid and the REP-117 helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse import AngleGrid, InputError, Scan
from scanfuse.scan import full_circle, normalized_ranges, to_rep117


def make_scan(ranges, **fields):
    values = {
        'angle_min': -1.0,
        'angle_max': 1.0,
        'angle_increment': 0.5,
        'range_min': 0.1,
        'range_max': 10.0,
        'ranges': np.asarray(ranges, dtype=np.float32),
    }
    values.update(fields)
    return Scan(**values)


def test_angles_follow_the_laserscan_definition():
    scan = make_scan([1, 2, 3, 4, 5])
    np.testing.assert_allclose(scan.angles(), [-1.0, -0.5, 0.0, 0.5, 1.0])


def test_ranges_become_float32():
    scan = make_scan(np.array([1.0, 2.0], dtype=np.float64), angle_max=-0.5)
    assert scan.ranges.dtype == np.float32


def test_two_dimensional_ranges_are_rejected():
    with pytest.raises(InputError, match='one-dimensional'):
        make_scan(np.ones((2, 2)))


def test_zero_increment_is_rejected():
    with pytest.raises(InputError, match='angle_increment must be finite and non-zero'):
        make_scan([1.0], angle_increment=0.0)


def test_intensities_must_match_ranges():
    with pytest.raises(InputError, match='2 values for 3 ranges'):
        make_scan([1, 2, 3], intensities=np.ones(2))


def test_empty_grid_is_rejected():
    with pytest.raises(InputError, match='at least one reading'):
        AngleGrid(0.0, 0.1, 0)


@pytest.mark.parametrize('angle_min', [-math.pi, 0.0])
def test_slot_of_handles_both_conventions(angle_min):
    grid = AngleGrid(angle_min, 2 * math.pi / 8, 8)
    # The slot centred on angle a holds a - inc/2 + eps ... a + inc/2 - eps, modulo 2 pi.
    for i, centre in enumerate(grid.angles()):
        probes = np.array([centre, centre + 0.3, centre - 0.3, centre + 2 * math.pi])
        np.testing.assert_array_equal(grid.slot_of(probes), [i, i, i, i])


def test_slot_of_negative_increment():
    grid = AngleGrid(1.0, -0.5, 5)  # 1.0, 0.5, 0.0, -0.5, -1.0
    np.testing.assert_array_equal(
        grid.slot_of(np.array([1.0, 0.45, -0.1, -1.2, 2.0])), [0, 1, 2, 4, -1]
    )


def test_slot_of_outside_partial_grid_is_minus_one():
    grid = AngleGrid(-0.5, 0.25, 5)  # covers [-0.625, 0.625)
    np.testing.assert_array_equal(grid.slot_of(np.array([0.7, -0.7, math.pi])), [-1, -1, -1])


def test_normalized_ranges_drops_driver_error_values_but_keeps_infinities():
    scan = make_scan([0.0, 0.05, 5.0, 11.0, np.inf, -np.inf, np.nan])
    out = normalized_ranges(scan)
    assert np.isnan(out[0])
    assert np.isnan(out[1])
    assert out[2] == 5.0
    assert np.isnan(out[3])
    assert out[4] == np.inf
    assert out[5] == -np.inf
    assert np.isnan(out[6])


def test_to_rep117_maps_out_of_range_to_infinities():
    out = to_rep117(np.array([0.05, 1.0, 12.0, np.nan], np.float32), 0.1, 10.0)
    assert out[0] == -np.inf
    assert out[1] == 1.0
    assert out[2] == np.inf
    assert np.isnan(out[3])


def _scan(angle_min: float, increment: float, count: int) -> Scan:
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (count - 1),
        angle_increment=increment,
        range_min=0.02,
        range_max=10.0,
        ranges=np.arange(1, count + 1, dtype=np.float32),
        time_increment=1e-5,
    )


def test_full_circle_keeps_a_270_degree_scans_readings_at_their_angles():
    # A UST-10LX: -135 to +135 degrees in 0.25-degree steps, 1081 readings. Over 360 degrees
    # that increment makes 1440 slots; -135 degrees is 180 steps after -180.
    step = math.radians(0.25)
    scan = _scan(-math.radians(135.0), step, 1081)
    wide = full_circle(scan)
    assert wide is not None
    assert len(wide) == 1440
    assert wide.angle_min == pytest.approx(-math.pi)
    assert wide.angle_increment == scan.angle_increment
    np.testing.assert_array_equal(wide.ranges[180 : 180 + 1081], scan.ranges)
    assert np.isnan(wide.ranges[:180]).all()
    assert np.isnan(wide.ranges[180 + 1081 :]).all()
    np.testing.assert_allclose(wide.angles()[180 : 180 + 1081], scan.angles(), atol=1e-12)
    assert wide.time_increment == 0.0  # the readings moved: the beam times are not its own


def test_full_circle_of_a_clockwise_scan_starts_near_plus_pi():
    step = math.radians(1.0)
    scan = _scan(math.radians(90.0), -step, 181)  # +90 down to -90 degrees
    wide = full_circle(scan)
    assert wide is not None
    assert len(wide) == 360
    assert wide.angle_min == pytest.approx(math.pi)  # 90 steps before +90 degrees, clockwise
    np.testing.assert_allclose(wide.angles()[90 : 90 + 181], scan.angles(), atol=1e-12)


def test_full_circle_leaves_a_360_degree_scan_alone():
    step = 2 * math.pi / 720
    assert full_circle(_scan(-math.pi, step, 720)) is None
